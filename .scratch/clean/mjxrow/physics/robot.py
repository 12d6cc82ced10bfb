"""The UGV: a Clearpath-Jackal-like skid steer with a forward RGB-D camera.

Frames: the chassis body's origin lies midway between the four wheel axles (at wheel-centre
height), x forward, y left, z up. At rest on flat ground the origin is `wheel_radius` above it.

The model is four SPHERE wheels (MJX collides heightfields with spheres, not cylinders) on hinge
joints about the chassis y axis. The chassis is a box that takes no part in contacts unless
`SimConfig.chassis_contacts` is set (sim.py). Wheels sit at a Jackal's track (0.376 m) so that
they touch the ground where a Jackal's do; being spheres they reach 0.286 m sideways, beyond
the 0.430 m footprint, which matters only for obstacle contacts (plant collisions use the
footprint). The wheel geoms have `priority` 1, so a wheel contact takes the wheel's `friction`
whatever the terrain's or the obstacle's (MuJoCo would otherwise take the larger of the two).

Drive. Each wheel has a velocity servo, torque = L·tanh(kv·(ω_target − ω)/L) (`servo`: kv for
small errors, saturating smoothly at the motor limit L = `wheel_torque`), applied through a
`<motor>` and integrated linearly implicitly: sim.step adds dt·∂torque/∂(−ω) to the wheel's
armature for each physics step, so the torque acts with the wheel speed at the END of the step
(backward Euler) and the contact solver sees the servo's stiffness. The armature of
0.05 kg·m² stands for the motor and gearbox's reflected inertia and keeps light wheels stable.
`max_accel` / `max_alpha` rate-limit the (v, ω) the wheels follow (`ramp`, every physics
step), as the Jackal's ROS controller does. Why (MuJoCo's `<velocity>` actuator at the
default step) and where the numbers come from: docs/physics.md.

Skid steer: a commanded (v, ω) is clipped to the limits, then mapped to wheel speeds
v_left/right = v ∓ ω·(track·turn_factor)/2, divided by the wheel radius. Skid-steer vehicles turn
slower than the kinematic (differential-drive) rule predicts because the wheels scrub sideways;
`turn_factor` (> 1) widens the effective track so that the yaw rate reached on flat ground
matches the commanded ω (ROS's diff_drive "wheel_separation_multiplier" for Jackal is 1.5).
turn_factor = 1.55 brings the yaw rate reached on flat ground within 6 % of the command
(docs/physics.md).
"""

from __future__ import annotations

import dataclasses
import math
import numbers

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
                "length", "width", "max_accel", "max_alpha", "kv", "wheel_torque")


# physically sane magnitudes |value| (0 aside) of the robot's numbers: far beyond any real field
# robot, tight enough that MuJoCo never sees a degenerate body (a 1e-300 m wheel has no inertia)
_M, _KG = (1e-3, 100.0, "m"), (1e-3, 1e5, "kg")
SANE: dict[str, tuple[float, float, str]] = {
    "v_max": (1e-3, 100.0, "m/s"), "omega_max": (1e-3, 100.0, "rad/s"),
    "length": _M, "width": _M, "wheel_radius": _M, "wheelbase": _M, "track": _M,
    "chassis_height": _M, "chassis_clearance": _M, "cam_height": _M, "cam_forward": _M,
    "cam_lateral": _M, "mass": _KG, "wheel_mass": _KG, "turn_factor": (1e-2, 100.0, ""),
    "kv": (1e-3, 1e6, "N·m·s/rad"), "wheel_torque": (1e-3, 1e6, "N·m"),
    "max_accel": (1e-3, 1e4, "m/s²"), "max_alpha": (1e-3, 1e4, "rad/s²"),
    "armature": (1e-6, 1e3, "kg·m²"), "wheel_damping": (1e-6, 1e6, "N·m·s/rad"),
    "friction": (1e-3, 100.0, ""),  # cam_pitch_deg and cam_fovy: their own ranges below
}


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
    turn_factor: float = 1.55  # effective track / track in the (v, ω) → wheel speed map [-]
    kv: float = 30.0  # N·m·s/rad, velocity-actuator gain per wheel
    wheel_torque: float = 5.0  # N·m, motor torque limit per wheel; 0 = unlimited
    max_accel: float = 20.0  # m/s², rate limit of the v the wheels follow; 0 = none
    max_alpha: float = 25.0  # rad/s², rate limit of the ω the wheels follow; 0 = none
    armature: float = 0.05  # kg·m², wheel-joint armature (motor inertia; needed for stability)
    wheel_damping: float = 0.0  # N·m·s/rad, passive damping of the wheel joints
    friction: float = 1.0  # wheel sliding friction coefficient [-]
    # camera mount (chassis frame)
    cam_height: float = 0.40  # m, above flat ground at rest
    cam_forward: float = 0.20  # m, ahead of the chassis origin
    cam_lateral: float = 0.0  # m, left of the centre line
    cam_pitch_deg: float = -10.0  # degrees, negative looks down
    cam_fovy: float = 42.0  # degrees, vertical field of view (horizontal follows from W/H)

    def __post_init__(self):
        for f in dataclasses.fields(self):
            v = getattr(self, f.name)
            if isinstance(v, bool) or not isinstance(v, numbers.Real) or not math.isfinite(v):
                raise ValueError(f"robot.{f.name}: expected a finite number, got {v!r}")
            low, high, unit = SANE.get(f.name, (-math.inf, math.inf, ""))
            if v != 0 and not low <= abs(v) <= high:  # zero: the sign checks below decide
                raise ValueError(f"robot.{f.name}: {v:g} {unit} is outside the sane range "
                                 f"[{low:g}, {high:g}] {unit} (mjxrow/physics/robot.py SANE)")
        positive = ("v_max", "omega_max", "length", "width", "mass", "wheel_mass", "wheel_radius",
                    "wheelbase", "track", "chassis_height", "turn_factor", "kv",
                    "cam_height", "cam_fovy")
        for name in positive:
            if not getattr(self, name) > 0:
                raise ValueError(f"robot.{name}: must be positive, got {getattr(self, name)}")
        for name in ("armature", "wheel_damping", "friction", "chassis_clearance", "wheel_torque",
                     "max_accel", "max_alpha"):
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
    xp = _xp(cmd)
    cmd = xp.asarray(cmd)
    v = xp.clip(cmd[..., 0], -get("v_max"), get("v_max"))
    w = xp.clip(cmd[..., 1], -get("omega_max"), get("omega_max"))
    half = 0.5 * get("track") * get("turn_factor")
    side = xp.asarray(WHEEL_SIDE, cmd.dtype)
    return (v[..., None] - side * half * w[..., None]) / get("wheel_radius")


def _xp(*xs):
    """numpy for host arrays (a MuJoCo C loop, tests), jax.numpy for jax arrays and tracers."""
    return jnp if any(isinstance(x, jax.Array) for x in xs) else np


def ramp(target: jax.Array, cmd: jax.Array, cfg: RobotConfig | dict, dt: float) -> jax.Array:
    """The command the wheels follow after one physics step of the acceleration limits.

    target: float [..., 2] (v [m/s], ω [rad/s]) followed so far; cmd: float [..., 2] the
    controller's command (clipped to ±v_max, ±omega_max here); dt: s, the physics step.
    Returns target moved toward cmd by at most max_accel·dt and max_alpha·dt (a limit of 0
    jumps at once). numpy in, numpy out (`servo` too): the same code steps MuJoCo C."""
    get = cfg.__getitem__ if isinstance(cfg, dict) else lambda k: getattr(cfg, k)
    xp = _xp(target, cmd)
    cmd = xp.asarray(cmd)
    lim = xp.asarray([get("v_max"), get("omega_max")], cmd.dtype)
    cmd = xp.clip(cmd, -lim, lim)
    step = xp.asarray([get("max_accel") or xp.inf, get("max_alpha") or xp.inf],
                      cmd.dtype) * dt
    return target + xp.clip(cmd - target, -step, step)


def _f(*xs: float) -> str:
    return " ".join(f"{x:.6g}" for x in xs)


def servo(target: jax.Array, speed: jax.Array, cfg: RobotConfig | dict
          ) -> tuple[jax.Array, jax.Array]:
    """The wheel servos: (torque [N·m], stiffness [N·m·s/rad]), float [..., 4] each.

    target, speed: wheel speeds [rad/s] [..., 4] (`wheel_speeds`, the wheel joints' qvel).
    torque = L·tanh(kv·(target − speed)/L) with L = wheel_torque (kv·(target − speed) when
    it is 0): kv for small errors, saturating smoothly at ±L; stiffness = −∂torque/∂speed =
    kv·(1 − tanh²), the implicit term sim.step adds to the wheels' armature as dt·stiffness
    (module doc)."""
    get = cfg.__getitem__ if isinstance(cfg, dict) else lambda k: getattr(cfg, k)
    kv, lim = get("kv"), get("wheel_torque")
    xp = _xp(target, speed)
    tau = kv * (xp.asarray(target) - xp.asarray(speed))
    if not lim > 0:
        return tau, xp.full_like(tau, kv)
    t = xp.tanh(tau / lim)
    return lim * t, kv * (1.0 - t * t)


def mjcf_body(cfg: RobotConfig, pos: tuple[float, float, float] = (0.0, 0.0, 0.2),
              chassis_contacts: bool = False) -> str:
    """MJCF `<body name="chassis">` (free joint, chassis box, four wheels, camera) to put in a
    `<worldbody>`. Wheels have contype=1, conaffinity=0: they touch geoms whose conaffinity
    has bit 0 (terrain, obstacles) and never each other. With `chassis_contacts` the box has
    contype=1 as well. The wheel joints' armature is the motor's (`armature`); sim.step adds
    the servo's implicit term to it every physics step."""
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
            f'mass="{cfg.wheel_mass:.6g}" contype="1" conaffinity="0" condim="3" priority="1" '
            f'friction="{cfg.friction:.6g} 0.005 0.0001" group="1" rgba="0.1 0.1 0.1 1"/>',
            "  </body>",
        ]
    lines.append("</body>")
    return "\n".join(lines)


def mjcf_actuators(cfg: RobotConfig) -> str:
    """MJCF `<motor>` actuators (inside `<actuator>`), one per wheel in WHEELS order: ctrl is
    the wheel torque [N·m] (`servo`), limited to ±wheel_torque when that is set."""
    limit = (f' forcelimited="true" forcerange="{_f(-cfg.wheel_torque, cfg.wheel_torque)}"'
             if cfg.wheel_torque > 0 else "")
    return "\n".join(f'<motor name="wheel_{n}" joint="wheel_{n}"{limit}/>' for n in WHEELS)


def mjcf_numeric(cfg: RobotConfig) -> str:
    """MJCF `<numeric>` (inside `<custom>`) carrying `cfg.numeric()` so that a compiled model
    knows its robot's limits and geometry."""
    return f'<numeric name="{NUMERIC}" data="{_f(*cfg.numeric())}"/>'
