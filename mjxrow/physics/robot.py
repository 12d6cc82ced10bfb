"""The UGV: a Clearpath-Jackal-like skid steer with a forward RGB-D camera.

Frames: the chassis body's origin lies midway between the four wheel axles (at wheel-centre
height), x forward, y left, z up. At rest on flat ground the origin is `wheel_radius` above it.

The model is four SPHERE wheels (MJX collides heightfields with spheres, not cylinders) on hinge
joints about the chassis y axis, each driven by a velocity actuator (torque = kv·(target −
wheel speed), optionally clipped to ±`wheel_torque`). The chassis is a box that takes no part
in contacts unless `SimConfig.chassis_contacts` is set (sim.py). Stability notes: light wheels
need joint armature (0.05 kg·m²) and the `implicitfast` integrator, which also treats the
actuators' velocity gain implicitly. Wheels sit at a Jackal's track (0.376 m) so that they touch
the ground where a Jackal's do; being spheres they reach 0.286 m sideways, beyond the 0.430 m
footprint, which matters only for obstacle contacts (plant collisions use the footprint).

Skid steer: a commanded (v, ω) is clipped to the limits, then mapped to wheel speeds
v_left/right = v ∓ ω·(track·turn_factor)/2, divided by the wheel radius. Skid-steer vehicles turn
slower than the kinematic (differential-drive) rule predicts because the wheels scrub sideways;
`turn_factor` (> 1) widens the effective track so that the yaw rate reached on flat ground
matches the commanded ω (ROS's diff_drive "wheel_separation_multiplier" for Jackal is 1.5).
With kv = 30 and turn_factor = 1.9 the yaw rate reached on flat ground is within 10 % of the
command for |ω| ≤ 1 rad/s and 0 ≤ v ≤ 0.5 m/s (measured; at kv = 8 it was 36-76 %, too low
and uneven: a soft servo lets the wheels lag while they scrub).
"""

from __future__ import annotations

import dataclasses
import math

import jax
import jax.numpy as jnp
import numpy as np

# wheel order everywhere: front-left, front-right, rear-left, rear-right
WHEELS = ("fl", "fr", "rl", "rr")
WHEEL_SIDE = np.array([1.0, -1.0, 1.0, -1.0])  # +1 left (y > 0), -1 right
WHEEL_FRONT = np.array([1.0, 1.0, -1.0, -1.0])  # +1 front (x > 0), -1 rear
CAMERA = "front"  # name of the robot's camera in the model
NUMERIC = "mjxrow_robot"  # name of the <numeric> that carries the robot's numbers in the model
# order of the numbers in that <numeric>
NUMERIC_KEYS = ("v_max", "omega_max", "wheel_radius", "track", "wheelbase", "turn_factor",
                "length", "width")


@dataclasses.dataclass(frozen=True)
class RobotConfig:
    """Robot dimensions, limits and camera mount (static: one compile per distinct value).

    Defaults follow a Clearpath Jackal with an Intel RealSense D435 (≈69° × 42° field of view)
    on its front, about 0.40 m above the ground, pitched 10° down."""

    # command limits
    v_max: float = 0.5  # m/s, |v| is clipped to this
    omega_max: float = 1.0  # rad/s, |ω| is clipped to this
    # body
    length: float = 0.508  # m, footprint along x (the collision footprint for plants)
    width: float = 0.430  # m, footprint along y
    mass: float = 17.0  # kg, total (chassis + 4 wheels)
    wheel_mass: float = 0.5  # kg, each wheel
    wheel_radius: float = 0.098  # m
    wheelbase: float = 0.262  # m, front-to-rear axle distance
    track: float = 0.376  # m, left-to-right wheel-centre distance
    chassis_height: float = 0.18  # m, box height
    chassis_clearance: float = 0.06  # m, box bottom above flat ground
    # drive
    turn_factor: float = 1.9  # effective track / track in the (v, ω) → wheel speed map [-]
    kv: float = 30.0  # N·m·s/rad, velocity-actuator gain per wheel
    wheel_torque: float = 0.0  # N·m, torque limit per wheel; 0 = unlimited (friction limits it)
    armature: float = 0.05  # kg·m², wheel-joint armature (needed for stability)
    wheel_damping: float = 0.0  # N·m·s/rad, passive damping of the wheel joints
    friction: float = 1.0  # wheel sliding friction coefficient [-]
    # camera mount (chassis frame)
    cam_height: float = 0.40  # m, above flat ground at rest
    cam_forward: float = 0.20  # m, ahead of the chassis origin
    cam_lateral: float = 0.0  # m, left of the centre line
    cam_pitch_deg: float = -10.0  # degrees, negative looks down
    cam_fovy: float = 42.0  # degrees, vertical field of view (horizontal follows from W/H)

    def __post_init__(self):
        positive = ("v_max", "omega_max", "length", "width", "mass", "wheel_mass", "wheel_radius",
                    "wheelbase", "track", "chassis_height", "turn_factor", "kv",
                    "cam_height", "cam_fovy")
        for name in positive:
            if not getattr(self, name) > 0:
                raise ValueError(f"robot.{name}: must be positive, got {getattr(self, name)}")
        for name in ("armature", "wheel_damping", "friction", "chassis_clearance", "wheel_torque"):
            if getattr(self, name) < 0:
                raise ValueError(f"robot.{name}: must be non-negative, got {getattr(self, name)}")
        if self.mass <= 4 * self.wheel_mass:
            raise ValueError(f"robot.mass: {self.mass} kg must exceed the 4 wheels' "
                             f"{4 * self.wheel_mass} kg")
        if not -90.0 < self.cam_pitch_deg < 90.0:
            raise ValueError(
                f"robot.cam_pitch_deg: must lie in (-90, 90), got {self.cam_pitch_deg}")
        if not self.cam_fovy < 180.0:
            raise ValueError(f"robot.cam_fovy: must be below 180 degrees, got {self.cam_fovy}")

    @property
    def wheel_xy(self) -> np.ndarray:
        """float [4, 2]: wheel centres in the chassis frame [m], order WHEELS."""
        return np.stack([WHEEL_FRONT * self.wheelbase / 2, WHEEL_SIDE * self.track / 2], -1)

    @property
    def cam_local(self) -> np.ndarray:
        """float [3]: camera position in the chassis frame [m]."""
        return np.array([self.cam_forward, self.cam_lateral, self.cam_height - self.wheel_radius])

    @property
    def cam_rot_local(self) -> np.ndarray:
        """float [3, 3]: camera axes (columns x right, y up, z backwards) in the chassis frame."""
        p = math.radians(self.cam_pitch_deg)
        fwd = np.array([math.cos(p), 0.0, math.sin(p)])  # optical axis
        x = np.array([0.0, -1.0, 0.0])
        z = -fwd
        y = np.cross(z, x)
        return np.stack([x, y, z], -1)

    def numeric(self) -> np.ndarray:
        """float [len(NUMERIC_KEYS)]: the numbers sim.step / sim.reset read back from a model."""
        return np.array([getattr(self, k) for k in NUMERIC_KEYS], np.float64)


def wheel_speeds(cmd: jax.Array, cfg: RobotConfig | dict) -> jax.Array:
    """Skid-steer map from a command to wheel angular speeds.

    cmd: float [..., 2] = (v [m/s], ω [rad/s]); clipped to ±v_max, ±omega_max first.
    cfg: a RobotConfig, or the dict `sim.robot_numbers(mx)` returns.
    Returns float [..., 4] wheel speeds [rad/s] in WHEELS order (fl, fr, rl, rr); positive rolls
    the robot forward."""
    get = cfg.__getitem__ if isinstance(cfg, dict) else lambda k: getattr(cfg, k)
    cmd = jnp.asarray(cmd)
    v = jnp.clip(cmd[..., 0], -get("v_max"), get("v_max"))
    w = jnp.clip(cmd[..., 1], -get("omega_max"), get("omega_max"))
    half = 0.5 * get("track") * get("turn_factor")
    side = jnp.asarray(WHEEL_SIDE, cmd.dtype)
    return (v[..., None] - side * half * w[..., None]) / get("wheel_radius")


def _f(*xs: float) -> str:
    return " ".join(f"{x:.6g}" for x in xs)


def mjcf_body(cfg: RobotConfig, pos: tuple[float, float, float] = (0.0, 0.0, 0.2),
              chassis_contacts: bool = False) -> str:
    """MJCF `<body name="chassis">` (free joint, chassis box, four wheels, camera) to put in a
    `<worldbody>`. Wheels have contype=1, conaffinity=0: they touch geoms whose conaffinity
    has bit 0 (terrain, obstacles) and never each other. With `chassis_contacts` the box has
    contype=1 as well."""
    chassis_mass = cfg.mass - 4 * cfg.wheel_mass
    box_half = (cfg.length / 2, (cfg.track - cfg.wheel_radius) / 2, cfg.chassis_height / 2)
    box_z = cfg.chassis_clearance + cfg.chassis_height / 2 - cfg.wheel_radius
    ct = 1 if chassis_contacts else 0
    rot = cfg.cam_rot_local
    xyaxes = _f(*rot[:, 0], *rot[:, 1])
    lines = [
        f'<body name="chassis" pos="{_f(*pos)}">',
        '  <freejoint name="root"/>',
        f'  <geom name="chassis" type="box" size="{_f(*box_half)}" pos="0 0 {box_z:.6g}" '
        f'mass="{chassis_mass:.6g}" contype="{ct}" conaffinity="0" group="1" '
        f'rgba="0.85 0.65 0.1 1"/>',
        f'  <camera name="{CAMERA}" pos="{_f(*cfg.cam_local)}" xyaxes="{xyaxes}" '
        f'fovy="{cfg.cam_fovy:.6g}"/>',
    ]
    for name, (x, y) in zip(WHEELS, cfg.wheel_xy, strict=True):
        lines += [
            f'  <body name="wheel_{name}" pos="{_f(x, y, 0.0)}">',
            f'    <joint name="wheel_{name}" type="hinge" axis="0 1 0" '
            f'armature="{cfg.armature:.6g}" damping="{cfg.wheel_damping:.6g}"/>',
            f'    <geom name="wheel_{name}" type="sphere" size="{cfg.wheel_radius:.6g}" '
            f'mass="{cfg.wheel_mass:.6g}" contype="1" conaffinity="0" condim="3" '
            f'friction="{cfg.friction:.6g} 0.005 0.0001" group="1" rgba="0.1 0.1 0.1 1"/>',
            "  </body>",
        ]
    lines.append("</body>")
    return "\n".join(lines)


def mjcf_actuators(cfg: RobotConfig) -> str:
    """MJCF `<velocity>` actuators (inside `<actuator>`), one per wheel in WHEELS order."""
    limit = (f' forcelimited="true" forcerange="{_f(-cfg.wheel_torque, cfg.wheel_torque)}"'
             if cfg.wheel_torque > 0 else "")
    return "\n".join(f'<velocity name="wheel_{n}" joint="wheel_{n}" kv="{cfg.kv:.6g}"{limit}/>'
                     for n in WHEELS)


def mjcf_numeric(cfg: RobotConfig) -> str:
    """MJCF `<numeric>` (inside `<custom>`) carrying `cfg.numeric()` so that a compiled model
    knows its robot's limits and geometry."""
    return f'<numeric name="{NUMERIC}" data="{_f(*cfg.numeric())}"/>'
