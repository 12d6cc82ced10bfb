"""The policy network: a small CNN torso over the image observation (plus the proprioception
vector), a Gaussian policy head and a value head (Flax linen).

    net = PolicyNet(NetConfig())
    mean, log_std, value = net.apply(params, obs)   # obs: env.observe's dict, any batch axes

mean float32 [..., 2] (the action's mean, not squashed: the environment clips to [-1, 1]),
log_std float32 [2] (state-independent), value float32 [...]. Images: uint8 (RGB, mask) are
scaled to [-0.5, 0.5]; float features pass as they are. Convolutions pad SAME, so any image
size works (a 16 × 16 test image included).

With `symmetric` the network is left-right equivariant by construction: it runs its torso on
the observation and on its mirror image (the image flipped along its width, ω negated in the
proprioception: `observe.PROPRIO_MIRROR`) and averages, ω's mean antisymmetrically, so that
the mirrored world gets the mirrored action and the same value. A world that looks the same in
a mirror (a straight lane, seen from its centre) then gets ω = 0 exactly: no left-right bias
is left for training to remove.

With `aux` the network also has an auxiliary head on the same features: it predicts where the
robot stands in its lane, the lateral offset and the heading error (`env.core.lane_error`, in
units of `LANE_ERROR_SCALE`), which behaviour cloning learns beside the action
(`bc.aux_cost`), so that the torso keeps what the offset looks like. The head is sown into
the `intermediates` collection (`lane_error_head`); acting ignores it.
"""

from __future__ import annotations

import dataclasses
import math
from typing import Any

import flax.linen as nn
import jax
import jax.numpy as jnp

from mjxrow.policies import observe


@dataclasses.dataclass(frozen=True)
class NetConfig:
    """Architecture of the policy network (static; saved with the checkpoint)."""

    channels: tuple[int, ...] = (16, 32, 32)  # conv layers' output channels
    kernels: tuple[int, ...] = (8, 4, 3)  # their square kernel sizes [px]
    strides: tuple[int, ...] = (4, 2, 2)  # their strides
    hidden: int = 256  # units of the dense layer after the torso
    init_log_std: float = -1.0  # initial log std of the Gaussian policy (normalised actions)
    symmetric: bool = False  # left-right equivariant: the torso sees the observation and its
    # mirror image, ω's mean is their antisymmetric average (twice the torso's work)
    aux: bool = False  # an auxiliary head predicting the lane offset and heading error (doc)

    def __post_init__(self):
        object.__setattr__(self, "channels", tuple(int(c) for c in self.channels))
        object.__setattr__(self, "kernels", tuple(int(k) for k in self.kernels))
        object.__setattr__(self, "strides", tuple(int(s) for s in self.strides))
        if not len(self.channels) == len(self.kernels) == len(self.strides):
            raise ValueError(f"net: channels, kernels and strides need equal lengths, got "
                             f"{self.channels}, {self.kernels}, {self.strides}")
        if int(self.hidden) < 1:
            raise ValueError(f"net.hidden: must be at least 1, got {self.hidden}")
        for name in ("symmetric", "aux"):
            if not isinstance(getattr(self, name), bool):
                raise ValueError(f"net.{name}: must be true or false, got "
                                 f"{getattr(self, name)!r}")

    def to_dict(self) -> dict[str, Any]:
        return {f.name: (list(v) if isinstance(v := getattr(self, f.name), tuple) else v)
                for f in dataclasses.fields(self)}

    @classmethod
    def from_dict(cls, d: dict[str, Any]) -> NetConfig:
        known = {f.name for f in dataclasses.fields(cls)}
        unknown = sorted(set(d) - known)
        if unknown:
            raise ValueError(f"network: unknown keys {unknown}")
        return cls(**{k: tuple(v) if isinstance(v, list) else v for k, v in d.items()})


# the auxiliary head's units: the lateral offset per 0.5 m, the heading error per 0.25 rad
LANE_ERROR_SCALE = (0.5, 0.25)

TINY = NetConfig(channels=(4, 8), kernels=(4, 3), strides=(2, 2), hidden=16)


class PolicyNet(nn.Module):
    """obs dict → (mean [..., 2], log_std [2], value [...]); see the module doc."""

    cfg: NetConfig = NetConfig()

    @nn.compact
    def __call__(self, obs: dict[str, jax.Array]) -> tuple[jax.Array, jax.Array, jax.Array]:
        img = obs["image"]
        batch = img.shape[:-3]
        x = img.reshape((-1,) + img.shape[-3:])
        n = x.shape[0]
        p = obs["proprio"].reshape(n, -1) if "proprio" in obs else None
        if self.cfg.symmetric:  # the observation and its mirror image, one batch
            x = jnp.concatenate([x, jnp.flip(x, axis=-2)])
            if p is not None:
                p = jnp.concatenate([p, p * jnp.asarray(observe.PROPRIO_MIRROR, p.dtype)])
        x = x.astype(jnp.float32) / 255.0 - 0.5 if img.dtype == jnp.uint8 \
            else x.astype(jnp.float32)
        for c, k, s in zip(self.cfg.channels, self.cfg.kernels, self.cfg.strides, strict=True):
            x = nn.relu(nn.Conv(c, (k, k), (s, s), padding="SAME")(x))
        x = x.reshape(x.shape[0], -1)
        if p is not None:
            x = jnp.concatenate([x, p], -1)
        x = nn.relu(nn.Dense(self.cfg.hidden)(x))
        mean = nn.Dense(2, kernel_init=nn.initializers.variance_scaling(
            0.01, "fan_in", "truncated_normal"))(x)
        value = nn.Dense(1)(x)[:, 0]
        if self.cfg.aux:  # both the offset and the heading error change sign in a mirror
            aux = nn.Dense(2, name="lane_error_head")(x)
            aux = 0.5 * (aux[:n] - aux[n:]) if self.cfg.symmetric else aux
            self.sow("intermediates", "lane_error", aux.reshape(batch + (2,)))
        if self.cfg.symmetric:  # the mirror's action mirrored back, averaged
            mean = 0.5 * (mean[:n] + mean[n:] * jnp.asarray(observe.ACTION_MIRROR))
            value = 0.5 * (value[:n] + value[n:])
        log_std = self.param("log_std", nn.initializers.constant(self.cfg.init_log_std), (2,))
        return mean.reshape(batch + (2,)), log_std, value.reshape(batch)


def init(net: PolicyNet, obs_example: dict[str, jax.Array], key: jax.Array) -> dict:
    """The network's variables for observations shaped like `obs_example` (one world)."""
    variables = net.init(key, jax.tree.map(lambda x: x[None], obs_example))
    return {k: v for k, v in variables.items() if k != "intermediates"}


def lane_error_prediction(net: PolicyNet, variables: Any, obs: dict[str, jax.Array]
                          ) -> tuple[tuple[jax.Array, jax.Array, jax.Array], jax.Array]:
    """(the network's outputs, its auxiliary head's lane error [..., 2] in units of
    `LANE_ERROR_SCALE`) on `obs`; the network needs `aux`."""
    out, state = net.apply(variables, obs, mutable=["intermediates"])
    return out, state["intermediates"]["lane_error"][0]


def log_prob(mean: jax.Array, log_std: jax.Array, action: jax.Array) -> jax.Array:
    """log N(action; mean, exp(log_std)²), summed over the 2 action dims: [...]."""
    z = (action - mean) * jnp.exp(-log_std)
    return jnp.sum(-0.5 * z * z - log_std - 0.5 * math.log(2 * math.pi), -1)


def entropy(log_std: jax.Array) -> jax.Array:
    """Entropy of the diagonal Gaussian [] (nats)."""
    return jnp.sum(log_std + 0.5 * math.log(2 * math.pi * math.e))
