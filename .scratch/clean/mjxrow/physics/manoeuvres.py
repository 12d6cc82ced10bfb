"""Driving manoeuvres that expose time-step artefacts of the robot's physics.

Each manoeuvre is one world (a small two-row field, flat or on a constant slope, no obstacles)
driven open loop through a command sequence at 15 Hz for `seconds`:

- `start`: v = 0.5 m/s from rest, ω = 0.
- `stop`: v = 0.5 m/s for half the time, then (0, 0).
- `flip_turn`: v = 0.5 m/s with ω = +1, −1, +1, ... rad/s flipped every control period (what
  an oscillating controller asks for).
- `descent`: as `stop`, driving down a 25° slope (the robot heads downhill).
- `climb`: as `stop`, driving up a 30° slope.
- `hold` (HOLD, not in MANOEUVRES): standing (command 0) on a 20° slope, for the wheel
  friction: at 1 the wheels hold (tan 20° = 0.36), at 0.3 the robot slides (`slide_cm`).

`run(sim_cfg, robot_cfg)` simulates all five in one compiled call (jit(vmap(scan(sim.step))));
`run_c` the same worlds in MuJoCo C, stepped as sim.step does (the tests: no compile per step);
sampling the state after every control period; `figures(traj)` reduces the samples to the
numbers compared between a coarse and a fine physics step (tests/test_physics_limits.py,
experiments/physics_manoeuvres.py):

- start: `overshoot_pct` = 100·(max forward speed − 0.5) / 0.5; `settle_s` = the time after
  which the forward speed stays within ±5 % of 0.5 m/s.
- stop: `pitch_deg` = max |pitch| [°] after the stop command; `stop_cm` = distance [cm]
  travelled from the stop command to the end.
- flip_turn: `hop_cm` = max height [cm] of the chassis origin above its resting height;
  `yaw_rate` = max |yaw rate| [rad/s]; `dist_m` = distance covered [m].
- descent / climb: `pitch_deg` = max |pitch − slope angle| [°] (chassis pitch against the
  slope's); `dist_m` = distance covered along x [m]; `flipped` = tilt beyond
  `sim_cfg.max_tilt_deg` (or a failed simulation) at any sample.
"""

from __future__ import annotations

import copy
import dataclasses
import functools
import math

import jax
import jax.numpy as jnp
import numpy as np

from mjxrow import field as mjxrow_field
from mjxrow.physics import robot, sim

MANOEUVRES = ("start", "stop", "flip_turn", "descent", "climb")
HOLD = "hold"  # standing (command 0) on a 20° slope: what the wheel friction holds (run_c)
SLOPE_DEG = {"descent": -25.0, "climb": 30.0, HOLD: 20.0}  # degrees, along the travel (+x)
V = 0.5  # m/s, the commanded speed
# a small two-row field, no obstacles, no roughness: the only terrain feature is the slope
FIELD = dict(terrain_length=30.0, row_length=24.0, terrain_width=8.0, rows_per_group=2,
             terrain_dh=0.0, stone_density=0.0, branch_density=0.0, p_missing=0.0)


def commands(name: str, n_steps: int) -> np.ndarray:
    """float32 [n_steps, 2]: the (v [m/s], ω [rad/s]) sequence of manoeuvre `name`."""
    cmd = np.zeros((n_steps, 2), np.float32)
    cmd[:, 0] = V
    if name == HOLD:
        cmd[:, 0] = 0.0
    if name in ("stop", "descent", "climb"):
        cmd[n_steps // 2:, 0] = 0.0
    if name == "flip_turn":
        cmd[:, 1] = np.where(np.arange(n_steps) % 2 == 0, 1.0, -1.0)
    return cmd


def slope(name: str) -> float:
    """dz/dx [-] of manoeuvre `name`'s terrain."""
    return math.tan(math.radians(SLOPE_DEG.get(name, 0.0)))


def sim_config(sim_cfg: sim.SimConfig) -> sim.SimConfig:
    """`sim_cfg` with a patch height range that holds the steepest manoeuvre's slope."""
    lx = sim_cfg.patch_size[0]
    need = max(abs(slope(n)) for n in MANOEUVRES) * lx
    return dataclasses.replace(sim_cfg, patch_z=max(sim_cfg.patch_z, math.ceil(need + 1.0)))


def run(sim_cfg: sim.SimConfig | None = None, robot_cfg: robot.RobotConfig | None = None,
        seconds: float = 4.0) -> dict[str, dict[str, np.ndarray]]:
    """Simulate every manoeuvre (host; compiles once per configuration).

    Returns name → samples after each control period [T]: `x`, `z` [m] (chassis origin),
    `pitch` [rad] (nose up positive), `v` [m/s] forward speed, `w` [rad/s] yaw rate, `bad`,
    `flipped` (bool), plus `cmd` [T, 2] and the scalars `slope` (dz/dx) and `dt` [s]."""
    sim_cfg = sim_config(sim_cfg or sim.SimConfig())
    robot_cfg = robot_cfg or robot.RobotConfig()
    n = math.ceil(seconds * sim_cfg.control_hz - 1e-9)
    params = mjxrow_field.stack_params(
        [mjxrow_field.make_params("zucchini", **FIELD, slope_x=slope(m)) for m in MANOEUVRES]
    )
    shape = mjxrow_field.fit_shape(params, "zucchini", obstacle_slots=1)
    _, mx = sim.make_model(shape, sim_cfg, robot_cfg)
    cmds = jnp.asarray(np.stack([commands(m, n) for m in MANOEUVRES]))

    def world(p, cmd_seq):
        field = mjxrow_field.generate(p, shape, jax.random.key(0))
        lane = mjxrow_field.robot_lane(field)
        mw = sim.world_model(mx, field, lane, sim_cfg)
        s0 = sim.reset(mw, field, lane, jax.random.key(0), sim_cfg)

        def body(s, cmd):
            s = sim.step(mw, s, cmd, sim_cfg)
            xmat = s.data.xmat[1]
            vel = sim.velocity(s)
            out = dict(x=s.data.qpos[0], z=s.data.qpos[2],
                       pitch=jnp.arcsin(jnp.clip(xmat[2, 0], -1.0, 1.0)), v=vel[0], w=vel[1],
                       bad=sim.is_bad(s, sim_cfg), flipped=sim.is_flipped(s, sim_cfg))
            return s, out

        _, traj = jax.lax.scan(body, s0, cmd_seq)
        return s0.data.qpos[0], traj

    x0, traj = jax.device_get(jax.jit(jax.vmap(world))(params, cmds))
    out = {}
    for i, m in enumerate(MANOEUVRES):
        t = {k: np.asarray(v[i]) for k, v in traj.items()}
        t.update(x0=float(x0[i]), cmd=np.asarray(cmds[i]), slope=slope(m),
                 dt=sim_cfg.physics_dt, control_hz=sim_cfg.control_hz,
                 wheel_radius=robot_cfg.wheel_radius)
        out[m] = t
    return out


@functools.lru_cache(maxsize=8)
def _c_worlds(sim_cfg: sim.SimConfig, robot_cfg: robot.RobotConfig, fields: tuple[tuple, ...]):
    """(C model, start qpos float [nq]) per field (FieldParams overrides as sorted items),
    built by the MJX code; cached (one compile for every manoeuvre and friction)."""
    fp = [mjxrow_field.make_params("zucchini", **dict(f)) for f in fields]
    shape = mjxrow_field.fit_shape(mjxrow_field.stack_params(fp), "zucchini", obstacle_slots=1)
    m, mx = sim.make_model(shape, sim_cfg, robot_cfg)

    def world(p):
        fld = mjxrow_field.generate(p, shape, jax.random.key(0))
        lane = mjxrow_field.robot_lane(fld)
        mw = sim.world_model(mx, fld, lane, sim_cfg)
        return mw, sim.reset(mw, fld, lane, jax.random.key(0), sim_cfg).data.qpos

    mws, q0 = jax.device_get(jax.jit(jax.vmap(world))(mjxrow_field.stack_params(fp)))
    return [(sim.world_mjmodel(m, jax.tree.map(lambda x, i=i: x[i], mws)), np.asarray(q0[i]))
            for i in range(len(fp))]


def c_world(
    name: str,
    sim_cfg: sim.SimConfig | None = None,
    robot_cfg: robot.RobotConfig | None = None,
    field: dict | None = None,
) -> tuple:
    """(MuJoCo C model, start qpos float [nq]) of manoeuvre `name`'s world (`run_c`; the
    model's timestep is sim_cfg's physics step; a copy, free to modify). The worlds of every
    manoeuvre are built together and cached, once for all physics steps."""
    sim_cfg = sim_config(sim_cfg or sim.SimConfig())
    every = MANOEUVRES + (HOLD,)
    over = [tuple(sorted({**FIELD, "slope_x": slope(m), **(field or {})}.items())) for m in every]
    worlds = _c_worlds(dataclasses.replace(sim_cfg, dt=sim.SimConfig.dt),
                       robot_cfg or robot.RobotConfig(), tuple(over))
    mc, q0 = worlds[every.index(name)]
    mc = copy.deepcopy(mc)
    mc.opt.timestep = sim_cfg.physics_dt
    return mc, q0


def run_c(sim_cfg: sim.SimConfig | None = None, robot_cfg: robot.RobotConfig | None = None,
          seconds: float = 4.0, names: tuple[str, ...] = MANOEUVRES, friction: float | None = None,
          field: dict | None = None) -> dict[str, dict[str, np.ndarray]]:
    """`run` in MuJoCo C on the same model (host): each world is built by the MJX code
    (field.generate, sim.world_model, sim.reset) and written into a C model
    (sim.world_mjmodel), then stepped as sim.step does: per physics step the followed command
    ramps (robot.ramp), the servo torque goes to the motors and dt × its stiffness to the wheel
    armature (robot.servo). The worlds are compiled once for every physics step (the step is
    the C model's timestep): seconds instead of minutes on a CPU.

    names: manoeuvres, of MANOEUVRES and HOLD; friction: wheel friction
    written into the C model (None: robot_cfg's); field: FieldParams overrides on top of FIELD
    (`slope_x` is the manoeuvre's unless given). Same samples as `run`."""
    import mujoco

    sim_cfg = sim_config(sim_cfg or sim.SimConfig())
    robot_cfg = robot_cfg or robot.RobotConfig()
    n = math.ceil(seconds * sim_cfg.control_hz - 1e-9)
    dt = sim_cfg.physics_dt
    out = {}
    for name in names:
        mc, q0 = c_world(name, sim_cfg, robot_cfg, field)
        rn = sim.robot_numbers(mc)
        dofs = sim.wheel_dofs(mc)
        wheels = [
            mujoco.mj_name2id(mc, mujoco.mjtObj.mjOBJ_GEOM, f"wheel_{w}") for w in robot.WHEELS
        ]
        chassis = mujoco.mj_name2id(mc, mujoco.mjtObj.mjOBJ_BODY, "chassis")
        if friction is not None:
            mc.geom_friction[wheels, 0] = friction
        arm = mc.dof_armature[dofs].copy()
        d = mujoco.MjData(mc)
        d.qpos[:] = q0
        cmds = commands(name, n).astype(np.float64)
        target = np.zeros(2)
        rec = {k: np.zeros(n) for k in ("x", "z", "pitch", "v", "w")}
        rec.update(bad=np.zeros(n, bool), flipped=np.zeros(n, bool))
        for i in range(n):
            for _ in range(sim_cfg.substeps):
                target = robot.ramp(target, cmds[i], rn, dt)
                tau, stiff = robot.servo(robot.wheel_speeds(target, rn), d.qvel[dofs], rn)
                d.ctrl[:] = tau
                mc.dof_armature[dofs] = arm + dt * stiff
                mujoco.mj_step(mc, d)
            mujoco.mj_kinematics(mc, d)
            xmat = d.xmat[chassis].reshape(3, 3)
            rec["x"][i], rec["z"][i] = d.qpos[0], d.qpos[2]
            rec["pitch"][i] = math.asin(float(np.clip(xmat[2, 0], -1.0, 1.0)))
            rec["v"][i], rec["w"][i] = xmat[:, 0] @ d.qvel[:3], xmat[2] @ d.qvel[3:6]
            finite = np.isfinite(d.qpos).all() and np.isfinite(d.qvel).all()
            rec["bad"][i] = not finite or np.abs(d.qvel).max() > sim_cfg.max_speed
            rec["flipped"][i] = (math.acos(float(np.clip(xmat[2, 2], -1.0, 1.0)))
                                 > math.radians(sim_cfg.max_tilt_deg))
            if rec["bad"][i]:
                break
        rec.update(x0=float(q0[0]), cmd=cmds, slope=float({"slope_x": slope(name), **(field or {})}[
            "slope_x"]), dt=dt,
                   control_hz=sim_cfg.control_hz, wheel_radius=robot_cfg.wheel_radius)
        out[name] = rec
    return out


def figures(traj: dict[str, dict[str, np.ndarray]]) -> dict[str, dict[str, float]]:
    """Manoeuvre name → its figures (see the module doc) from `run`'s samples."""
    out = {}
    for name, t in traj.items():
        hz = t["control_hz"]
        half = len(t["x"]) // 2
        f = {"flipped": float(np.any(t["flipped"]) or np.any(t["bad"]))}
        if name == "start":
            f["overshoot_pct"] = 100.0 * (float(np.max(t["v"])) - V) / V
            outside = np.nonzero(np.abs(t["v"] - V) > 0.05 * V)[0]
            f["settle_s"] = (outside[-1] + 1 if len(outside) else 0) / hz
        elif name == "stop":
            f["pitch_deg"] = math.degrees(float(np.max(np.abs(t["pitch"][half - 1:]))))
            f["stop_cm"] = 100.0 * float(t["x"][-1] - t["x"][half - 1])
        elif name == HOLD:
            f["slide_cm"] = 100.0 * float(t["x"][-1] - t["x0"])
        elif name == "flip_turn":
            f["hop_cm"] = 100.0 * float(np.max(t["z"]) - t["wheel_radius"])
            f["yaw_rate"] = float(np.max(np.abs(t["w"])))
            f["dist_m"] = float(t["x"][-1] - t["x0"])
        else:
            rel = t["pitch"] - math.atan(t["slope"])
            f["pitch_deg"] = math.degrees(float(np.max(np.abs(rel))))
            f["dist_m"] = float(t["x"][-1] - t["x0"])
        out[name] = f
    return out


def table(rows: dict[str, dict[str, dict[str, float]]]) -> str:
    """A plain-text table: one column per configuration label (rows: manoeuvre · figure)."""
    labels = list(rows)
    keys = [(m, k) for m, fs in rows[labels[0]].items() for k in fs]
    width = max(12, *(len(lb) for lb in labels))
    lines = [f"{'manoeuvre':<10} {'figure':<14} " + " ".join(f"{lb:>{width}}" for lb in labels)]
    for m, k in keys:
        vals = " ".join(f"{rows[lb][m][k]:>{width}.3g}" for lb in labels)
        lines.append(f"{m:<10} {k:<14} {vals}")
    return "\n".join(lines)
