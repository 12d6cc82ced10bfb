"""Light at the renderer's surface points: the sun's visibility (shadow rays toward the sun
through the plants, weeds and obstacles, culled by the row structure like the camera's rays) and
the ground's ambient occlusion near the rows. Used by `render.core.render`'s shading."""

from __future__ import annotations

import jax
import jax.numpy as jnp

from mjxrow.field import lanes as field_lanes
from mjxrow.render import geom
from mjxrow.render import tiles as render_tiles
from mjxrow.render.shade import SKY

INF = jnp.inf
SHADOW_REACH = 60.0  # m, how far a shadow ray looks for a plant toward the sun


def sun_visibility(field, shape, tab, obst, wtab, p, normal, cls, cond, cfg, nt):
    """Visibility of the sun from surface points p [N, 3] (tile-major; cls [N] their class):
    1 lit, 0 in a plant's, weed's or obstacle's shadow."""
    n = p.shape[0]
    l = cond.sun_dir
    o = p + 2e-3 * normal + 1e-3 * l
    t_min = jnp.zeros((n,), jnp.float32)
    ot = o.reshape(nt, -1, 3)
    seen = (cls != SKY).reshape(nt, -1, 1)
    lo = jnp.min(jnp.where(seen, ot, INF), axis=1)
    hi = jnp.max(jnp.where(seen, ot, -INF), axis=1)
    sweep, live = render_tiles.shadow_sweep(lo, hi, l)
    t_max = jnp.where(live, SHADOW_REACH, -1.0)
    with jax.named_scope("rd_shadow_cull"):
        ids, entry, *_ = render_tiles.cull(
            tab,
            shape.max_plants_per_row,
            *sweep,
            t_max,
            cfg.shadow_row_blocks,
            cfg.shadow_block_keep,
            cfg.shadow_keep,
        )
    ls = tuple(jnp.reshape(l[i], (1, 1)) for i in range(3))
    t_pl = render_tiles.exact(tab, ids, entry, geom.xyz(ot), ls, t_min.reshape(nt, -1),
                              jnp.full(ot.shape[:2], SHADOW_REACH, jnp.float32),
                    any_hit=True, kernel=cfg.kernel).reshape(-1)
    oid, oent = render_tiles.cull_obstacles(obst, *sweep, t_max, cfg.obstacle_keep)
    t_ob = geom.trace_obstacles_tiled(obst, oid, oent, geom.xyz(ot), ls, t_min.reshape(nt, -1),
                                   any_hit=True).reshape(-1)
    shade_ = jnp.isfinite(t_pl) | jnp.isfinite(t_ob)
    if wtab is not None:
        wid, went = render_tiles.cull_weeds(wtab, *sweep, t_max, cfg.weed_keep)
        t_wd = render_tiles.exact(wtab, wid, went, geom.xyz(ot), ls, t_min.reshape(nt, -1),
                                  jnp.full(ot.shape[:2], SHADOW_REACH, jnp.float32),
                                  any_hit=True, kernel=cfg.kernel).reshape(-1)
        shade_ = shade_ | jnp.isfinite(t_wd)
    return jnp.where(shade_, 0.0, 1.0)


def ground_occlusion(tab, p):
    """Ambient occlusion of the ground near the rows: 0.55 under a canopy line .. 1 in a lane."""
    ok = tab.row_zhi > tab.row_zlo  # rows with plants
    u = field_lanes.to_field(tab.bend, p[:, 0:1], p[:, 1:2])[1]  # across the rows (y if straight)
    dist = jnp.min(jnp.where(ok, jnp.abs(u - tab.row_y), 1e3), axis=1)
    s = jnp.clip((dist - 0.2 * tab.reach_y) / jnp.maximum(1.2 * tab.reach_y, 1e-3), 0.0, 1.0)
    return 0.55 + 0.45 * s * s * (3 - 2 * s)
