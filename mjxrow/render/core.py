"""Batched camera renderer: a pure JAX ray caster of one field from one camera.

`render(field, shape, cam_pos, cam_rot, intr, cond, key=None) -> Frame` draws exactly what the
exports (`mjxrow.worlds.mjcf.to_mjcf`) draw: the heightfield terrain with MuJoCo's
triangulation, each plant's primitives from `crops.prims.plant_prims` (ellipsoids and
capsules, intersected exactly), stones (spheres) and fallen branches (capsules). It is
jittable and vmappable over worlds and cameras; jit/vmap are composed by the callers (episode,
dataset, benchmarks), e.g.

    frames = jax.jit(jax.vmap(lambda f, p, r, c: render(f, shape, p, r, intr, c)))(...)

Camera convention (MuJoCo's): `cam_pos float32 [3]` (world) and `cam_rot float32 [3, 3]` whose
columns are the camera's x (right), y (up) and z (backwards) axes, i.e. `data.cam_xpos` and
`data.cam_xmat.reshape(3, 3)`; the camera looks along −z. `Intrinsics.fovy` is the vertical field
of view in degrees; the horizontal one follows from width / height. Pixel (i, j) looks through
the centre of the pixel, row 0 at the top.

What is not drawn: anything beyond `RenderConfig.far` metres (150 m: every preset field fits);
the terrain's side walls; a plant primitive that contains the camera (seen from inside).

How it stays fast (tiles, culling through the row structure, the Pallas kernels) and what it
does not draw: docs/render.md. Sky pixels have `depth = SKY_DEPTH`, `mask = False`,
`classes = SKY`. The kernel (`RenderConfig.kernel`) defaults by backend (`config.default_kernel`);
the environment variable MJXROW_RENDER_KERNEL overrides it for every command.
"""

from __future__ import annotations

import functools

import jax
import jax.numpy as jnp
import numpy as np
from flax import struct

from mjxrow import field as mjxrow_field
from mjxrow.crops import prims as crops_prims
from mjxrow.render import geom, pallas, shade
from mjxrow.render import light as render_light
from mjxrow.render import terrain as render_terrain
from mjxrow.render import tiles as render_tiles
from mjxrow.render import weeds as render_weeds
from mjxrow.render.config import DEFAULT_CONFIG, Intrinsics, RenderConfig, resolve
from mjxrow.render.geom import PlantTable, plant_table
from mjxrow.render.shade import (
    CONDITIONS,
    OBSTACLE,
    PLANT,
    SKY,
    SOIL,
    SUN_AZIMUTH_DEG,
    WEED,
    Conditions,
    condition_by_index,
    conditions,
)

__all__ = ["CONDITIONS", "DEFAULT_CONFIG", "Conditions", "Frame", "Intrinsics", "PlantTable",
           "RenderConfig", "SKY_DEPTH", "SUN_AZIMUTH_DEG", "WEED", "geometry", "plant_table",
           "camera_rot", "condition_by_index", "conditions", "render"]

INF = jnp.inf
SKY_DEPTH = 1000.0  # m, depth of sky pixels (finite, larger than any field)
def _settle(tree, how: str):
    """The shading's per-pixel terms, kept as `how` says."""
    if how == "loop":
        return geom.materialise(tree)
    if how == "barrier":
        return jax.lax.optimization_barrier(tree)
    return tree


@struct.dataclass
class _Surface:
    """What the shading needs of the plant or weed under each pixel ([N]; any value
    elsewhere)."""

    material: jax.Array  # int32 [N], crops.prims.LEAF ... WEED
    base: jax.Array  # float32 [N, 3]: base z [m], height [m], phase [0, 1)
    item: jax.Array  # int32 [N], plant index (R·P + the weed's slot for a weed): texture seed
    k: jax.Array  # int32 [N], primitive


@struct.dataclass
class Frame:
    """One rendered image (add [B] in front for a batch)."""

    rgb: jax.Array  # uint8 [H, W, 3]
    depth: jax.Array  # float32 [H, W], metres along the optical axis; SKY_DEPTH for sky
    mask: jax.Array  # bool [H, W], crop plant pixels (classes == PLANT; never weeds)
    classes: jax.Array  # uint8 [H, W]: SKY 0, SOIL 1, PLANT 2, OBSTACLE 3, WEED 4


def camera_rot(yaw: jax.Array, pitch: jax.Array, roll: jax.Array = 0.0) -> jax.Array:
    """cam_rot float32 [3, 3] (columns right, up, backwards) of a camera looking along heading
    `yaw` (rad, about z from +x), tilted by `pitch` (rad, negative looks down) and rolled by
    `roll` (rad, about the optical axis, positive turns the image clockwise)."""
    cy, sy, cp, sp = jnp.cos(yaw), jnp.sin(yaw), jnp.cos(pitch), jnp.sin(pitch)
    fwd = jnp.stack([cp * cy, cp * sy, sp])
    right = jnp.stack([sy, -cy, jnp.zeros_like(cy)])
    up = jnp.cross(right, fwd)
    cr, sr = jnp.cos(roll), jnp.sin(roll)
    right, up = cr * right - sr * up, sr * right + cr * up
    return jnp.stack([right, up, -fwd], 1).astype(jnp.float32)


def pixel_rays(intr: Intrinsics) -> np.ndarray:
    """Camera-frame ray directions through the pixel centres, z = −1: float32 [H·W, 3]."""
    ty = np.tan(np.deg2rad(intr.fovy) / 2)
    tx = ty * intr.width / intr.height
    j = (2 * (np.arange(intr.width) + 0.5) / intr.width - 1) * tx
    i = (1 - 2 * (np.arange(intr.height) + 0.5) / intr.height) * ty
    xx, yy = np.meshgrid(j, i)
    return np.stack([xx, yy, -np.ones_like(xx)], -1).reshape(-1, 3).astype(np.float32)


def _trace(field, shape, tab, obst, wtab, rays, cfg):
    """Nearest surface of each ray (flat, tile-major [N = T·P]): (t, class, point, normal,
    point in the plant's or weed's primitive frame, `_Surface` of the plant or weed pixels,
    is_branch). wtab: the frame's `weeds.table`, or None (a field without weeds)."""
    cam, d, c, tan_a = rays
    nt, npx = tan_a.shape[0], d.shape[0] // tan_a.shape[0]
    n = d.shape[0]
    o = jnp.broadcast_to(cam, d.shape)
    t_min = jnp.full((n,), cfg.near, jnp.float32)
    far = jnp.full((n,), cfg.far, jnp.float32)
    with jax.named_scope("rd_terrain"):
        if cfg.kernel == "pallas":
            t_ter, n_ter = pallas.trace_terrain(field.terrain, field.terrain_size, o, d, t_min, far,
                                                cfg.terrain_steps, cfg.terrain_refine, npx)
        else:
            t_ter, n_ter = render_terrain.trace_terrain(
                field.terrain,
                field.terrain_size,
                o,
                d,
                t_min,
                far,
                cfg.terrain_steps,
                cfg.terrain_refine,
            )
    sweep = render_tiles.camera_sweep(cam, c, tan_a)
    oc = tuple(jnp.reshape(cam[i], (1, 1)) for i in range(3))
    with jax.named_scope("rd_obstacles"):
        oid, oent = render_tiles.cull_obstacles(obst, *sweep, jnp.full((nt,), cfg.far, jnp.float32),
                                                cfg.obstacle_keep)
        t_obs, n_obs, branch = geom.trace_obstacles_tiled(obst, oid, oent, oc,
                                                          geom.xyz(d.reshape(nt, npx, 3)),
                                                          t_min.reshape(nt, npx))
        t_obs, branch = t_obs.reshape(-1), branch.reshape(-1)
    t_far = jnp.minimum(jnp.minimum(t_ter, t_obs), far)
    t_wd = jnp.full((n,), INF)
    if wtab is not None:
        with jax.named_scope("rd_weeds"):
            t_cut = t_far.reshape(nt, npx)
            wid, went = render_tiles.cull_weeds(wtab, *sweep, jnp.max(t_cut, axis=1),
                                                cfg.weed_keep)
            t_wd, weed, k_wd = (x.reshape(-1) for x in render_tiles.exact(
                wtab, wid, went, oc, geom.xyz(d.reshape(nt, npx, 3)), t_min.reshape(nt, npx),
                t_cut, kernel=cfg.kernel))
        t_far = jnp.minimum(t_far, t_wd)
    t_pl, plant, k = _trace_plants(shape, tab, sweep, oc, d.reshape(nt, npx, 3),
                                   t_far.reshape(nt, npx), cfg)
    cls = jnp.where(jnp.isfinite(t_pl), PLANT,
                    jnp.where(jnp.isfinite(t_wd), WEED,
                              jnp.where((t_obs < t_ter) & (t_obs < cfg.far), OBSTACLE,
                                        jnp.where(t_ter < cfg.far, SOIL, SKY))))
    t = jnp.where(cls == PLANT, t_pl, jnp.where(cls == OBSTACLE, t_obs, t_ter))
    t = jnp.where(cls == WEED, t_wd, t)
    t = jnp.where(cls == SKY, 0.0, t)
    p = o + t[:, None] * d
    with jax.named_scope("rd_plant_normal"):
        n_pl, local = geom.plant_normal(tab, plant, k, p)
    surf = _Surface(material=jnp.asarray(tab.material)[k], base=tab.base[plant], item=plant, k=k)
    if wtab is not None:
        with jax.named_scope("rd_weed_normal"):
            n_wd, local_wd = geom.plant_normal(wtab, weed, k_wd, p)
        is_weed = cls == WEED
        n_pl = jnp.where(is_weed[:, None], n_wd, n_pl)
        local = jnp.where(is_weed[:, None], local_wd, local)
        surf = _Surface(material=jnp.where(is_weed, crops_prims.WEED, surf.material),
                        base=jnp.where(is_weed[:, None], wtab.base[weed], surf.base),
                        item=jnp.where(is_weed, tab.base.shape[0] + wtab.index[weed], plant),
                        k=jnp.where(is_weed, k_wd, k))
    normal = jnp.where(((cls == PLANT) | (cls == WEED))[:, None], n_pl,
                       jnp.where((cls == OBSTACLE)[:, None], n_obs, n_ter))
    return t, cls, p, normal, local, surf, branch


def _trace_plants(shape, tab, sweep, oc, d, t_far, cfg):
    """Nearest plant hit of the camera rays d [T, P, 3] (t_far [T, P]; `sweep` the tiles'
    `camera_sweep`, oc the camera as (x, y, z) of [1, 1]): every tile's first
    `keep` candidates, then the deep tiles' first `deep_keep` of a longer window. Returns
    flat (t [N] (+inf: none), plant int32 [N], k int32 [N])."""
    nt = d.shape[0]
    P = shape.max_plants_per_row
    o, cc, g, tau = sweep
    with jax.named_scope("rd_cull"):
        ids, entry, rest, reach = render_tiles.cull(tab, P, o, cc, g, tau,
                                                    jnp.max(t_far, axis=1), cfg.row_blocks,
                                                    cfg.block_keep, cfg.keep)
    t_min = jnp.full(t_far.shape, cfg.near, jnp.float32)
    with jax.named_scope("rd_exact"):
        t, plant, k = render_tiles.exact(tab, ids, entry, oc, geom.xyz(d), t_min, t_far,
                                         kernel=cfg.kernel)
    n_deep = min(nt, int(np.ceil(cfg.deep_share * nt)))
    with jax.named_scope("rd_deep"):
        if cfg.deep_keep > 0 and n_deep > 0:
            u = jnp.minimum(t, t_far)  # nothing beyond a ray's current hit matters
            cut = jnp.max(u, axis=1)
            # plants that may still be nearer than some ray's hit: past the kept ones, or kept
            # plants entered before the cut beyond the first `keep`
            score = jnp.where(rest > 0, rest + jnp.sum(entry < cut[:, None], 1), 0)
            score, sel = jax.lax.top_k(score.astype(jnp.float32), n_deep)
            t2, plant2, k2 = _deep_pass(tab, P, (o[sel], cc[sel], g[sel], tau[sel]), d[sel],
                                        t_min[sel], u[sel], score > 0, reach[sel], oc, cfg)
            better = t2 < t[sel]
            # top_k's indices are distinct: a plain scatter, also under deterministic ops
            t = t.at[sel].set(jnp.where(better, t2, t[sel]), unique_indices=True)
            plant = plant.at[sel].set(jnp.where(better, plant2, plant[sel]), unique_indices=True)
            k = k.at[sel].set(jnp.where(better, k2, k[sel]), unique_indices=True)
    return t.reshape(-1), plant.reshape(-1), k.reshape(-1)


def _deep_pass(tab, P, sweep, d, t_min, u, live, reach, oc, cfg):
    """The deep tiles' second cull and exact test (sweep: their `camera_sweep`, d [D, Q, 3]
    their rays, t_min and u [D, Q] the rays' near limit and current hits, live [D] tiles with
    plants left to test, reach [D] how far along their rays the first pass held every plant,
    `cull`'s): each tile, or each of its `deep_split`² sub-tiles (its own cone and cut, so a
    sub-tile over near hits keeps few plants and one over the far field keeps far ones),
    keeps the `deep_keep` plants its sweep enters first beyond the first pass's reach (the
    next layer: on a view over many rows of small plants the plants a far ray meets lie
    behind hundreds that its tile's cone grazes), within a window of `deep_row_blocks`.
    Returns (t, plant, k) [D, Q]."""
    D, Q = u.shape
    n = cfg.deep_split
    ts = int(round(np.sqrt(Q)))
    m = n * n
    split = n > 1 and ts % n == 0 and pallas.supported(Q // m)
    if split:  # the rays regrouped sub-tile-major: [D·m, Q/m]
        r = np.arange(ts).reshape(n, ts // n)
        order = (r[:, None, :, None] * ts + r[None, :, None, :]).reshape(-1)
        d, t_min, u = (x[:, order].reshape(D * m, Q // m, *x.shape[2:]) for x in (d, t_min, u))
        sweep = render_tiles.camera_sweep(sweep[0][:1], *render_tiles.cone(d))
        live, reach = jnp.repeat(live, m), jnp.repeat(reach, m)
    # a ray point at distance t ≥ reach projects on the centre ray at s ≥ reach · cos α
    s_min = reach / jnp.sqrt(1.0 + sweep[3] ** 2)
    ids, entry, *_ = render_tiles.cull(tab, P, *sweep, jnp.max(u, axis=1),
                                       cfg.deep_row_blocks, cfg.deep_block_keep, cfg.deep_keep,
                                       s_min=s_min)
    entry = jnp.where(live[:, None], entry, INF)
    out = render_tiles.exact(tab, ids, entry, oc, geom.xyz(d), t_min, u, kernel=cfg.kernel)
    if split:
        out = tuple(x.reshape(D, Q)[:, np.argsort(order)] for x in out)
    return out


def _rotate(v, rot):
    """Camera-frame vectors v [N, 3] → world frame (elementwise: no tiny matrix product)."""
    return v[:, 0:1] * rot[:, 0] + v[:, 1:2] * rot[:, 1] + v[:, 2:3] * rot[:, 2]


def _setup(field, shape, cam_pos, cam_rot, intr, cfg, table=None):
    """Field with its terrain in memory, plant table, obstacle table, weed table (None: the
    shape holds no weeds), rays (camera [3], directions [N, 3] tile-major, tile centres
    [T, 3], tan of the tile half-angles [T]), |z = −1 pixel ray| [N], tile grid."""
    # a terrain generated in the same jit must be in memory before the per-ray gathers
    field = field.replace(terrain=geom.materialise(field.terrain))
    dirs, norm, centre, tan_a, tiles = render_tiles.tile_layout(intr.width, intr.height, intr.fovy,
                                                      cfg.tile)
    cam_pos = jnp.asarray(cam_pos, jnp.float32)
    cam_rot = jnp.asarray(cam_rot, jnp.float32)
    d = _rotate(jnp.asarray(dirs.reshape(-1, 3)), cam_rot)
    c = _rotate(jnp.asarray(centre), cam_rot)
    with jax.named_scope("rd_table"):
        tab = geom.plant_table(field, shape) if table is None else table
    obst = geom.obstacle_table(field, cam_pos, -cam_rot[:, 2],
                            min(cfg.obstacles, shape.obstacle_slots))
    wtab = None
    if shape.weed_slots > 0:
        with jax.named_scope("rd_weed_table"):
            wtab = render_weeds.table(field, cam_pos, cam_rot, intr,
                                      min(cfg.weeds, shape.weed_slots))
    rays = (cam_pos, d, c, jnp.asarray(tan_a))
    return field, tab, obst, wtab, rays, jnp.asarray(norm.reshape(-1)), tiles


def geometry(
    field: mjxrow_field.Field,
    shape: mjxrow_field.FieldShape,
    cam_pos: jax.Array,
    cam_rot: jax.Array,
    intr: Intrinsics,
    cfg: RenderConfig = DEFAULT_CONFIG,
    table: PlantTable | None = None,
) -> tuple[jax.Array, jax.Array]:
    """What `render` sees, without shading: (depth float32 [H, W] (metres along the optical
    axis, SKY_DEPTH for sky), classes uint8 [H, W]). Same arguments as `render`."""
    cfg = resolve(cfg, shape.crop, intr)
    field, tab, obst, wtab, rays, norm, tiles = _setup(field, shape, cam_pos, cam_rot, intr,
                                                       cfg, table)
    t, cls, *_ = _trace(field, shape, tab, obst, wtab, rays, cfg)
    depth = jnp.where(cls == SKY, SKY_DEPTH, t / norm).astype(jnp.float32)
    to_image = functools.partial(_image, tiles=tiles, intr=intr)
    return to_image(depth), to_image(cls.astype(jnp.uint8))


def _image(x, tiles, intr):
    """Flat tile-major [N, ...] → [H, W, ...]."""
    nt = tiles[0] * tiles[1]
    return render_tiles.untile(x.reshape((nt, -1) + x.shape[1:]), tiles, intr.height, intr.width)


def render(
    field: mjxrow_field.Field,
    shape: mjxrow_field.FieldShape,
    cam_pos: jax.Array,
    cam_rot: jax.Array,
    intr: Intrinsics,
    cond: Conditions,
    key: jax.Array | None = None,
    cfg: RenderConfig = DEFAULT_CONFIG,
    table: PlantTable | None = None,
) -> Frame:
    """Render ONE field from ONE camera (pure; jit and vmap outside).

    field: one `Field` (no batch axis); shape, intr, cfg: static. cam_pos float32 [3] [m],
    cam_rot float32 [3, 3] (columns right, up, backwards). cond: `conditions(name)`. key: None
    for a deterministic image, or a PRNG key for sensor noise and exposure variation
    (augmentation). table: `plant_table(field, shape)` computed once for many frames of the
    same field (an episode), or None to compute it here. Returns a `Frame` of [H, W] images."""
    cfg = resolve(cfg, shape.crop, intr)
    with jax.named_scope("rd_setup"):
        field, tab, obst, wtab, rays, norm, tiles = _setup(field, shape, cam_pos, cam_rot,
                                                           intr, cfg, table)
    d = rays[1]
    t, cls, p, normal, local, surf, is_branch = _trace(field, shape, tab, obst, wtab, rays, cfg)
    if cfg.settle == "barrier":
        p, normal, local = jax.lax.optimization_barrier((p, normal, local))
    with jax.named_scope("rd_shadow"):
        if cfg.shadows:  # the sun's visibility, the shadow weakened by cond.shadow
            lit = render_light.sun_visibility(field, shape, tab, obst, wtab, p, normal, cls,
                                              cond, cfg, tiles[0] * tiles[1])
            vis = 1.0 - cond.shadow * (1.0 - lit)
        else:
            vis = jnp.ones_like(t)

    albedo, normal, sky = shade.surfaces(shape.crop, cls, surf.material, p, local,
                                         surf.base[:, 2], surf.item, surf.k, is_branch, normal,
                                         d, cond, keep=functools.partial(_settle, how=cfg.settle))
    # light: sky ambient (occluded near plants and under canopies) + sun (shadowed); weeds are
    # lit as leaves
    leafy = (cls == PLANT) | (cls == WEED)
    ndl = jnp.sum(normal * cond.sun_dir, -1)
    rel_h = jnp.clip((p[:, 2] - surf.base[:, 0]) / jnp.maximum(surf.base[:, 1], 1e-3), 0.0, 1.0)
    ao = jnp.where(leafy, 0.45 + 0.55 * jnp.sqrt(rel_h), render_light.ground_occlusion(tab, p))
    sun = jnp.maximum(ndl, 0.0) + jnp.where(leafy, 0.3 * jnp.maximum(-ndl, 0.0), 0.0)
    # the per-pixel terms once, not once per colour channel
    albedo, ao, sun, vis = _settle((albedo, ao, sun, vis), cfg.settle)
    light = ao[:, None] * cond.ambient + (vis * sun)[:, None] * cond.sun_rgb
    radiance = albedo * light
    fog = 1.0 - jnp.exp(-t / cond.haze)
    radiance = radiance + (cond.sky_horizon - radiance) * fog[:, None]
    radiance = jnp.where((cls == SKY)[:, None], sky, radiance)

    exposure = cond.exposure
    if key is not None:
        k_exp, k_noise, k_wb = jax.random.split(key, 3)
        exposure = exposure * jnp.exp(0.15 * jax.random.normal(k_exp, ()))
        radiance = radiance * (1.0 + 0.03 * jax.random.normal(k_wb, (3,)))
    radiance = _settle(radiance, cfg.settle)
    to_image = functools.partial(_image, tiles=tiles, intr=intr)
    img = to_image(jnp.clip(radiance * exposure, 0.0, 1.0) ** (1.0 / 2.2))  # [H, W, 3]
    if key is not None:
        img = img + cond.noise * jax.random.normal(k_noise, img.shape)
    rgb = jnp.clip(jnp.round(img * 255.0), 0, 255).astype(jnp.uint8)

    depth = jnp.where(cls == SKY, SKY_DEPTH, t / norm)
    return Frame(rgb=rgb, depth=to_image(depth.astype(jnp.float32)),
                 mask=to_image(cls == PLANT), classes=to_image(cls.astype(jnp.uint8)))
