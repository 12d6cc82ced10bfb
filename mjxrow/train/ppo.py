"""A compact PPO (Schulman et al. 2017) on optax, with Brax's conventions for time limits: the
advantage is generalised advantage estimation (GAE) with the episodes' terminations cutting
the bootstrap and truncated steps (time limits) contributing no TD error.

    adv, ret = gae(traj, bootstrap, cfg)
    params, opt_state, metrics = sgd(params, opt_state, batch, key, loss_fn, tx, epochs, mbs)

`sgd` (epochs × shuffled minibatches in one `lax.scan`) serves behaviour cloning too.
"""

from __future__ import annotations

import dataclasses
import math
from collections.abc import Callable
from typing import Any

import jax
import jax.numpy as jnp
import optax

from mjxrow.policies import networks as policies_networks
from mjxrow.train import bc as train_bc
from mjxrow.train.rollout import Transition


@dataclasses.dataclass(frozen=True)
class PPOConfig:
    """PPO settings (static)."""

    learning_rate: float = 3e-4  # Adam step size
    discount: float = 0.99  # per control step (15 Hz: a horizon of ~7 s)
    gae_lambda: float = 0.95  # GAE λ
    clip: float = 0.2  # ratio clip ε
    entropy_cost: float = 1e-3  # weight of the entropy bonus
    value_cost: float = 0.5  # weight of the value loss
    epochs: int = 4  # passes over each rollout
    minibatches: int = 32  # minibatches per pass
    max_grad_norm: float = 0.5  # global gradient-norm clip
    reward_scale: float = 1.0  # factor on the rewards before GAE
    start_log_std: float | None = None  # the policy's log std (normalised actions) set when
    # PPO takes over, from BC / DAgger or from `train.init` (BC does not train it; None: as
    # the network holds it, NetConfig.init_log_std for a fresh one)
    teacher_cost: float = 0.0  # weight of the imitation term: the squared error of the mean
    # action to the teacher's on the same observations (DAgger's loss; Rajeswaran et al.
    # 2018's demonstration-augmented policy gradient), which keeps PPO near the teacher's
    # skill while it follows the reward (0: plain PPO)

    def __post_init__(self):
        for name in ("learning_rate", "discount", "clip", "max_grad_norm", "reward_scale"):
            if not getattr(self, name) > 0:
                raise ValueError(f"ppo.{name}: must be positive, got {getattr(self, name)}")
        if not 0 <= self.gae_lambda <= 1:
            raise ValueError(f"ppo.gae_lambda: must lie in [0, 1], got {self.gae_lambda}")
        for name in ("epochs", "minibatches"):
            if int(getattr(self, name)) < 1:
                raise ValueError(f"ppo.{name}: must be at least 1, got {getattr(self, name)}")
        for name in ("entropy_cost", "value_cost", "teacher_cost"):
            v = getattr(self, name)
            if isinstance(v, bool) or not isinstance(v, (int, float)) or not v >= 0:
                raise ValueError(f"ppo.{name}: must be a non-negative number, got {v!r}")
        v = self.start_log_std
        if v is not None and (isinstance(v, bool) or not isinstance(v, (int, float))
                              or not math.isfinite(v)):
            raise ValueError(f"ppo.start_log_std: must be a finite number or null, got {v!r}")


def optimizer(learning_rate: float, max_grad_norm: float) -> optax.GradientTransformation:
    return optax.chain(optax.clip_by_global_norm(max_grad_norm), optax.adam(learning_rate))


def gae(traj: Transition, bootstrap: jax.Array, discount: float, lam: float,
        reward_scale: float = 1.0) -> tuple[jax.Array, jax.Array]:
    """(advantages, value targets), float32 [T, B] each, of a rollout [T, B] whose last
    observation's values are `bootstrap` [B]. A terminated step (done, not truncated) does not
    bootstrap; a truncated step's TD error is zeroed, as Brax's PPO does."""
    term = traj.done * (1.0 - traj.truncation)
    keep = 1.0 - traj.truncation
    v_next = jnp.concatenate([traj.value[1:], bootstrap[None]], 0)
    delta = (traj.reward * reward_scale + discount * (1.0 - term) * v_next - traj.value) * keep

    def back(acc, x):
        d, t, k = x
        acc = d + discount * lam * (1.0 - t) * k * acc
        return acc, acc

    _, adv = jax.lax.scan(back, jnp.zeros_like(bootstrap), (delta, term, keep), reverse=True)
    return adv, adv + traj.value


def loss(net: policies_networks.PolicyNet, cfg: PPOConfig):
    """The clipped PPO loss on a minibatch dict (obs, action, log_prob, advantage, target,
    teacher), plus `cfg.teacher_cost` · the mean action's squared error to the teacher's:
    `(params, batch) -> (loss, metrics)`."""

    def fn(params, b):
        mean, log_std, value = net.apply(params, b["obs"])
        logp = policies_networks.log_prob(mean, log_std, b["action"])
        adv = b["advantage"]
        adv = (adv - adv.mean()) / (adv.std() + 1e-8)
        ratio = jnp.exp(logp - b["log_prob"])
        pg = -jnp.mean(jnp.minimum(ratio * adv,
                                   jnp.clip(ratio, 1 - cfg.clip, 1 + cfg.clip) * adv))
        v_loss = 0.5 * jnp.mean((b["target"] - value) ** 2)
        ent = policies_networks.entropy(log_std)
        imitation = train_bc.teacher_error(mean, b["teacher"])
        total = (pg + cfg.value_cost * v_loss - cfg.entropy_cost * ent
                 + cfg.teacher_cost * imitation)
        return total, {"loss": total, "policy_loss": pg, "value_loss": v_loss,
                       "teacher_loss": imitation,
                       "entropy": ent, "approx_kl": jnp.mean(b["log_prob"] - logp),
                       "clip_frac": jnp.mean(jnp.abs(ratio - 1) > cfg.clip)}

    return fn


def batch(traj: Transition, advantage: jax.Array, target: jax.Array) -> dict:
    """The flat training batch [T·B, ...] of a rollout."""
    flat = lambda x: x.reshape((-1,) + x.shape[2:])  # noqa: E731
    out = {"obs": jax.tree.map(flat, traj.obs), "action": flat(traj.action),
           "log_prob": flat(traj.log_prob), "teacher": flat(traj.teacher),
           "advantage": flat(advantage), "target": flat(target)}
    if traj.lane_error is not None:
        out["lane_error"] = flat(traj.lane_error)
    return out


def sgd(params: Any, opt_state: Any, data: dict, key: jax.Array,
        loss_fn: Callable, tx: optax.GradientTransformation, epochs: int, minibatches: int,
        scale: jax.Array | None = None):
    """`epochs` passes over `data` (a dict of [N, ...] arrays) in `minibatches` shuffled
    minibatches (N rounded down to a multiple), one optax step each, its updates times `scale`
    (traced: a learning-rate schedule; None: 1). Returns (params, opt_state, mean metrics
    over the steps)."""
    n = jax.tree.leaves(data)[0].shape[0]
    size = n // minibatches
    if size < 1:
        raise ValueError(f"minibatches: {minibatches} minibatches of {n} samples")

    def step(carry, idx):
        params, opt_state = carry
        mb = jax.tree.map(lambda x: x[idx], data)
        grads, metrics = jax.grad(loss_fn, has_aux=True)(params, mb)
        updates, opt_state = tx.update(grads, opt_state, params)
        if scale is not None:
            updates = jax.tree.map(lambda u: scale * u, updates)
        metrics["grad_norm"] = optax.global_norm(grads)
        return (optax.apply_updates(params, updates), opt_state), metrics

    perms = jax.vmap(lambda k: jax.random.permutation(k, n)[:size * minibatches])(
        jax.random.split(key, epochs))
    idx = perms.reshape(epochs * minibatches, size)
    (params, opt_state), metrics = jax.lax.scan(step, (params, opt_state), idx)
    return params, opt_state, jax.tree.map(jnp.mean, metrics)
