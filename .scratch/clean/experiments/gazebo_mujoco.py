"""The MuJoCo side of `experiments/gazebo_check.sh`: one exported world's robot driven open loop
by the closed loop's own physics, stepped in MuJoCo C as `physics.sim.step` steps it (the
world built by `sim.world_model` for the episode `python -m mjxrow.worlds` exports, the command
ramped by `robot.ramp`, the wheel servos of `robot.servo` with their implicit stiffness in
the armature, the obstacle slots refilled every control period).

    python experiments/gazebo_mujoco.py --preset pear --set field.terrain_dh=0 \
        --cmd 0.5 0 --seconds 40 --at 1.5708

prints one line of JSON: the start pose and, at each time of `--at` (default: the end), the
pose (x, y, z [m], roll, pitch, yaw [rad], world frame) and the displacement in the start's
heading frame (forward, left [m], yaw change [rad]); and `wheel_speeds`, the wheel speed
targets [rad/s] (fl, fr, rl, rr) of the command once ramped up (`robot.wheel_speeds`), which the
check gives the Gazebo robot's wheel joints.
"""

from __future__ import annotations

import argparse
import json
import math

import jax
import jax.numpy as jnp
import mujoco
import numpy as np

from mjxrow.physics import robot, sim
from mjxrow.worlds import replay, scene


def world(preset: str, seed: int, sets: list[str], episode: int, lane: int | None):
    """(C model, start qpos float [nq], C-side MJX world model, SimConfig) of the episode that
    `python -m mjxrow.worlds --preset ... --seed ... --episode ... --set ...` exports."""
    run, shape = replay.resolve_run(preset, seed, sets)
    ep = replay.episode_world(run, shape, episode, lane)
    cfg = ep.robot.sim
    m, mx = sim.make_model(ep.shape, cfg, ep.robot.robot)
    field_lane = int(scene.field_lanes(ep.field)[ep.start.lane])
    mw = jax.jit(sim.world_model, static_argnums=3)(mx, ep.field, jnp.int32(field_lane), cfg)
    q0 = np.zeros(m.nq)
    q0[:7] = ep.start.qpos
    return sim.world_mjmodel(m, mw), q0, mw, cfg


def pose(d: mujoco.MjData) -> np.ndarray:
    """float64 [6]: the chassis (x, y, z, roll, pitch, yaw)."""
    return np.r_[d.qpos[:3], scene.euler_zyx(scene.quat_rot(d.qpos[3:7]))[::-1]]


def drive(preset: str, cmd: tuple[float, float], seconds: float, at: list[float] | None = None,
          seed: int = 0, sets: list[str] = (), episode: int = 0,
          lane: int | None = None) -> dict:
    """Drive (v [m/s], ω [rad/s]) = cmd open loop from rest for `seconds` (whole control
    periods); poses at the times `at` [s] (rounded to control periods; default: the end)."""
    mc, q0, mw, cfg = world(preset, seed, list(sets), episode, lane)
    rn = sim.robot_numbers(mc)
    dofs = sim.wheel_dofs(mc)
    arm = mc.dof_armature[dofs].copy()
    wheels = [mujoco.mj_name2id(mc, mujoco.mjtObj.mjOBJ_BODY, f"wheel_{n}") for n in robot.WHEELS]
    refresh = jax.jit(sim.refresh_contacts)
    d = mujoco.MjData(mc)
    d.qpos[:] = q0
    mujoco.mj_forward(mc, d)
    start = pose(d)
    n = math.ceil(seconds * cfg.control_hz - 1e-9)
    marks = {min(n, max(1, round(t * cfg.control_hz))): t for t in (at or [seconds])}
    target, out = np.zeros(2), []
    for i in range(1, n + 1):
        mujoco.mj_kinematics(mc, d)
        slots = refresh(mw, jnp.asarray(d.xpos[wheels, :2], jnp.float32))
        for name in ("geom_pos", "geom_quat", "geom_size"):
            getattr(mc, name)[:] = np.asarray(getattr(slots, name))
        for _ in range(cfg.substeps):
            target = robot.ramp(target, np.asarray(cmd, np.float64), rn, cfg.physics_dt)
            tau, stiff = robot.servo(robot.wheel_speeds(target, rn), d.qvel[dofs], rn)
            d.ctrl[:] = tau
            mc.dof_armature[dofs] = arm + cfg.physics_dt * stiff
            mujoco.mj_step(mc, d)
        if i in marks:
            p = pose(d)
            dx, dy = p[:2] - start[:2]
            c, s = math.cos(start[5]), math.sin(start[5])
            out.append({"t": i / cfg.control_hz, "pose": p.round(5).tolist(),
                        "forward": round(c * dx + s * dy, 5), "left": round(-s * dx + c * dy, 5),
                        "dyaw": round(math.remainder(p[5] - start[5], math.tau), 5)})
    wheel = robot.wheel_speeds(robot.ramp(np.zeros(2), np.asarray(cmd, np.float64), rn, math.inf),
                               rn)
    return {"start": start.round(5).tolist(), "dt": cfg.physics_dt, "at": out,
            "wheel_speeds": np.round(wheel, 5).tolist()}


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--preset", required=True)
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--episode", type=int, default=0)
    ap.add_argument("--lane", type=int)
    ap.add_argument("--set", action="append", default=[], dest="sets")
    ap.add_argument("--cmd", type=float, nargs=2, default=(0.5, 0.0), metavar=("V", "OMEGA"))
    ap.add_argument("--seconds", type=float, default=40.0)
    ap.add_argument("--at", type=float, nargs="*")
    a = ap.parse_args()
    print(json.dumps(drive(a.preset, tuple(a.cmd), a.seconds, a.at, a.seed, a.sets, a.episode,
                           a.lane)))


if __name__ == "__main__":
    main()
