"""What every export of ONE field shares (host, numpy): number formatting, rotations, the
active rows, and the robot an export carries with its start pose in each lane.

The start poses are the closed loop's own: `physics.sim.reset` on `physics.sim.world_model`
(start `sim.path_length` before the row end, wheels on the terrain, chassis tilted to rest on
them), so an exported robot stands where an episode's robot stands.
"""

from __future__ import annotations

import dataclasses
import functools

import jax
import jax.numpy as jnp
import numpy as np

from mjxrow import field as mjxrow_field
from mjxrow.physics import robot as physics_robot
from mjxrow.physics import sim

CAMERA_IMAGE = (64, 64)  # px (width, height): the sweep's default camera image


def num(x: float, nd: int = 3) -> str:
    """A number with `nd` decimals, trailing zeros dropped ('1.500' → '1.5', '-0.000' → '0')."""
    s = f"{float(x):.{nd}f}".rstrip("0").rstrip(".")
    return "0" if s in ("-0", "") else s


def nums(xs, nd: int = 3) -> str:
    """Space-separated `num`s of every element of `xs`."""
    return " ".join(num(x, nd) for x in np.ravel(xs))


def euler_zyx(rot: np.ndarray) -> np.ndarray:
    """Angles (a, b, c) [rad] with rot = Rz(a) @ Ry(b) @ Rx(c): MJCF `euler` with
    eulerseq="zyx", and SDF's pose (roll, pitch, yaw) = (c, b, a). rot: [..., 3, 3] → [..., 3]."""
    sb = np.clip(-rot[..., 2, 0], -1.0, 1.0)
    lock = np.abs(sb) > 1.0 - 1e-6
    a = np.where(lock, np.arctan2(-rot[..., 0, 1], rot[..., 1, 1]),
                 np.arctan2(rot[..., 1, 0], rot[..., 0, 0]))
    c = np.where(lock, 0.0, np.arctan2(rot[..., 2, 1], rot[..., 2, 2]))
    return np.stack([a, np.arcsin(sb), c], -1)


def quat_rot(q: np.ndarray) -> np.ndarray:
    """Rotation matrices [..., 3, 3] of unit quaternions [..., 4] (w, x, y, z)."""
    w, x, y, z = np.moveaxis(np.asarray(q, np.float64), -1, 0)
    rows = ([1 - 2 * (y * y + z * z), 2 * (x * y - w * z), 2 * (x * z + w * y)],
            [2 * (x * y + w * z), 1 - 2 * (x * x + z * z), 2 * (y * z - w * x)],
            [2 * (x * z - w * y), 2 * (y * z + w * x), 1 - 2 * (x * x + y * y)])
    return np.stack([np.stack(r, -1) for r in rows], -2)


def host(field: mjxrow_field.Field) -> mjxrow_field.Field:
    """`field` as numpy arrays; ValueError unless it is ONE field (no batch axis)."""
    f = jax.tree.map(np.asarray, field)
    if f.terrain.ndim != 2:
        raise ValueError(f"field: expected ONE field (terrain [NY, NX]), got terrain shape "
                         f"{f.terrain.shape}; index the batch first")
    return f


def active_rows(f: mjxrow_field.Field) -> tuple[np.ndarray, np.ndarray]:
    """Active rows sorted by u, across the rows (y on straight rows): (field row index [n], new
    index 0..n-1 per field row [R])."""
    act = np.flatnonzero(f.row_active)
    order = act[np.argsort(f.row_y[act], kind="stable")]
    new = np.full(f.row_y.shape, -1)
    new[order] = np.arange(len(order))
    return order, new


def field_lanes(f: mjxrow_field.Field) -> np.ndarray:
    """Field lane indices (into `lane_y`) of the lanes between consecutive active rows, by u."""
    order, _ = active_rows(f)
    return order[:-1]


@dataclasses.dataclass(frozen=True)
class Robot:
    """The robot an export carries, as the closed loop runs it (static, hashable).

    robot: dimensions, drive and camera mount; sim: physics settings (time step, solver) and
    `path_length`, which places the start; image: the camera's (width, height) in pixels."""

    robot: physics_robot.RobotConfig = physics_robot.RobotConfig()
    sim: sim.SimConfig = sim.SimConfig()
    image: tuple[int, int] = CAMERA_IMAGE

    @property
    def hfov(self) -> float:
        """rad, the camera's horizontal field of view (from fovy and the image's aspect)."""
        w, h = self.image
        return 2.0 * np.arctan(np.tan(np.radians(self.robot.cam_fovy) / 2) * w / h)


def robot_for(field: mjxrow_field.Field, robot: physics_robot.RobotConfig | None = None,
              image: tuple[int, int] = CAMERA_IMAGE) -> Robot:
    """The default `Robot` for a field: the closed loop's defaults, with the path shortened to
    the row length where the rows are shorter than `SimConfig.path_length`."""
    f = host(field)
    rows = float(f.row_x[1] - f.row_x[0])
    cfg = sim.SimConfig()
    return Robot(robot or physics_robot.RobotConfig(),
                 dataclasses.replace(cfg, path_length=min(cfg.path_length, rows)), image)


@dataclasses.dataclass(frozen=True)
class Start:
    """Where the robot starts: `lane` (index of `lanes_table`, 0..n-1 by u) and its free-joint
    pose `qpos` float64 [7] = (x, y, z [m], quaternion w, x, y, z) of the chassis origin."""

    lane: int
    qpos: np.ndarray

    @property
    def xyz_rpy(self) -> np.ndarray:
        """float64 [6]: (x, y, z [m], roll, pitch, yaw [rad]), SDF's pose."""
        return np.r_[self.qpos[:3], euler_zyx(quat_rot(self.qpos[3:]))[::-1]]


@functools.lru_cache(maxsize=8)
def _reset_fn(shape: mjxrow_field.FieldShape, robot: Robot):
    _, mx = sim.make_model(shape, robot.sim, robot.robot)

    def one(field, lane, key, noise):
        m = sim.world_model(mx, field, lane, robot.sim)
        return sim.reset(m, field, lane, key, robot.sim, noise).data.qpos[:7]

    return jax.jit(jax.vmap(one, in_axes=(None, 0, 0, None)))


def start_poses(field: mjxrow_field.Field, shape: mjxrow_field.FieldShape, robot: Robot, lanes=None,
                keys: jax.Array | None = None, noise: sim.PoseNoise | None = None) -> np.ndarray:
    """float64 [N, 7]: the chassis qpos (x, y, z, qw, qx, qy, qz) of `sim.reset` in each of
    `lanes` (field lane indices [N]; default: every lane between active rows, by u), with
    reset keys `keys` [N] and start-pose `noise` (default: none: on the lane's centre line,
    heading along it)."""
    f = host(field)
    lanes = field_lanes(f) if lanes is None else np.atleast_1d(np.asarray(lanes))
    if keys is None:
        keys = jax.random.split(jax.random.key(0), len(lanes))
    noise = noise if noise is not None else sim.pose_noise()
    q = _reset_fn(shape, robot)(field, jnp.asarray(lanes, jnp.int32), keys, noise)
    return np.asarray(q, np.float64)


def default_start(field: mjxrow_field.Field, shape: mjxrow_field.FieldShape, robot: Robot,
                  lane: int | None = None) -> Start:
    """The start in table lane `lane` (0..n-1 by u; None: the field's `robot_lane`), without
    noise. ValueError naming `lane` when it does not exist."""
    f = host(field)
    lanes = field_lanes(f)
    if lane is None:
        lane = int(np.flatnonzero(lanes == int(mjxrow_field.robot_lane(f)))[0])
    if not 0 <= lane < len(lanes):
        raise ValueError(f"lane: {lane} is not a lane of this field (0..{len(lanes) - 1})")
    return Start(lane, start_poses(field, shape, robot)[lane])
