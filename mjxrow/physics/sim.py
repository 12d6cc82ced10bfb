"""MJX physics of the robot driving one lane of a field (impl "jax"): the state, `reset`,
`step` and the read-outs, on the model of `mjxrow.physics.model` with each world written in by
`mjxrow.physics.world` (whose names this module re-exports: `sim.SimConfig`, `sim.make_model`,
`sim.world_model`, ...; the terrain patch and the obstacle contact slots are explained in
`world`, the choices of time step and solver in `model`).

- `reset(mx, field, lane, key, sim_cfg, noise) -> SimState`: the robot at rest at the start of
  its lane, wheels on the terrain.
- `step(mx, state, cmd, sim_cfg) -> SimState`: one control period of `sim_cfg.substeps`
  physics steps (the command ramped within the robot's limits, the wheel servos, the obstacle
  contact slots refilled first).
- `pose`, `velocity`, `camera_pose`, `tilt`, `is_bad`, `is_flipped`, `off_patch`.
"""

from __future__ import annotations

import math

import jax
import jax.numpy as jnp
import numpy as np
from flax import struct

from mjxrow import field as mjxrow_field
from mjxrow.field import lanes as field_lanes
from mjxrow.physics import robot
from mjxrow.physics.checks import (  # noqa: F401  (the physics' face: sim.check_lane, ...)
    auto_lane_kind,
    check_lane,
    check_params,
    check_patch_z,
    fit_patch_z,
    lane_free_width,
    patch_relief,
)
from mjxrow.physics.model import (  # noqa: F401  (the physics' face: sim.make_model, ...)
    TERRAIN,
    WORLD_FIELDS,
    SimConfig,
    _geom_ids,
    _wheel_body_ids,
    make_model,
    model_axes,
    model_xml,
    robot_numbers,
    wheel_dofs,
)
from mjxrow.physics.quiet import mjx
from mjxrow.physics.world import (  # noqa: F401  (sim.world_model, ...)
    _axis_quat,
    _quat_mul,
    obstacles_dropped,
    patch_frame,
    patch_heights,
    patch_yaw,
    refresh_contacts,
    to_patch,
    world_mjmodel,
    world_model,
)

# ---------------------------------------------------------------------------------------------
# State


@struct.dataclass
class PoseNoise:
    """Start-pose noise (traced: sweepable). Scalars, or [B] when batched."""

    lateral_std: jax.Array  # m, std of the start's offset from the lane centre line
    heading_std: jax.Array  # rad, std of the start heading around +x


def pose_noise(lateral_std: float = 0.0, heading_std: float = 0.0) -> PoseNoise:
    return PoseNoise(np.float32(lateral_std), np.float32(heading_std))


@struct.dataclass
class SimState:
    """One world's simulation state."""

    data: mjx.Data  # MJX data; kinematics (xpos, cam_xpos, ...) match qpos after reset/step
    steps: jax.Array  # int32 [], control periods simulated since reset
    target: jax.Array  # float32 [2], (v [m/s], ω [rad/s]) the wheels follow (robot.ramp)


def lane_of(field: mjxrow_field.Field, sim_cfg: SimConfig) -> jax.Array:
    """int32 []: the lane the robot drives, `field.robot_lane(field, mode=sim_cfg.lane)`
    (traced; check the request on the host with `check_lane`)."""
    return mjxrow_field.robot_lane(field, mode=sim_cfg.lane)


def _patch_surface(mx: mjx.Model, sim_cfg: SimConfig, x: jax.Array, y: jax.Array) -> jax.Array:
    """Height [m] of the world's patch surface (as MuJoCo triangulates it) at world (x, y)."""
    terrain_id = _geom_ids(mx)[0]
    ny, nx = sim_cfg.patch_cells
    c = mx.geom_pos[terrain_id]
    grid = mx.hfield_data.reshape(ny, nx) * sim_cfg.patch_z
    size = jnp.asarray(sim_cfg.patch_size, jnp.float32)
    frame = jnp.stack([c[0], c[1], patch_yaw(mx, terrain_id)])
    return c[2] + mjxrow_field.terrain_height(grid, size, *to_patch(frame, x, y))


def reset(mx: mjx.Model, field: mjxrow_field.Field, lane: jax.Array | None, key: jax.Array,
          sim_cfg: SimConfig, noise: PoseNoise | None = None) -> SimState:
    """Robot at rest at the start of `lane`, wheels on the terrain (pure, jittable).

    mx: the world's model (`world_model(mx, field, lane, sim_cfg)`); field: the same Field;
    lane: int32 [] lane index, or None for `lane_of(field, sim_cfg)`; key: PRNG key for the
    pose noise; noise: start-pose noise (None: none).

    The start is `sim_cfg.path_length` before the row end along the lane's centre line, moved
    across it by N(0, lateral_std), heading N(0, heading_std) around the line's direction
    (+x on straight rows); the chassis is tilted to rest on the terrain under its
    four wheels and placed 2 mm above it."""
    rn = robot_numbers(mx)
    if lane is None:
        lane = lane_of(field, sim_cfg)
    kl, kh = jax.random.split(key)
    lat = jnp.float32(0.0) if noise is None else noise.lateral_std * jax.random.normal(kl)
    yaw = jnp.float32(0.0) if noise is None else noise.heading_std * jax.random.normal(kh)
    bend = field_lanes.field_bend(field)
    s0, u0 = field.row_x[1] - sim_cfg.path_length, field.lane_y[lane] + lat
    x0, y0 = field_lanes.to_world(bend, s0, u0)
    yaw = yaw + field_lanes.heading(bend, s0, u0)
    wxy = jnp.asarray(np.stack([robot.WHEEL_FRONT * rn["wheelbase"] / 2,
                                robot.WHEEL_SIDE * rn["track"] / 2], -1), jnp.float32)
    c, s = jnp.cos(yaw), jnp.sin(yaw)
    wx = x0 + c * wxy[:, 0] - s * wxy[:, 1]
    wy = y0 + s * wxy[:, 0] + c * wxy[:, 1]
    hw = _patch_surface(mx, sim_cfg, wx, wy)  # [4] fl, fr, rl, rr
    pitch = -jnp.arctan2(0.5 * (hw[0] + hw[1] - hw[2] - hw[3]), rn["wheelbase"])
    roll = jnp.arctan2(0.5 * (hw[0] + hw[2] - hw[1] - hw[3]), rn["track"])
    quat = _quat_mul(_quat_mul(_axis_quat(yaw, 2), _axis_quat(pitch, 1)), _axis_quat(roll, 0))
    z0 = jnp.mean(hw) + rn["wheel_radius"] + 0.002
    d = mjx.make_data(mx)
    qpos = d.qpos.at[:3].set(jnp.stack([x0, y0, z0])).at[3:7].set(quat).at[7:].set(0.0)
    d = d.replace(qpos=qpos.astype(d.qpos.dtype), qvel=jnp.zeros_like(d.qvel))
    d = mjx.camlight(mx, mjx.kinematics(mx, d))  # poses only: step begins with mjx.forward
    return SimState(data=d, steps=jnp.int32(0), target=jnp.zeros(2, jnp.float32))


def step(mx: mjx.Model, state: SimState, cmd: jax.Array, sim_cfg: SimConfig) -> SimState:
    """Advance one control period (sim_cfg.substeps physics steps) under cmd float [2] =
    (v [m/s], ω [rad/s]), clipped to the robot's limits. Before every physics step the
    followed command `state.target` moves toward cmd within the robot's acceleration limits
    (robot.ramp, max_accel / max_alpha per physics_dt), so a step change of the command becomes
    the same ramp at any dt, and is mapped to wheel speeds (robot.wheel_speeds) that the wheel
    servos track (robot.servo: the torque goes to the wheel motors, dt × its stiffness to the
    wheels' armature for this physics step: linearly implicit, see robot).
    The obstacle contact slots are refilled first around the chassis (`refresh_contacts`).
    Kinematics (xpos, xmat, cam_xpos, ...) are refreshed to the final qpos, so `camera_pose`
    and `pose` describe the same instant. mx: the world's model."""
    rn = robot_numbers(mx)
    dt, dofs = sim_cfg.physics_dt, wheel_dofs(mx)
    cmd = jnp.asarray(cmd, jnp.float32)
    mx = refresh_contacts(mx, state.data.xpos[_wheel_body_ids(mx), :2])

    armature = mx.dof_armature[dofs]

    def body(carry, _):
        d, target = carry
        target = robot.ramp(target, cmd, rn, dt)
        tau, stiff = robot.servo(robot.wheel_speeds(target, rn), d.qvel[dofs], rn)
        m = mx.tree_replace({"dof_armature": mx.dof_armature.at[dofs].set(
            armature + dt * stiff, unique_indices=True)})
        d = d.replace(ctrl=tau.astype(d.ctrl.dtype))
        return (mjx.step(m, d), target), None

    (d, target), _ = jax.lax.scan(body, (state.data, state.target.astype(jnp.float32)), None,
                                  length=sim_cfg.substeps)
    d = mjx.camlight(mx, mjx.kinematics(mx, d))
    return SimState(data=d, steps=state.steps + 1, target=target)


# ---------------------------------------------------------------------------------------------
# Read-outs


def pose(state: SimState) -> jax.Array:
    """float32 [3]: (x [m], y [m], yaw [rad]) of the chassis origin; yaw of its x axis
    projected on the ground, in (−π, π]."""
    q = state.data.qpos
    w, x, y, z = q[3], q[4], q[5], q[6]
    yaw = jnp.arctan2(2.0 * (w * z + x * y), 1.0 - 2.0 * (y * y + z * z))
    return jnp.stack([q[0], q[1], yaw])


def velocity(state: SimState) -> jax.Array:
    """float32 [2]: (forward speed [m/s] along the chassis x axis, yaw rate [rad/s] about
    world z)."""
    d = state.data
    xmat = d.xmat[1]  # chassis body
    return jnp.stack([jnp.dot(xmat[:, 0], d.qvel[:3]), jnp.dot(xmat[2], d.qvel[3:6])])


def camera_pose(state: SimState) -> tuple[jax.Array, jax.Array]:
    """The robot camera: (cam_pos float32 [3] world [m], cam_rot float32 [3, 3] whose columns
    are the camera's x right, y up, z backwards axes in the world), i.e. MuJoCo's
    `data.cam_xpos[0]`, `data.cam_xmat[0].reshape(3, 3)`; fovy is robot_cfg.cam_fovy."""
    d = state.data
    return d.cam_xpos[0], d.cam_xmat[0].reshape(3, 3)


def tilt(state: SimState) -> jax.Array:
    """float32 []: angle [rad] between the chassis z axis and world z."""
    return jnp.arccos(jnp.clip(state.data.xmat[1, 2, 2], -1.0, 1.0))


def is_flipped(state: SimState, sim_cfg: SimConfig) -> jax.Array:
    """bool []: chassis tilted beyond `sim_cfg.max_tilt_deg`."""
    return tilt(state) > math.radians(sim_cfg.max_tilt_deg)


def is_bad(state: SimState, sim_cfg: SimConfig | None = None) -> jax.Array:
    """bool []: the simulation failed: a non-finite qpos / qvel, or any velocity above
    `sim_cfg.max_speed` (m/s or rad/s: exploded). An episode ends as `sim_error` on it."""
    max_speed = (sim_cfg or SimConfig()).max_speed
    d = state.data
    finite = jnp.all(jnp.isfinite(d.qpos)) & jnp.all(jnp.isfinite(d.qvel))
    return ~finite | (jnp.max(jnp.abs(d.qvel)) > max_speed)


def off_patch(mx: mjx.Model, state: SimState, sim_cfg: SimConfig, margin: float = 0.3) -> jax.Array:
    """bool []: the chassis origin is within `margin` [m] of the terrain patch's edge or beyond
    (where the robot would fall off the physics terrain). mx: the world's model."""
    terrain_id = _geom_ids(mx)[0]
    c = mx.geom_pos[terrain_id, :2]
    half = 0.5 * jnp.asarray(sim_cfg.patch_size) - margin
    frame = jnp.stack([c[0], c[1], patch_yaw(mx, terrain_id)])
    local = jnp.stack(to_patch(frame, state.data.qpos[0], state.data.qpos[1]))
    return jnp.any(jnp.abs(local) > half)
