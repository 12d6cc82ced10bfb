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

With `replay` R > 0 the updates also see earlier rollouts (DAgger's aggregated data set, held to
one rollout's size): a buffer of N samples (N = a rollout's, T · B) holding the first rollout
whole, then 1/R of every later rollout in turn, chosen at random, written over the oldest
(`replay_mix`). Each BC update trains on the current rollout and the buffer as it was (2N
samples, in the same number of minibatches), so the network keeps the states it reached R
rollouts ago while it learns its own newest ones.
"""

from __future__ import annotations

import dataclasses

import jax
import jax.numpy as jnp

from mjxrow.policies import networks as policies_networks
from mjxrow.policies import observe as policies_observe


@dataclasses.dataclass(frozen=True)
class BCConfig:
    """Behaviour cloning / DAgger settings (static)."""

    learning_rate: float = 1e-3  # Adam step size
    epochs: int = 2  # passes over each rollout
    minibatches: int = 32  # minibatches per pass (15,360 samples each at the default
    # 15,360 worlds and 32 steps)
    dagger: bool = True  # the learner acts more and more (β falls to 0); False: plain BC
    beta_until: float = 1.0  # fraction of the phase over which β falls from 1 to 0 (the
    # network alone, β = 0, drifts from the teacher: docs/training.md, fifth round)
    noise_std: float = 0.2  # std of the noise on the acting action (normalised units)
    value_cost: float = 0.5  # weight of the value loss
    max_grad_norm: float = 1.0  # global gradient-norm clip
    aux_cost: float = 1.0  # weight of the auxiliary head's loss (a network with `net.aux`)
    replay: int = 0  # earlier rollouts the updates also see, 1/replay of each (0: the current
    # rollout alone; a buffer of one rollout's samples, ~6 GB of 64 × 64 images at 15,360 worlds)
    lr_end: float = 1.0  # the step size at the end of the phase, a fraction of learning_rate
    # (linear from 1 at its start; 1: constant)
    mirror: bool = False  # every update sees a random half of its samples mirrored left-right
    # (`mirrored`: image flipped, ω negated), so the network learns no left-right bias (not yet
    # measured under a full schedule: docs/training.md, seventh round)

    def __post_init__(self):
        for name in ("learning_rate", "max_grad_norm"):
            if not getattr(self, name) > 0:
                raise ValueError(f"bc.{name}: must be positive, got {getattr(self, name)}")
        for name in ("noise_std", "value_cost", "aux_cost"):
            if not getattr(self, name) >= 0:
                raise ValueError(f"bc.{name}: must be non-negative, got {getattr(self, name)}")
        if not isinstance(self.mirror, bool):
            raise ValueError(f"bc.mirror: must be true or false, got {self.mirror!r}")
        if not 0 <= self.lr_end <= 1:
            raise ValueError(f"bc.lr_end: must lie in [0, 1], got {self.lr_end}")
        if not 0 < self.beta_until <= 1:
            raise ValueError(f"bc.beta_until: must lie in (0, 1], got {self.beta_until}")
        for name in ("epochs", "minibatches"):
            if int(getattr(self, name)) < 1:
                raise ValueError(f"bc.{name}: must be at least 1, got {getattr(self, name)}")
        if isinstance(self.replay, bool) or int(self.replay) != self.replay or self.replay < 0:
            raise ValueError(f"bc.replay: must be a whole number ≥ 0, got {self.replay!r}")

    def beta(self, progress: float) -> float:
        """Probability that the teacher acts at `progress` ∈ [0, 1] of the phase."""
        if not self.dagger:
            return 1.0
        return float(max(0.0, 1.0 - progress / self.beta_until))

    def lr_scale(self, progress: float) -> float:
        """The step size at `progress` ∈ [0, 1] of the phase, a fraction of learning_rate."""
        return float(1.0 - (1.0 - self.lr_end) * min(1.0, max(0.0, progress)))


REPLAYED = ("obs", "teacher", "target", "lane_error")  # what the buffer keeps of a training
# batch (those of them the batch has)


def replay_buffer(batch: dict) -> dict:
    """An empty buffer for training batches like `batch` (a dict of [N, ...] arrays or their
    shapes): zeros of the `REPLAYED` entries, `pos` 0 (the next slot to write), `filled`
    False (the first `replay_mix` writes the whole of its rollout)."""
    zeros = lambda x: jnp.zeros(x.shape, x.dtype)  # noqa: E731
    return {**{k: jax.tree.map(zeros, batch[k]) for k in REPLAYED if k in batch},
            "pos": jnp.int32(0), "filled": jnp.bool_(False)}


def replay_mix(buffer: dict, batch: dict, key: jax.Array, spans: int) -> tuple[dict, dict]:
    """(training data, the buffer after): the `REPLAYED` entries of `batch` ([N, ...]) followed
    by the buffer's (2N samples), and the buffer with 1/`spans` of `batch` (N // spans samples
    at random) written over its slot `pos` (slots of N // spans samples, in turn); an empty
    buffer (`filled` False) first takes the whole batch, shuffled."""
    n = jax.tree.leaves(batch["teacher"])[0].shape[0]
    k = max(1, n // spans)
    names = [name for name in REPLAYED if name in buffer]
    cur = {name: batch[name] for name in names}
    k_fill, k_pick = jax.random.split(key)
    old = jax.lax.cond(buffer["filled"],
                       lambda: {name: buffer[name] for name in names},
                       lambda: jax.tree.map(lambda x: x[jax.random.permutation(k_fill, n)], cur))
    data = jax.tree.map(lambda a, b: jnp.concatenate([a, b]), cur, old)
    pick = jax.random.permutation(k_pick, n)[:k]
    start = buffer["pos"] * k

    def write(dst, src):
        part = src[pick]
        return jax.lax.dynamic_update_slice(dst, part, (start,) + (0,) * (dst.ndim - 1))

    slots = n // k
    after = {**jax.tree.map(write, old, cur), "pos": (buffer["pos"] + 1) % slots,
             "filled": jnp.bool_(True)}
    return data, after


def mirror_flags(key: jax.Array, n: int) -> jax.Array:
    """bool [n]: which of n samples `mirrored` mirrors (a random half, each with p = 0.5)."""
    return jax.random.bernoulli(key, 0.5, (n,))


def mirrored(b: dict) -> dict:
    """The training batch `b` with every sample whose `b['mirror']` is set mirrored
    left-right, as the same world seen in a mirror: its image ([..., H, W, C]) flipped along
    the width, ω negated in the proprioception (measured and previous action) and in the
    teacher's action; v and the value target stay. Without 'mirror', `b` as it is."""
    if "mirror" not in b:
        return b
    m = b["mirror"]
    obs = dict(b["obs"])
    img = obs["image"]
    obs["image"] = jnp.where(m.reshape(m.shape + (1,) * (img.ndim - 1)),
                             jnp.flip(img, axis=-2), img)
    signs = lambda s: jnp.where(m[:, None], jnp.array(s), 1.0)  # noqa: E731
    if "proprio" in obs:
        obs["proprio"] = obs["proprio"] * signs(policies_observe.PROPRIO_MIRROR)
    teacher = b["teacher"] * signs(policies_observe.ACTION_MIRROR)
    out = {**b, "obs": obs, "teacher": teacher}
    if "lane_error" in b:  # the offset and the heading error change sign
        out["lane_error"] = b["lane_error"] * signs((-1.0, -1.0))
    return out


def teacher_error(mean: jnp.ndarray, teacher: jnp.ndarray) -> jnp.ndarray:
    """The mean over samples of the squared error of the network's mean action to the
    teacher's (summed over the 2 normalised action dims): BC's loss, and PPO's teacher term."""
    return jnp.mean(jnp.sum((mean - teacher) ** 2, -1))


def lane_error_loss(pred: jnp.ndarray, lane_error: jnp.ndarray) -> jnp.ndarray:
    """The auxiliary head's loss: the mean over samples of the squared error of its prediction
    (units of `networks.LANE_ERROR_SCALE`) to the lane error (offset [m], heading [rad])."""
    target = lane_error / jnp.asarray(policies_networks.LANE_ERROR_SCALE, lane_error.dtype)
    return jnp.mean(jnp.sum((pred - target) ** 2, -1))


def loss(net: policies_networks.PolicyNet, value_cost: float, aux_cost: float = 0.0):
    """`(params, batch) -> (loss, metrics)`: MSE of the mean action to the teacher's plus
    `value_cost` · the value head's squared error to the λ-return targets, plus with the
    network's `aux` head `aux_cost` · its `lane_error_loss`, on the batch `mirrored` where it
    flags samples."""

    def fn(params, b):
        b = mirrored(b)
        if net.cfg.aux:
            (mean, _, value), pred = policies_networks.lane_error_prediction(net, params,
                                                                             b["obs"])
            aux = {"lane_error_loss": lane_error_loss(pred, b["lane_error"])}
        else:
            (mean, _, value), aux = net.apply(params, b["obs"]), {}
        bc = teacher_error(mean, b["teacher"])
        v_loss = 0.5 * jnp.mean((b["target"] - value) ** 2)
        total = bc + value_cost * v_loss + aux_cost * sum(aux.values())
        return total, {"loss": total, "bc_loss": bc, "value_loss": v_loss,
                       "omega_error": jnp.mean(jnp.abs(mean[:, 1] - b["teacher"][:, 1])),
                       **aux}

    return fn
