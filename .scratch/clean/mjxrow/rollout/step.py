"""THE control step of one world, shared by the evaluator (`rollout.episode`) and the training
environment (`env.core.Env`): command → one control period of physics → end events → one log
row. The observation and the policy in front of it are the caller's (the evaluator's policy sees
`observation(...)`; an environment's agent sees its own frame), so an oracle episode renders
nothing.

An episode ends at the first event, in this order of precedence: sim_error (NaN or exploded
state, or a non-finite command), flipped, collision (robot footprint touching a plant's
collision footprint, metrics.collides), goal (within `goal_radius`), missed_goal (past the goal's
line: beyond the lane's end + `goal_radius` along the lane), off_patch (the robot left the
simulated terrain), stuck (moved less than `stuck_dist` over `stuck_window` steps), timeout
(after `n_steps`). A step that fails (sim_error) keeps the state before it; a world already
done keeps its state and logs nothing (NaN pose and velocity, alive False, event RUNNING).
"""

from __future__ import annotations

import dataclasses
import math
from typing import Any, ClassVar, NamedTuple

import jax
import jax.numpy as jnp

from mjxrow import control, crops
from mjxrow import field as mjxrow_field
from mjxrow.field import lanes as field_lanes
from mjxrow.physics import sim
from mjxrow.rollout import metrics

CMD_SHAPE = (2,)  # a command: (v [m/s], omega [rad/s])


@dataclasses.dataclass(frozen=True)
class EpisodeConfig:
    """Episode settings (YAML section `episode`; hashable). `crop` picks the plants' collision
    footprint and `sim` holds the physics (control rate, path length, flip threshold); the YAML
    sets those through `preset` and the `sim` section. Everything is static except the
    start-pose noise (`TRACED`), which the rollout takes per episode."""

    crop: str
    max_time: float = 60.0  # s, timeout; an episode has ceil(max_time · sim.control_hz)
    # control steps
    goal_radius: float = 0.40  # m, goal reached within this distance
    stuck_window: int = 45  # control steps between stuck checks (3 s at 15 Hz)
    stuck_dist: float = 0.05  # m, moving less than this over a window is stuck
    collision_window: int = 4  # plants checked each side along a row (metrics.collides)
    end_off_patch: bool = True  # end an episode that leaves the terrain patch as off_patch
    end_missed_goal: bool = True  # end an episode that passes the goal's line as missed_goal
    start_offset_std: float = 0.0  # m, std of the start's lateral offset from the lane centre
    start_yaw_std: float = 0.0  # deg, std of the start heading about the row direction
    sim: sim.SimConfig = sim.SimConfig()

    TRACED: ClassVar[tuple[str, ...]] = ("start_offset_std", "start_yaw_std")

    def __post_init__(self):
        if self.crop not in crops.CROPS:
            raise ValueError(f"episode.crop: unknown crop {self.crop!r}; expected one of "
                             f"{crops.names()}")
        for name in ("stuck_window", "collision_window"):
            if int(getattr(self, name)) < 1:
                raise ValueError(f"episode.{name}: must be at least 1, got {getattr(self, name)}")
        for name in ("max_time", "goal_radius", "stuck_dist"):
            if not getattr(self, name) > 0:
                raise ValueError(f"episode.{name}: must be positive, got {getattr(self, name)}")
        for name in ("start_offset_std", "start_yaw_std"):
            v = getattr(self, name)
            if not (math.isfinite(v) and v >= 0):
                raise ValueError(f"episode.{name}: must be finite and non-negative, got {v}")

    @property
    def n_steps(self) -> int:
        """Control steps before the timeout: ceil(max_time · control_hz)."""
        return max(1, math.ceil(self.max_time * self.sim.control_hz - 1e-9))

    @property
    def control_dt(self) -> float:
        """s, one control period."""
        return 1.0 / self.sim.control_hz

    @property
    def path_length(self) -> float:
        """m, start → goal along the lane (sim.path_length)."""
        return self.sim.path_length

    @property
    def noise(self) -> sim.PoseNoise:
        """The start-pose noise (traced): lateral std [m], heading std [rad]."""
        return sim.pose_noise(self.start_offset_std, math.radians(self.start_yaw_std))

    def static(self) -> EpisodeConfig:
        """This config with the traced fields at their defaults: the compile key."""
        return dataclasses.replace(self, start_offset_std=0.0, start_yaw_std=0.0)


def end_reason(m, s_new: sim.SimState, bad: jax.Array, t: jax.Array, anchor: jax.Array,
               lane: field_lanes.Lane, field: mjxrow_field.Field, half: tuple[float, float],
               cfg: EpisodeConfig) -> jax.Array:
    """int32 [] `metrics.REASONS` code of the step that produced `s_new` (RUNNING if none), for
    the episode here and the training environment alike. m: the world's model; bad: the step
    failed (NaN, exploded, non-finite command); t: int32 [] index of the step; anchor [2]: the
    position at the last stuck check; lane: the driven lane (its end is the goal); half: the
    robot's half length and width [m].
    Precedence: sim_error > flipped > collision > goal > missed_goal > off_patch > stuck >
    timeout."""
    scfg = cfg.sim
    p = sim.pose(s_new)
    goal = field_lanes.goal(lane)
    along = field_lanes.project(lane, p[:2])[0]
    check = (t + 1) % cfg.stuck_window == 0
    events = [  # lowest precedence first: later entries win
        (t >= cfg.n_steps - 1, metrics.TIMEOUT),
        (check & (jnp.linalg.norm(p[:2] - anchor) < cfg.stuck_dist), metrics.STUCK),
        (sim.off_patch(m, s_new, scfg) if cfg.end_off_patch else False, metrics.OFF_PATCH),
        (along > lane.s_end + cfg.goal_radius if cfg.end_missed_goal else False,
         metrics.MISSED_GOAL),
        (jnp.linalg.norm(p[:2] - goal) <= cfg.goal_radius, metrics.GOAL),
        (metrics.collides(p, field, cfg.crop, half, cfg.collision_window), metrics.COLLISION),
        (sim.is_flipped(s_new, scfg), metrics.FLIPPED),
        (bad, metrics.SIM_ERROR),
    ]
    reason = jnp.int32(metrics.RUNNING)
    for happened, code in events:
        reason = jnp.where(happened, code, reason)
    return reason


class Carry(NamedTuple):
    """What a world carries from one control step to the next (besides any policy state)."""

    sim: sim.SimState
    done: jax.Array  # bool [], the episode has ended
    anchor: jax.Array  # float32 [2], the position at the last stuck check [m]


class Row(NamedTuple):
    """One control step's log row (`metrics.Log` holds them as [T] arrays)."""

    pose: jax.Array  # float32 [3], (x, y, yaw) after the step; NaN once done
    cmd: jax.Array  # float32 [2], the command (v [m/s], omega [rad/s])
    alive: jax.Array  # bool [], the episode was running at this step
    event: jax.Array  # int32 [], the end event of this step (metrics.RUNNING if none)
    vel: jax.Array  # float32 [2], body velocity after the step; NaN once done or failed


def start(s0: sim.SimState) -> Carry:
    """The carry of a world at its start state `s0`."""
    return Carry(sim=s0, done=jnp.zeros((), bool), anchor=sim.pose(s0)[:2])


def observation(s: sim.SimState, field: mjxrow_field.Field, lane: field_lanes.Lane,
                aux: Any = None) -> control.Obs:
    """What a controller sees of state `s`: its pose, the lane (its centre line), the goal, the
    camera pose and the field (`aux`: the policy's per-episode data, `Policy.prepare`)."""
    cam_pos, cam_rot = sim.camera_pose(s)
    return control.Obs(pose=sim.pose(s), lane=lane, goal=field_lanes.goal(lane),
                       cam_pos=cam_pos, cam_rot=cam_rot, field=field, aux=aux)


def check_command(cmd) -> jax.Array:
    """`cmd` as float32 [2]; ValueError (at trace time) for another shape."""
    cmd = jnp.asarray(cmd, jnp.float32)
    if cmd.shape != CMD_SHAPE:
        raise ValueError(f"policy: the command must be float [2] = (v [m/s], omega [rad/s]), "
                         f"got shape {cmd.shape}")
    return cmd


def step(m, field: mjxrow_field.Field, lane: field_lanes.Lane, half: tuple[float, float],
         carry: Carry, cmd: jax.Array, t: jax.Array, cfg: EpisodeConfig
         ) -> tuple[Carry, Row, jax.Array]:
    """One world's control step `t` (int32 []) under command `cmd` float32 [2] (v [m/s],
    omega [rad/s]): (next carry, log row, end reason of this step (metrics.RUNNING if none)).
    m: the world's MJX model; lane: the driven lane (`field.lanes.lane`; its end is the goal);
    half: the robot's half length and width [m]."""
    cmd = check_command(cmd)
    s, done = carry.sim, carry.done
    with jax.named_scope("cl_physics"):  # the scopes name the stages in profiles
        s_new = sim.step(m, s, cmd, cfg.sim)
    bad = sim.is_bad(s_new, cfg.sim) | ~jnp.all(jnp.isfinite(cmd))
    p = sim.pose(s_new)
    with jax.named_scope("cl_events"):
        reason = end_reason(m, s_new, bad, t, carry.anchor, lane, field, half, cfg)
    check = (t + 1) % cfg.stuck_window == 0
    keep_old = done | bad
    nxt = Carry(sim=jax.tree.map(lambda x, y: jnp.where(keep_old, x, y), s, s_new),
                done=done | (reason != metrics.RUNNING),
                anchor=jnp.where(check, p[:2], carry.anchor))
    row = Row(pose=jnp.where(done, jnp.nan, p), cmd=cmd, alive=~done,
              event=jnp.where(done, metrics.RUNNING, reason).astype(jnp.int32),
              vel=jnp.where(keep_old, jnp.nan, sim.velocity(s_new)))
    return nxt, row, reason


def record(log: metrics.Log, t: jax.Array, row: Row, reason: jax.Array) -> metrics.Log:
    """`log` ([T] per step) with `row` written at step `t`, ended by `reason` after t + 1 steps
    (an environment's episode so far; the evaluator stacks its rows instead)."""
    return log.replace(pose=log.pose.at[t].set(row.pose), cmd=log.cmd.at[t].set(row.cmd),
                       alive=log.alive.at[t].set(row.alive), event=log.event.at[t].set(row.event),
                       vel=log.vel.at[t].set(row.vel), reason=reason, steps=t + 1)
