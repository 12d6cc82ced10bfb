"""Batched training rollouts shared by PPO, behaviour cloning and DAgger: `unroll` runs the
policy network in one batched, auto-resetting environment for `length` control steps. Each crop
has its own static field shape, hence its own environment and compiled rollout; the trainer
runs one per crop and joins their outputs (`join`).

Who acts: with probability `beta` per world and step the teacher's action
(`state.info["teacher_action"]`, BC and DAgger), otherwise the network's mean; Gaussian noise is
added to either, with std exp(log_std) (PPO's sampling) where `ppo` is true and `noise_std`
otherwise. Both are traced, so BC, DAgger and PPO share one compiled rollout.

Every step records a `Transition`; every episode that ends adds its navigation metrics and
return to `EpisodeStats` (sums and counts; the host divides).
"""

from __future__ import annotations

from typing import Any

import jax
import jax.numpy as jnp
from flax import struct

from mjxrow.policies import networks as policies_networks
from mjxrow.rollout import metrics as rollout_metrics


def episode_keys() -> tuple[str, ...]:
    """The metrics averaged over the episodes that end: the return and `nav/<name>` of every
    registered metric with Metric.train, in the registry's order."""
    return ("return", *(f"nav/{m.name}" for m in rollout_metrics.METRICS.values() if m.train))


@struct.dataclass
class Transition:
    """One step of B worlds ([T, B, ...] after `unroll`)."""

    obs: dict  # the observation the action was taken on
    action: jax.Array  # float32 [2], as taken (before the environment's clip)
    log_prob: jax.Array  # float32 [], of the action under the network's Gaussian
    value: jax.Array  # float32 [], the network's value of obs
    reward: jax.Array  # float32 []
    done: jax.Array  # float32 [], the step ended the episode
    truncation: jax.Array  # float32 [], ... by a time limit (bootstrap through it)
    teacher: jax.Array  # float32 [2], the teacher's action on obs (labels of BC / DAgger)


def _stats(state, sums: dict) -> dict:
    done = state.done > 0
    out = dict(sums)
    for k in episode_keys():
        if k not in state.metrics:
            continue
        x = state.metrics[k]
        ok = done & jnp.isfinite(x)
        s, n = out[k]
        out[k] = (s + jnp.sum(jnp.where(ok, x, 0.0)), n + jnp.sum(ok))
    for k, x in state.metrics.items():
        if k.startswith("reward/"):
            s, n = out[k]
            out[k] = (s + jnp.sum(x), n + x.size)
    s, n = out["episodes"]
    out["episodes"] = (s + jnp.sum(done), n + done.size)
    return out


def unroll(
    net: policies_networks.PolicyNet,
    env,
    params: Any,
    state,
    key: jax.Array,
    beta: jax.Array,
    noise_std: jax.Array,
    ppo: jax.Array,
    pool=None,
    *,
    length: int,
):
    """Run `length` steps in `env` (batched, auto-resetting; `state` its state; `pool` an
    `env.randomize.Pool` its resets draw a share from, or None). Returns (new state, Transition
    [length, B, ...], bootstrap values [B] of the final observations, episode stats {name:
    (sum, count)}). Pure: jit it with `env`, `net` and `length` static (closure)."""

    def act(st, k):
        mean, log_std, value = net.apply(params, st.obs)
        k_noise, k_mix = jax.random.split(k)
        teacher = st.info["teacher_action"]
        use_teacher = jax.random.uniform(k_mix, value.shape) < beta
        base = jnp.where(use_teacher[:, None], teacher, mean)
        scale = jnp.where(ppo, jnp.exp(log_std), noise_std)
        a = base + scale * jax.random.normal(k_noise, mean.shape)
        return a, policies_networks.log_prob(mean, log_std, a), value, teacher

    def body(carry, k):
        st, sums = carry
        a, logp, value, teacher = act(st, k)
        nxt = env.step(st, a, pool)
        tr = Transition(obs=st.obs, action=a, log_prob=logp, value=value, reward=nxt.reward,
                        done=nxt.done, truncation=nxt.info["truncation"], teacher=teacher)
        return (nxt, _stats(nxt, sums)), tr

    (state, sums), traj = jax.lax.scan(body, (state, _sums0(state)),
                                       jax.random.split(key, length))
    return state, traj, net.apply(params, state.obs)[2], sums


def _sums0(state) -> dict:
    """`unroll`'s episode stats before its first step: {name: (0, 0)}."""
    m = state.metrics
    names = [k for k in episode_keys() if k in m] + [k for k in m if k.startswith("reward/")]
    zero = jnp.zeros((), jnp.float32)
    return {k: (zero, zero) for k in (*names, "episodes")}


def out_structure(state) -> Any:
    """The tree structure of `unroll`'s result on worlds `state` (arrays or shapes), without
    tracing it: for a traced program kept as data (`runtime.exported`), whose results come
    back as leaves."""
    x = jnp.zeros(())
    tr = Transition(obs=state.obs, action=x, log_prob=x, value=x, reward=x, done=x,
                    truncation=x, teacher=x)
    return jax.tree.structure((state, tr, x, _sums0(state)))


def summarise_stats(sums: dict) -> dict[str, float]:
    """Host means of `unroll`'s stats: episode metrics over the episodes that ended, reward
    terms over all steps, and `episodes` (how many ended)."""
    out = {}
    for k, (s, n) in sums.items():
        s, n = float(s), float(n)
        out[k] = s if k == "episodes" else (s / n if n > 0 else float("nan"))
    return out


def join(outs: list) -> tuple:
    """`unroll`'s outputs of several environments as one: (their states as a tuple,
    Transition [T, ΣB_i, ...], bootstrap values [ΣB_i], episode stats summed)."""
    cat = lambda axis: lambda *x: jnp.concatenate(x, axis)  # noqa: E731
    return (tuple(o[0] for o in outs), jax.tree.map(cat(1), *[o[1] for o in outs]),
            jnp.concatenate([o[2] for o in outs]),
            jax.tree.map(lambda *x: sum(x[1:], x[0]), *[o[3] for o in outs]))


def per_preset_success(presets: tuple[str, ...], stats: list) -> dict[str, float]:
    """`success/<preset>`: the success rate of each preset's episodes that ended in the
    iteration (NaN where none did), where several presets train together."""
    if len(presets) < 2:
        return {}
    return {f"success/{p}": summarise_stats(st)["nav/success"]
            for p, st in zip(presets, stats, strict=True) if "nav/success" in st}
