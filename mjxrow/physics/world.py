"""Every world written into the MJX model of `mjxrow.physics.model` (pure, jittable; vmap
over the field): its terrain patch, the obstacles near its lane and the colliding contact slots.

- `world_model(mx, field, lane, sim_cfg) -> mjx.Model`: this world's patch heights
  (`hfield_data`), the patch's placement and the obstacles near the lane (`geom_pos`,
  `geom_quat`, `geom_size`) written into the model (pure; vmap it with a batched `field`).
- `refresh_contacts(mx, points)`: the contact slots filled with the obstacles nearest the
  robot's wheels (`sim.step` does this every control period).
- `world_mjmodel(m, mx_world)`: one world's arrays written back into the C model.
- `patch_frame`, `to_patch`, `patch_yaw`, `patch_heights`: where the patch lies and its heights;
  `obstacles_dropped`: obstacles on the patch that found no slot.

Terrain patch. `hfield_size` is static in MJX while a field's terrain extent is traced, and a
whole field's grid would be mostly unused: the physics terrain is a patch of static size around
the driven lane, `path_length + patch_back + patch_front` long (x) and `patch_width` wide (y),
sampled every ≈`patch_cell` metres with `field.terrain_height` (which follows MuJoCo's own
triangulation) and placed by the terrain geom's position. Heights are stored as
(h − h_min) / `patch_z` in [0, 1] and the geom sits at z = h_min, so `patch_z` (static) must
exceed the height range over the patch: |ΔH| ≤ 0.3 m plus a 10 % slope over 24 m × 6 m is 3.3 m,
below the default 4 m (float32 keeps 0.5 mm resolution at that range). A robot leaving the patch
falls off its edge: `sim.off_patch` tells when. With cells ≥ 0.196 m a wheel of radius 0.098 m
touches a 2×2-cell sub-grid (8 prisms) per step instead of 3×3 (18 prisms).

Obstacles. Stones and fallen branches are capsules (a stone is a capsule of half length
`_STONE_HALF` ≈ 0: a sphere), so one geom holds either kind and geom types stay static. Per
world, `obst_{i}` geoms (K = min(sim_cfg.obstacle_candidates, shape.obstacle_slots)) take the
field's active obstacles that lie on the patch, nearest the lane's centre line first (more than K
are left out: `obstacles_dropped` counts them); unused ones are parked 100 m below the patch.
These geoms do not collide: MJX has no broadphase, so every colliding pair costs every step
(4 contacts per wheel on the terrain, 1 per wheel and obstacle, 4 constraint rows each), and
6 colliding obstacle geoms made a step 2.3× slower than 1. Instead J = sim_cfg.obstacle_slots
colliding `contact_{j}` geoms are filled, at the start of every control period, with copies of
the J obstacles nearest to any wheel (`refresh_contacts`); in one period the robot moves
≤ 3.5 cm, so this is exact unless more than J obstacles are within a wheel's reach in the same
period (two obstacles under two wheels at once). Default J = 1 (J = 2 cost 1.45× on CPU); set
`obstacle_slots=2` for fields dense with obstacles. Contacts are
only wheel↔terrain and wheel↔obstacle (plus chassis↔both with `chassis_contacts`, off by
default: a stone taller than the chassis' 6 cm clearance between the wheels passes through it);
plants take no part in physics.
"""

from __future__ import annotations

import copy

import jax
import jax.numpy as jnp
import mujoco
import numpy as np

from mjxrow import field as mjxrow_field
from mjxrow.field import lanes as field_lanes
from mjxrow.physics.model import (
    _PARK_DEPTH,
    _STONE_HALF,
    WORLD_FIELDS,
    SimConfig,
    _geom_ids,
    _obstacle_counts,
)
from mjxrow.physics.quiet import mjx


def _quat_mul(a: jax.Array, b: jax.Array) -> jax.Array:
    aw, ax, ay, az = jnp.moveaxis(a, -1, 0)
    bw, bx, by, bz = jnp.moveaxis(b, -1, 0)
    return jnp.stack([aw * bw - ax * bx - ay * by - az * bz,
                      aw * bx + ax * bw + ay * bz - az * by,
                      aw * by - ax * bz + ay * bw + az * bx,
                      aw * bz + ax * by - ay * bx + az * bw], -1)


def _axis_quat(angle: jax.Array, axis: int) -> jax.Array:
    """Quaternion(s) [..., 4] (w, x, y, z) of a rotation by `angle` [rad] about x, y or z."""
    h = 0.5 * jnp.asarray(angle, jnp.float32)
    parts = [jnp.cos(h)] + [jnp.sin(h) if k == axis else jnp.zeros_like(h) for k in range(3)]
    return jnp.stack(parts, -1)


PATCH_SAMPLES = 17  # points of a curved lane's centre line that place its patch


def patch_frame(field: mjxrow_field.Field, lane: jax.Array, sim_cfg: SimConfig) -> jax.Array:
    """float32 [3]: the patch centre (x, y) [m] and its direction (yaw [rad]) for `lane`.
    Along the lane it spans [row end − path_length − patch_back, row end + patch_front].
    Straight rows: along x, centred on the lane's centre line. Curved rows: along the chord
    between those two points of the centre line, centred across on the line's excursion from
    the chord (the patch turns with the rows; `patch_width` must hold the excursion)."""
    x_end = field.row_x[1]
    cx = x_end + 0.5 * (sim_cfg.patch_front - sim_cfg.path_length - sim_cfg.patch_back)
    ln = field_lanes.lane(field, lane)
    pts = field_lanes.polyline(ln, x_end - sim_cfg.path_length - sim_cfg.patch_back,
                               x_end + sim_cfg.patch_front, PATCH_SAMPLES)
    chord = pts[-1] - pts[0]
    yaw = jnp.arctan2(chord[1], chord[0])
    normal = jnp.stack([-jnp.sin(yaw), jnp.cos(yaw)])
    mid = 0.5 * (pts[0] + pts[-1])
    across = (pts - mid) @ normal
    c = mid + 0.5 * (jnp.max(across) + jnp.min(across)) * normal
    straight = (ln.bend.curvature == 0) & (ln.bend.amplitude == 0)
    return jnp.where(straight, jnp.stack([cx, field.lane_y[lane], 0.0]),
                     jnp.stack([c[0], c[1], yaw])).astype(jnp.float32)


def to_patch(frame: jax.Array, x: jax.Array, y: jax.Array) -> tuple[jax.Array, jax.Array]:
    """World (x, y) → the patch's own frame (origin at its centre, x along it), for a patch
    `frame` [3] (x, y, yaw) as `patch_frame` gives (the identity shift on straight rows)."""
    c, s = jnp.cos(frame[2]), jnp.sin(frame[2])
    dx, dy = x - frame[0], y - frame[1]
    return c * dx + s * dy, -s * dx + c * dy


def patch_yaw(mx: mjx.Model, terrain_id: int) -> jax.Array:
    """The direction [rad] of a world's terrain patch, from its geom's quaternion (a turn
    about z)."""
    q = mx.geom_quat[terrain_id]
    return 2.0 * jnp.arctan2(q[3], q[0])


def patch_heights(field: mjxrow_field.Field, lane: jax.Array, sim_cfg: SimConfig) -> jax.Array:
    """float32 [NY, NX] terrain heights [m] at the patch samples (NY, NX = sim_cfg.patch_cells;
    row j ↔ the patch's y, column i ↔ its x, as MuJoCo lays a heightfield)."""
    ny, nx = sim_cfg.patch_cells
    lx, ly = sim_cfg.patch_size
    f = patch_frame(field, lane, sim_cfg)
    a = ((jnp.linspace(0.0, 1.0, nx) - 0.5) * lx)[None, :]
    b = ((jnp.linspace(0.0, 1.0, ny) - 0.5) * ly)[:, None]
    c, s = jnp.cos(f[2]), jnp.sin(f[2])
    x = f[0] + (c * a - s * b)
    y = f[1] + (s * a + c * b)
    return mjxrow_field.terrain_height(field.terrain, field.terrain_size, x, y)


def _select_obstacles(field: mjxrow_field.Field, frame: jax.Array, sim_cfg: SimConfig, k: int):
    """Indices [k] of the obstacles that get a physics slot, whether each is used, and how many
    obstacles on the patch got none. frame: the patch's (x, y, yaw)."""
    lx, ly = sim_cfg.patch_size
    d = jnp.stack(to_patch(frame, field.obst_pos[:, 0], field.obst_pos[:, 1]), -1)
    on_patch = field.obst_active & (jnp.abs(d[:, 0]) < 0.5 * lx) & (jnp.abs(d[:, 1]) < 0.5 * ly)
    score = jnp.where(on_patch, jnp.abs(d[:, 1]), jnp.inf)
    neg, idx = jax.lax.top_k(-score, k)  # k ≤ shape.obstacle_slots (_obstacle_counts)
    used = jnp.isfinite(neg)
    dropped = jnp.sum(on_patch) - jnp.sum(used)
    return idx, used, dropped


def obstacles_dropped(field: mjxrow_field.Field, lane: jax.Array, sim_cfg: SimConfig,
                      shape: mjxrow_field.FieldShape) -> jax.Array:
    """int32 []: active obstacles on the patch that found no physics slot (0 when all fit)."""
    k = _obstacle_counts(shape, sim_cfg)[0]
    return _select_obstacles(field, patch_frame(field, lane, sim_cfg), sim_cfg, k)[2]


def world_model(
    mx: mjx.Model, field: mjxrow_field.Field, lane: jax.Array, sim_cfg: SimConfig
) -> mjx.Model:
    """`mx` with one world written in (pure, jittable; vmap over `field`/`lane` with
    `model_axes(mx)` as the out axes):

    - `hfield_data` float32 [NY·NX]: patch heights normalised by `patch_z` (see module doc);
    - `geom_pos` / `geom_quat` / `geom_size` [ngeom, 3|4|3]: terrain geom at (patch centre,
      h_min); `obst_{i}` geoms with this field's stones (capsule of ~0 length) and branches
      (capsule lying along its yaw) nearest the lane, unused ones parked below the patch; the
      contact slots filled for the start point (`refresh_contacts`).

    field: one Field (no batch axis); lane: int32 [] lane index (e.g. `field.robot_lane`)."""
    terrain_id, obst_ids, _ = _geom_ids(mx)
    centre = patch_frame(field, lane, sim_cfg)
    h = patch_heights(field, lane, sim_cfg)
    h_min = jnp.min(h)
    data = jnp.clip((h - h_min) / sim_cfg.patch_z, 0.0, 1.0).reshape(-1)
    geom_pos = mx.geom_pos.at[terrain_id].set(jnp.stack([centre[0], centre[1], h_min]))
    geom_quat = mx.geom_quat.at[terrain_id].set(
        _axis_quat(centre[2], 2).astype(mx.geom_quat.dtype))
    geom_size = mx.geom_size

    k = obst_ids.shape[0]
    if k:
        idx, used, _ = _select_obstacles(field, centre, sim_cfg, k)
        pos = field.obst_pos[idx]
        parked = jnp.stack([jnp.full(k, centre[0]), jnp.full(k, centre[1]),
                            h_min - _PARK_DEPTH - 3.0 * jnp.arange(k)], -1)
        pos = jnp.where(used[:, None], pos, parked)
        stone = field.obst_kind[idx] == mjxrow_field.STONE
        radius = jnp.where(used, field.obst_size[idx, 0], 0.01)
        half = jnp.where(stone | ~used, _STONE_HALF, field.obst_size[idx, 1])
        size = jnp.stack([radius, half, jnp.zeros_like(half)], -1)
        # capsule axis (local z) laid horizontally along yaw: Rz(yaw) · Ry(π/2)
        quat = _quat_mul(_axis_quat(field.obst_yaw[idx], 2),
                         _axis_quat(jnp.full(k, 0.5 * jnp.pi), 1))
        geom_pos = geom_pos.at[obst_ids].set(pos.astype(geom_pos.dtype), unique_indices=True)
        geom_quat = geom_quat.at[obst_ids].set(quat.astype(geom_quat.dtype), unique_indices=True)
        geom_size = geom_size.at[obst_ids].set(size.astype(geom_size.dtype), unique_indices=True)
    mx = mx.tree_replace({"hfield_data": data.astype(mx.hfield_data.dtype),
                          "geom_pos": geom_pos, "geom_quat": geom_quat, "geom_size": geom_size})
    start = field_lanes.point(field_lanes.lane(field, lane), field.row_x[1] - sim_cfg.path_length)
    return refresh_contacts(mx, start)


def refresh_contacts(mx: mjx.Model, points: jax.Array) -> mjx.Model:
    """`mx` with its colliding `contact_{j}` slots holding copies of the J obstacle geoms nearest
    to `points` float [P, 2] or [2] (world xy, m): ranked by the least horizontal distance from
    a point to the obstacle's segment, minus its radius; parked obstacles rank last (pure,
    jittable). `step` calls it with the four wheel centres at the start of every control period;
    `world_model` with the start point."""
    _, obst_ids, slot_ids = _geom_ids(mx)
    j = slot_ids.shape[0]
    if j == 0:
        return mx
    pos, quat, size = mx.geom_pos[obst_ids], mx.geom_quat[obst_ids], mx.geom_size[obst_ids]
    w, x, y, z = quat[:, 0], quat[:, 1], quat[:, 2], quat[:, 3]
    axis = jnp.stack([2 * (x * z + w * y), 2 * (y * z - w * x)], -1)  # local z in world, xy
    rel = jnp.reshape(points, (-1, 1, 2)) - pos[:, :2]  # [P, K, 2]
    t = jnp.clip(jnp.sum(rel * axis, -1) / jnp.maximum(jnp.sum(axis * axis, -1), 1e-9),
                 -size[:, 1], size[:, 1])
    dist = jnp.min(jnp.linalg.norm(rel - t[..., None] * axis, axis=-1), 0) - size[:, 0]
    parked = pos[:, 2] < mx.geom_pos[_geom_ids(mx)[0], 2] - 0.5 * _PARK_DEPTH
    _, idx = jax.lax.top_k(-jnp.where(parked, jnp.inf, dist), j)
    put = lambda x, v: x.at[slot_ids].set(v, unique_indices=True)  # noqa: E731 (distinct ids)
    return mx.tree_replace({"geom_pos": put(mx.geom_pos, pos[idx]),
                            "geom_quat": put(mx.geom_quat, quat[idx]),
                            "geom_size": put(mx.geom_size, size[idx])})


def world_mjmodel(m: mujoco.MjModel, mx_world: mjx.Model) -> mujoco.MjModel:
    """A copy of the C model with one world's arrays (from `world_model`, unbatched) written
    back: for MuJoCo C comparisons, its viewer and its renderer (host). C's midphase is
    disabled: its bounding-volume tree of the world body was built for the compile-time geom
    positions, which `world_model` moves (MJX has no midphase); and no geom is marked as sharing
    its body's frame (C would then ignore the moved `geom_pos`). Obstacle geoms were compiled
    with C bounding boxes for radius 0.1 m and half length 1 m (fields at scale ≤ 1.4 fit).
    To step C like `step`, write `refresh_contacts(mx_world, wheel xy)`'s geom arrays into the
    copy at the start of every control period (tests/test_sim.py does)."""
    out = copy.deepcopy(m)
    out.opt.disableflags |= mujoco.mjtDisableBit.mjDSBL_MIDPHASE
    out.geom_sameframe[:] = 0
    for name in WORLD_FIELDS:
        getattr(out, name)[...] = np.asarray(getattr(mx_world, name)).reshape(
            getattr(out, name).shape)
    return out
