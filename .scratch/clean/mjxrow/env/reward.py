"""The environment's reward terms. Its episodes end where the sweep's would: the environment
calls `rollout.step.step`, the evaluation episode's own step
(`tests/test_env.py` checks this on an oracle episode against `rollout.episode.episode`).

Reward of one control step (each term is logged as a metric `reward/<term>`):

- progress: `w_progress` · Δs [m], the advance along the lane's centre line;
- lateral: −`w_lateral` · |offset| [m] · dt [s], offset from the lane's centre line;
- heading: −`w_heading` · |yaw − the line's direction| [rad] · dt [s], heading error;
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
from mjxrow.field import lanes as field_lanes
from mjxrow.field.lanes import Lane
from mjxrow.rollout import metrics as rollout_metrics

TERMS = ("progress", "lateral", "heading", "collision", "goal", "failure")
FAILURES = (
    rollout_metrics.FLIPPED,
    rollout_metrics.OFF_PATCH,
    rollout_metrics.MISSED_GOAL,
    rollout_metrics.STUCK,
    rollout_metrics.SIM_ERROR,
)


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


def terms(prev_pose: jax.Array, pose: jax.Array, lane: Lane, reason: jax.Array,
          dt: float) -> dict[str, jax.Array]:
    """Unweighted reward terms of one step (float32 [] each, signs as in the module doc):
    prev_pose, pose [3] (x, y, yaw) before and after the step; lane: the driven lane's centre
    line; reason: the step's end code; dt [s] the control period."""
    pose = jnp.where(jnp.all(jnp.isfinite(pose)), pose, prev_pose)
    f = lambda c: c.astype(jnp.float32)  # noqa: E731
    failure = jnp.zeros((), bool)
    for code in FAILURES:
        failure = failure | (reason == code)
    s, offset, direction = field_lanes.project(lane, pose[:2])
    s_prev = field_lanes.project(lane, prev_pose[:2])[0]
    return {
        "progress": f(s - s_prev),
        "lateral": -jnp.abs(offset) * dt,
        "heading": -jnp.abs(wrap_angle(pose[2] - direction)) * dt,
        "collision": -f(reason == rollout_metrics.COLLISION),
        "goal": f(reason == rollout_metrics.GOAL),
        "failure": -f(failure),
    }


def total(cfg: RewardConfig, parts: dict[str, jax.Array]) -> jax.Array:
    """The weighted sum of `terms`."""
    return sum(getattr(cfg, f"w_{k}") * parts[k] for k in TERMS)
