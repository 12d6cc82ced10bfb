"""The training schedule: BC / DAgger for the first `bc_fraction` of the budget, then PPO (`phase`,
on the clock of `clock`: time, or the iterations' share where they end first); the phases a call
can reach (`reachable`); the budget a call schedules over when a deadline leaves less
(`call_budget`); whether PPO has run (`ppo_started`) and the log std PPO starts from
(`with_log_std`)."""

from __future__ import annotations

from typing import TYPE_CHECKING

import jax.numpy as jnp
import optax

if TYPE_CHECKING:
    from mjxrow.train.loop import TrainConfig


def call_budget(cfg: TrainConfig, elapsed: float, left: float | None) -> float:
    """The budget [s] this call schedules over: the run's (`cfg.budget_minutes`), cut to
    `elapsed` + `left` where a deadline leaves less (`left`: seconds to the deadline once
    everything is compiled; None: no deadline), so the BC / DAgger share and PPO's both fall
    inside the call."""
    budget = cfg.budget_minutes * 60.0
    return budget if left is None else min(budget, elapsed + max(left, 0.0))


def clock(cfg: TrainConfig, elapsed: float, budget: float, it: int,
          wall: float | None = None) -> float:
    """The schedule's clock [s] for the iteration after `it` done: the budget's `elapsed`, or
    with a deadline the wall time `wall` of the call's training where that ran ahead; with
    `cfg.iterations` at least their share done of `budget` (`budget` · it / iterations), so
    that β, the BC / PPO split and `bc.lr_end` run their course by whichever limit comes
    first (a run stopped by its iterations would otherwise end with β still high)."""
    t = elapsed if wall is None else max(elapsed, wall)
    if cfg.iterations:
        t = max(t, budget * it / cfg.iterations)
    return t


def phase(cfg: TrainConfig, elapsed: float, budget: float,
          ppo_started: bool = False) -> tuple[str, float, float, bool, float]:
    """(phase, beta, noise_std, ppo, lr_scale) at `elapsed` seconds of a `budget` [s]
    (`call_budget`; with a deadline the loop passes the wall time of the call's training where
    it is larger): BC / DAgger for its first `bc_fraction`, then PPO; once PPO has updated the
    network (`ppo_started`, from the PPO optimiser's step count) it stays PPO, whatever budget
    a resumed call has. `lr_scale`: BC's step size, a fraction of its learning rate
    (`bc.lr_end`'s schedule over the phase); 1 in PPO."""
    split = cfg.bc_fraction * budget
    if cfg.bc_fraction >= 1 or (elapsed < split and not ppo_started):
        progress = elapsed / split
        return "bc", cfg.bc.beta(progress), cfg.bc.noise_std, False, cfg.bc.lr_scale(progress)
    return "ppo", 0.0, 0.0, True, 1.0


def reachable(cfg: TrainConfig, elapsed: float, ppo_started: bool) -> list[str]:
    """The phases a call starting at `elapsed` can reach, whose updates it compiles: BC where
    it is the phase now under the whole budget (a deadline only cuts the budget, so the split
    comes no later), PPO unless `bc_fraction` is 1."""
    now = phase(cfg, elapsed, cfg.budget_minutes * 60.0, ppo_started)[0]
    return ["bc"] * (now == "bc") + ["ppo"] * (cfg.bc_fraction < 1)


def with_log_std(params: dict, log_std: float) -> dict:
    """The network's variables with its (state-independent) log std set to `log_std`."""
    p = params["params"]
    return {**params, "params": {**p, "log_std": jnp.full_like(p["log_std"], log_std)}}


def ppo_started(ppo_opt) -> bool:
    """Whether the PPO optimiser has taken a step (its Adam count)."""
    return int(optax.tree_utils.tree_get(ppo_opt, "count")) > 0
