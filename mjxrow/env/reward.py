"""The environment's end-of-episode events (as the evaluation episode decides them) and its
reward terms.

`end_reason` takes the same inputs in the same order of precedence as `rollout.episode`'s step
(sim_error > flipped > collision > goal > missed_goal > off_patch > stuck > timeout), so an
episode of the environment ends where the sweep's would; `tests/test_env.py` checks this on an
oracle episode against `rollout.episode.episode`.

Reward of one control step (each term is logged as a metric `reward/<term>`):

- progress: `w_progress` · Δx [m], the advance along the lane (rows run along +x);
- lateral: −`w_lateral` · |y − lane_y| [m] · dt [s], offset from the lane centre line;
- heading: −`w_heading` · |yaw| [rad] · dt [s], heading error from the row direction;
- collision: −`w_collision` when the step ends the episode touching a plant;
- goal: +`w_goal` when it ends within the goal radius;
- failure: −`w_failure` when it ends otherwise before the timeout (flipped, missed goal, off
  the terrain patch, stuck, simulation error).
"""

from __future__ import annotations

import dataclasses

import jax
import jax.numpy as jnp

from mjxrow.control.base import wrap_angle
from mjxrow.physics import sim
from mjxrow.rollout import metrics as M

TERMS = ("progress", "lateral", "heading", "collision", "goal", "failure")
FAILURES = (M.FLIPPED, M.OFF_PATCH, M.MISSED_GOAL, M.STUCK, M.SIM_ERROR)


@dataclasses.dataclass(frozen=True)
class RewardConfig:
    """Weights of the reward terms (static)."""

    w_progress: float = 1.0  # per metre advanced along the lane
    w_lateral: float = 1.0  # per metre of lateral offset, per second
    w_heading: float = 0.5  # per radian of heading error, per second
    w_collision: float = 10.0  # once, at a collision with a plant
    w_goal: float = 10.0  # once, at the goal
    w_failure: float = 10.0  # once, at any other early end

    def __post_init__(self):
        for f in dataclasses.fields(self):
            if not getattr(self, f.name) >= 0:
                raise ValueError(f"env.reward.{f.name}: must be non-negative, got "
                                 f"{getattr(self, f.name)}")


def end_reason(m, s_new: sim.SimState, bad: jax.Array, t: jax.Array, anchor: jax.Array,
               goal: jax.Array, field, half: tuple[float, float], cfg) -> jax.Array:
    """int32 [] `metrics.REASONS` code of the step that produced `s_new` (RUNNING if none), as
    `rollout.episode` decides it. m: the world's model; bad: the step failed (NaN, exploded,
    non-finite command); t: int32 [] index of the step; anchor [2]: the position at the last
    stuck check; goal [2]; half: the robot's half length and width [m]; cfg: the static
    `rollout.episode.EpisodeConfig`."""
    scfg = cfg.sim
    p = sim.pose(s_new)
    check = (t + 1) % cfg.stuck_window == 0
    events = [  # lowest precedence first: later entries win (rollout.episode's order)
        (t >= cfg.n_steps - 1, M.TIMEOUT),
        (check & (jnp.linalg.norm(p[:2] - anchor) < cfg.stuck_dist), M.STUCK),
        (sim.off_patch(m, s_new, scfg) if cfg.end_off_patch else False, M.OFF_PATCH),
        (p[0] > goal[0] + cfg.goal_radius if cfg.end_missed_goal else False, M.MISSED_GOAL),
        (jnp.linalg.norm(p[:2] - goal) <= cfg.goal_radius, M.GOAL),
        (M.collides(p, field, cfg.crop, half, cfg.collision_window), M.COLLISION),
        (sim.is_flipped(s_new, scfg), M.FLIPPED),
        (bad, M.SIM_ERROR),
    ]
    reason = jnp.int32(M.RUNNING)
    for happened, code in events:
        reason = jnp.where(happened, code, reason)
    return reason


def terms(prev_pose: jax.Array, pose: jax.Array, lane_y: jax.Array, reason: jax.Array,
          dt: float) -> dict[str, jax.Array]:
    """Unweighted reward terms of one step (float32 [] each, signs as in the module doc):
    prev_pose, pose [3] (x, y, yaw) before and after the step; lane_y []; reason: the step's
    end code; dt [s] the control period."""
    pose = jnp.where(jnp.all(jnp.isfinite(pose)), pose, prev_pose)
    f = lambda c: c.astype(jnp.float32)  # noqa: E731
    failure = jnp.zeros((), bool)
    for code in FAILURES:
        failure = failure | (reason == code)
    return {
        "progress": f(pose[0] - prev_pose[0]),
        "lateral": -jnp.abs(pose[1] - lane_y) * dt,
        "heading": -jnp.abs(wrap_angle(pose[2])) * dt,
        "collision": -f(reason == M.COLLISION),
        "goal": f(reason == M.GOAL),
        "failure": -f(failure),
    }


def total(cfg: RewardConfig, parts: dict[str, jax.Array]) -> jax.Array:
    """The weighted sum of `terms`."""
    return sum(getattr(cfg, f"w_{k}") * parts[k] for k in TERMS)
