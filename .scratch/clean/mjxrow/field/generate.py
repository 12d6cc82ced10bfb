"""Field generation: the terrain (one triangulation, as MuJoCo's heightfield), plants, rows,
lanes and obstacles of one field from its FieldParams, static FieldShape and a PRNG key."""

from __future__ import annotations

import jax
import jax.numpy as jnp

from mjxrow.field import lanes as field_lanes
from mjxrow.field.params import (
    BRANCH,
    LANE_CLEARANCE,
    N_TERRAIN_MODES,
    ROBOT_WIDTH,
    STONE,
    Field,
    FieldParams,
    FieldShape,
    _layout,
    _scaled,
    checks,
)

# ---------------------------------------------------------------------------------------------
# Terrain


def terrain_axes(terrain_size: jax.Array, cells: tuple[int, int]) -> tuple[jax.Array, jax.Array]:
    """Sample coordinates: x [NX] and y [NY] in metres (MuJoCo hfield layout: row j ↔ y)."""
    ny, nx = cells
    x = (jnp.linspace(0.0, 1.0, nx) - 0.5) * terrain_size[0]
    y = (jnp.linspace(0.0, 1.0, ny) - 0.5) * terrain_size[1]
    return x, y


def terrain_height(terrain: jax.Array, terrain_size: jax.Array, x: jax.Array,
                   y: jax.Array) -> jax.Array:
    """Height [m] of the terrain surface at (x, y) (any matching shapes), matching MuJoCo's
    heightfield triangulation: each cell is split along the diagonal from (i, j) to
    (i + 1, j + 1). Points outside the grid take the nearest edge height."""
    ny, nx = terrain.shape
    u = jnp.clip((x / terrain_size[0] + 0.5) * (nx - 1), 0.0, nx - 1 - 1e-4)
    v = jnp.clip((y / terrain_size[1] + 0.5) * (ny - 1), 0.0, ny - 1 - 1e-4)
    i = jnp.floor(u).astype(jnp.int32)
    j = jnp.floor(v).astype(jnp.int32)
    fu, fv = u - i, v - j
    h00 = terrain[j, i]
    h10 = terrain[j, i + 1]
    h01 = terrain[j + 1, i]
    h11 = terrain[j + 1, i + 1]
    lower = h00 + fu * (h10 - h00) + fv * (h11 - h10)  # triangle (00, 10, 11): fu >= fv
    upper = h00 + fv * (h01 - h00) + fu * (h11 - h01)  # triangle (00, 01, 11): fv > fu
    return jnp.where(fu >= fv, lower, upper)


def _terrain(q, lay, cells, key) -> tuple[jax.Array, jax.Array]:
    size = jnp.stack([q["terrain_length"], lay["ground_width"]])
    x, y = terrain_axes(size, cells)
    kd, kp, ka = jax.random.split(key, 3)
    # isotropic band-limited noise: wavelengths spread around terrain_scale
    ang = jax.random.uniform(kd, (N_TERRAIN_MODES,), maxval=2 * jnp.pi)
    lam = q["terrain_scale"] * jnp.exp(jax.random.uniform(ka, (N_TERRAIN_MODES,), minval=-0.7,
                                                          maxval=0.7))
    k = 2 * jnp.pi / lam
    phase = jax.random.uniform(kp, (N_TERRAIN_MODES,), maxval=2 * jnp.pi)
    amp = lam / q["terrain_scale"]  # longer waves a little stronger
    # Σ_m amp·cos(kx·x + ky·y + φ), separated into two [NY, M] × [M, NX] products
    ax = x[None, :] * (k * jnp.cos(ang))[:, None] + phase[:, None]  # [M, NX]
    by = y[:, None] * (k * jnp.sin(ang))[None, :]  # [NY, M]
    rough = (jnp.cos(by) * amp) @ jnp.cos(ax) - (jnp.sin(by) * amp) @ jnp.sin(ax)
    rough = rough - 0.5 * (rough.max() + rough.min())
    rough = rough / jnp.maximum(rough.max() - rough.min(), 1e-6) * q["terrain_dh"]
    heights = rough + q["slope_x"] * x[None, :] + q["slope_y"] * y[:, None]
    return heights.astype(jnp.float32), size


# ---------------------------------------------------------------------------------------------
# Generation


START_CLEAR = 0.5  # m: no obstacle reaches within this of the episode start's x (any lane)
PATH_LENGTH = 20.0  # m, default start → row end distance (sim.SimConfig.path_length)


def _clear_start(ox: jax.Array, size: jax.Array, yaw: jax.Array, x_start: jax.Array,
                 row_length: jax.Array, key: jax.Array) -> jax.Array:
    """Obstacle centres x [S] (uniform over the row, [−row_length/2, row_length/2]) with those
    whose x extent (radius + |half length · cos yaw|) comes within START_CLEAR of `x_start`
    drawn again, uniformly over the rest of the row: the robot never starts on or in an
    obstacle, and the obstacles outside the zone keep their places."""
    ext = size[:, 0] + size[:, 1] * jnp.abs(jnp.cos(yaw))
    lo, hi = -0.5 * row_length, 0.5 * row_length
    z0 = jnp.clip(x_start - START_CLEAR - ext, lo, hi)
    z1 = jnp.clip(x_start + START_CLEAR + ext, lo, hi)
    u = lo + jax.random.uniform(key, ox.shape) * (row_length - (z1 - z0))
    redraw = jnp.where(u >= z0, u + (z1 - z0), u)
    return jnp.where((ox > z0) & (ox < z1), redraw, ox)


def generate(params: FieldParams, shape: FieldShape, key: jax.Array,
             path_length: float | jax.Array = PATH_LENGTH) -> Field:
    """One field from scalar `params` (pure, jittable; vmap over params and key for a batch).

    path_length: m, where episodes start: `path_length` before the row end on every lane
    (sim.reset, `sim_cfg.path_length`; traced or static). Obstacles are kept START_CLEAR
    metres (along x, across the whole field) away from that start, so no robot starts on or
    inside one; pass the episodes' own path_length when it is not the default."""
    R, P, S = shape.max_rows, shape.max_plants_per_row, shape.obstacle_slots
    q = _scaled(params)
    lay = _layout(q)
    k_ter, k_pos, k_size, k_yaw, k_phase, k_miss, k_obs = jax.random.split(key, 7)

    terrain, tsize = _terrain(q, lay, shape.terrain_cells, k_ter)
    # keys of the later additions come from fold_in, so that a field without them is the same
    # field, plant for plant, as before they existed
    row_phase = jax.random.uniform(jax.random.fold_in(key, 101), (), maxval=2 * jnp.pi)
    bend = field_lanes.Bend(curvature=q["row_curvature"], amplitude=q["row_amplitude"],
                            wavelength=q["row_wavelength"], phase=row_phase)

    # rows: groups of rows_per_group, centred on y = 0
    r = jnp.arange(R, dtype=jnp.float32)
    rpg = q["rows_per_group"]
    g, jr = jnp.floor(r / rpg), jnp.mod(r, rpg)
    span = (lay["n_groups"] - 1.0) * lay["pitch"] + lay["group_w"]
    row_y = -0.5 * span + g * lay["pitch"] + jr * q["d_rr"]
    row_active = r < lay["n_rows"]
    row_y = jnp.where(row_active, row_y, 0.0)

    # plants on each row
    x0 = -0.5 * q["row_length"]
    i = jnp.arange(P, dtype=jnp.float32)
    jit_xy = jax.random.normal(k_pos, (R, P, 2)) * q["plant_jitter"]
    ps = x0 + i[None, :] * q["d_pp"] + jit_xy[..., 0]
    pu = row_y[:, None] + jit_xy[..., 1]
    px, py = field_lanes.to_world(bend, ps, pu)
    pz = terrain_height(terrain, tsize, px, py)
    size_nom = jnp.stack([q["plant_length"], q["plant_width"], q["plant_height"]])
    size_f = jnp.clip(1.0 + q["plant_size_var"] * jax.random.normal(k_size, (R, P, 1)), 0.5, 1.5)
    plant_active = (
        row_active[:, None]
        & (i[None, :] < lay["n_plants"])
        & (jax.random.uniform(k_miss, (R, P)) >= q["p_missing"])
        & ~gap_runs(q, (R, P), jax.random.fold_in(key, 102))
    )
    plant_yaw = jax.random.uniform(k_yaw, (R, P), minval=-jnp.pi, maxval=jnp.pi)

    # lanes between consecutive rows
    lane_y = 0.5 * (row_y[1:] + row_y[:-1])
    lane_width = row_y[1:] - row_y[:-1]
    lane_active = row_active[1:] & row_active[:-1]

    # obstacles in the lanes: first the stones, then the branches
    ko = jax.random.split(k_obs, 6)
    s = jnp.arange(S, dtype=jnp.float32)
    is_stone = s < lay["n_stones"]
    obst_active = s < lay["n_stones"] + lay["n_branches"]
    n_lanes = jnp.maximum(lay["n_rows"] - 1.0, 1.0)
    lane_idx = jnp.floor(jax.random.uniform(ko[0], (S,)) * n_lanes).astype(jnp.int32)
    lane_idx = jnp.clip(lane_idx, 0, R - 2)
    free = jnp.maximum(lane_width[lane_idx] - q["plant_width"], 0.2)
    ou = lane_y[lane_idx] + (jax.random.uniform(ko[1], (S,)) - 0.5) * 0.8 * free
    os_ = (jax.random.uniform(ko[2], (S,)) - 0.5) * q["row_length"]
    stone_r = q["scale"] * jax.random.uniform(ko[3], (S,), minval=0.03, maxval=0.08)
    branch_r = q["scale"] * jax.random.uniform(ko[3], (S,), minval=0.015, maxval=0.035)
    branch_half = q["scale"] * jax.random.uniform(ko[4], (S,), minval=0.25, maxval=0.7)
    radius = jnp.where(is_stone, stone_r, branch_r)
    obst_size = jnp.stack([radius, jnp.where(is_stone, 0.0, branch_half)], -1)
    obst_yaw = jax.random.uniform(ko[5], (S,), minval=-jnp.pi, maxval=jnp.pi)
    x_end = x0 + (lay["n_plants"] - 1.0) * q["d_pp"]
    os_ = _clear_start(os_, obst_size, obst_yaw, x_end - path_length, q["row_length"],
                       jax.random.fold_in(k_obs, 6))
    ox, oy = field_lanes.to_world(bend, os_, ou)
    obst_yaw = obst_yaw + field_lanes.heading(bend, os_, ou)
    # stones sunk to half their radius; branches lie on the ground
    oz = terrain_height(terrain, tsize, ox, oy) + jnp.where(is_stone, 0.5, 1.0) * radius
    obst_pos = jnp.stack([ox, oy, oz], -1)

    valid = jnp.all(jnp.stack([jnp.all(ok) for ok, _ in checks(params, shape).values()]))
    return Field(
        params=params,
        plant_pos=jnp.stack([px, py, pz], -1).astype(jnp.float32),
        plant_size=(size_nom * size_f).astype(jnp.float32),
        plant_yaw=plant_yaw.astype(jnp.float32),
        plant_heading=field_lanes.heading(bend, ps, pu).astype(jnp.float32),
        plant_phase=jax.random.uniform(k_phase, (R, P)),
        plant_active=plant_active,
        plant_row=jnp.broadcast_to(jnp.arange(R, dtype=jnp.int32)[:, None], (R, P)),
        row_y=row_y.astype(jnp.float32),
        row_active=row_active,
        row_x=jnp.stack([x0, x_end]).astype(jnp.float32),
        row_phase=row_phase.astype(jnp.float32),
        lane_y=lane_y.astype(jnp.float32),
        lane_width=lane_width.astype(jnp.float32),
        lane_active=lane_active,
        terrain=terrain,
        terrain_size=tsize.astype(jnp.float32),
        obst_pos=obst_pos.astype(jnp.float32),
        obst_size=obst_size.astype(jnp.float32),
        obst_yaw=obst_yaw.astype(jnp.float32),
        obst_kind=jnp.where(is_stone, STONE, BRANCH).astype(jnp.int32),
        obst_active=obst_active,
        **_weeds(q, lay, bend, row_y, row_active, x0, shape.weed_slots, terrain, tsize,
                 jax.random.fold_in(key, 103)),
        n_rows=lay["n_rows"].astype(jnp.int32),
        valid=valid,
    )


def gap_runs(q: dict, rp: tuple[int, int], key: jax.Array) -> jax.Array:
    """bool [R, P]: plant slots inside a gap. Along each row a two-state chain (planted ↔ gap)
    from slot to slot: a gap lasts a geometric number of slots with mean gap_length / d_pp
    (leaving with probability q = d_pp / gap_length, at most 1: a gap is at least one plant),
    and starts with the probability p that makes gap_rate gaps per 10 m on average (the
    chain's stationary rate of starts, p·q / (p + q) per slot, equals gap_rate · d_pp / 10).
    With gap_rate = 0 no slot is in a gap."""
    R, P = rp
    leave = jnp.clip(q["d_pp"] / q["gap_length"], 1e-6, 1.0)
    r = q["gap_rate"] * q["d_pp"] / 10.0
    enter = jnp.clip(r * leave / jnp.maximum(leave - r, 1e-9), 0.0, 1.0)
    u = jax.random.uniform(key, (P, R))
    first = u[0] < enter / jnp.maximum(enter + leave, 1e-9)  # the chain's stationary start

    def slot(gap, u_i):
        gap = jnp.where(gap, u_i >= leave, u_i < enter)
        return gap, gap

    _, rest = jax.lax.scan(slot, first, u[1:])
    return jnp.concatenate([first[None], rest]).T


def _weeds(q, lay, bend, row_y, row_active, x0, W, terrain, tsize, key) -> dict:
    """The weeds of a field: `n_weeds` (weed_density per m² over the rows' length and the
    ground from the first row to the last), uniform over it, each `weed_size` wide
    (± 25 %, clipped to 0.5–1.5×) and 0.35 of that high, turned at random."""
    if W == 0:
        z = jnp.zeros((0,), jnp.float32)
        return dict(weed_pos=jnp.zeros((0, 3), jnp.float32), weed_size=jnp.zeros((0, 2)),
                    weed_yaw=z, weed_phase=z, weed_active=jnp.zeros((0,), bool))
    ks = jax.random.split(key, 5)
    lo = jnp.min(jnp.where(row_active, row_y, jnp.inf))
    ws = x0 + jax.random.uniform(ks[0], (W,)) * q["row_length"]
    wu = lo + jax.random.uniform(ks[1], (W,)) * lay["span"]
    wx, wy = field_lanes.to_world(bend, ws, wu)
    wz = terrain_height(terrain, tsize, wx, wy)
    d = q["weed_size"] * jnp.clip(1.0 + 0.25 * jax.random.normal(ks[2], (W,)), 0.5, 1.5)
    return dict(weed_pos=jnp.stack([wx, wy, wz], -1).astype(jnp.float32),
                weed_size=jnp.stack([d, 0.35 * d], -1).astype(jnp.float32),
                weed_yaw=jax.random.uniform(ks[3], (W,), maxval=2 * jnp.pi),
                weed_phase=jax.random.uniform(ks[4], (W,)),
                weed_active=jnp.arange(W) < lay["n_weeds"])


LANE_MODES = ("auto", "in_group", "between_groups")  # robot_lane's choices (sim.SimConfig.lane)


def robot_lane(field: Field, robot_width: float = ROBOT_WIDTH, mode: str = "auto") -> jax.Array:
    """Index of the lane the robot drives (traced int32 []): of the active lanes of the kind
    `mode` picks, the one nearest the field centre (y = 0) whose free width (lane width − plant
    width) fits the robot (`robot_width` + LANE_CLEARANCE).

    mode (static): "auto" prefers the lanes inside a group and falls back to the lanes between
    groups when no in-group lane fits (lettuce and chard, or a narrow `d_rr`), so the lane
    kind can change along a d_rr sweep; "in_group" takes only lanes between two rows of one
    group (`d_rr` apart), "between_groups" only lanes between two groups (`d_RR` apart; with
    rows_per_group = 1 every lane). Where no lane of the kind fits, the nearest lane of the
    kind is returned (or, when there is none, the nearest fitting lane): traced code cannot
    raise, so check the request on the host first with `sim.check_lane`."""
    if mode not in LANE_MODES:
        raise ValueError(f"sim.lane: unknown lane mode {mode!r}; expected one of {LANE_MODES}")
    q = _scaled(field.params)
    free = field.lane_width - q["plant_width"]
    fits = field.lane_active & (free >= robot_width + LANE_CLEARANCE)
    lane = jnp.arange(field.lane_y.shape[-1], dtype=jnp.float32)
    in_group = jnp.mod(lane + 1.0, q["rows_per_group"]) != 0
    if mode == "auto":
        prefer_group = jnp.any(fits & in_group)
        penalty = jnp.where(fits, 0.0, 1e6) + jnp.where(prefer_group & ~in_group, 1e3, 0.0)
    else:
        kind = in_group if mode == "in_group" else ~in_group
        penalty = (jnp.where(fits, 0.0, 1e3) + jnp.where(kind, 0.0, 1e4)
                   + jnp.where(field.lane_active, 0.0, 1e6))
    return jnp.argmin(jnp.abs(field.lane_y) + penalty).astype(jnp.int32)
