"""Behaviour cloning and DAgger (Ross et al. 2011) from a teacher controller (the oracle's pure
pursuit on the true pose, or SegZeros on the ground-truth mask: the environment's run
controller), in the same batched rollouts as PPO (`train.rollout.unroll`).

Every iteration rolls out with the teacher acting with probability β (per world and step) and
the network otherwise, noise of std `noise_std` on either (states off the teacher's path), and
regresses the network's mean on the teacher's action at every visited observation (mean
squared error over the 2 normalised action dims). With `dagger` β falls linearly from 1 to 0
over the first `beta_until` of the phase (the learner visits its own states, the teacher labels
them); without it β stays 1 (plain behaviour cloning). The value head learns the λ-returns of
the same rollouts, so PPO can start from this network with a trained critic.
"""

from __future__ import annotations

import dataclasses

import jax.numpy as jnp

from mjxrow.policies import networks as policies_networks


@dataclasses.dataclass(frozen=True)
class BCConfig:
    """Behaviour cloning / DAgger settings (static)."""

    learning_rate: float = 1e-3  # Adam step size
    epochs: int = 2  # passes over each rollout
    minibatches: int = 32  # minibatches per pass (15,360 samples each at the default
    # 15,360 worlds and 32 steps)
    dagger: bool = True  # the learner acts more and more (β falls to 0); False: plain BC
    beta_until: float = 1.0  # fraction of the phase over which β falls from 1 to 0 (the
    # network alone, β = 0, drifts from the teacher: docs/training.md, sixth round)
    noise_std: float = 0.2  # std of the noise on the acting action (normalised units)
    value_cost: float = 0.5  # weight of the value loss
    max_grad_norm: float = 1.0  # global gradient-norm clip

    def __post_init__(self):
        for name in ("learning_rate", "max_grad_norm"):
            if not getattr(self, name) > 0:
                raise ValueError(f"bc.{name}: must be positive, got {getattr(self, name)}")
        for name in ("noise_std", "value_cost"):
            if not getattr(self, name) >= 0:
                raise ValueError(f"bc.{name}: must be non-negative, got {getattr(self, name)}")
        if not 0 < self.beta_until <= 1:
            raise ValueError(f"bc.beta_until: must lie in (0, 1], got {self.beta_until}")
        for name in ("epochs", "minibatches"):
            if int(getattr(self, name)) < 1:
                raise ValueError(f"bc.{name}: must be at least 1, got {getattr(self, name)}")

    def beta(self, progress: float) -> float:
        """Probability that the teacher acts at `progress` ∈ [0, 1] of the phase."""
        if not self.dagger:
            return 1.0
        return float(max(0.0, 1.0 - progress / self.beta_until))


def teacher_error(mean: jnp.ndarray, teacher: jnp.ndarray) -> jnp.ndarray:
    """The mean over samples of the squared error of the network's mean action to the
    teacher's (summed over the 2 normalised action dims): BC's loss, and PPO's teacher term."""
    return jnp.mean(jnp.sum((mean - teacher) ** 2, -1))


def loss(net: policies_networks.PolicyNet, value_cost: float):
    """`(params, batch) -> (loss, metrics)`: MSE of the mean action to the teacher's plus
    `value_cost` · the value head's squared error to the λ-return targets."""

    def fn(params, b):
        mean, _, value = net.apply(params, b["obs"])
        bc = teacher_error(mean, b["teacher"])
        v_loss = 0.5 * jnp.mean((b["target"] - value) ** 2)
        total = bc + value_cost * v_loss
        return total, {"loss": total, "bc_loss": bc, "value_loss": v_loss,
                       "omega_error": jnp.mean(jnp.abs(mean[:, 1] - b["teacher"][:, 1]))}

    return fn
