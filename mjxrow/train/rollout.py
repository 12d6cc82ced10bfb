"""Batched training rollouts shared by PPO, behaviour cloning and DAgger: the policy network in
one batched, auto-resetting environment for `length` control steps. Each crop has its own
static field shape, hence its own environment and rollout programs; the trainer runs one
rollout per crop, each in a thread of its own (`side_by_side`), and joins their outputs
(`join`).

A step is three programs (`Stepwise`, a host loop over them): `advance` (the network acts, the
worlds advance, the step's `Transition`), the environment's `step_reset` and `step_observe`.
Three smaller programs compile side by side in about half the time of one that holds them all
(docs/training.md, ninth round); the host's loop costs a few calls per step, against a step of
thousands of worlds. `unroll` is the same rollout as one program (a scan of the same parts):
the reference the tests compare `Stepwise` with.

Who acts: with probability `beta` per world and step the teacher's action
(`state.info["teacher_action"]`, BC and DAgger), otherwise the network's mean; Gaussian noise is
added to either, with std exp(log_std) (PPO's sampling) where `ppo` is true and `noise_std`
otherwise. Both are traced, so BC, DAgger and PPO share one compiled rollout.

Every step records a `Transition`; every episode that ends adds its navigation metrics and
return to `EpisodeStats` (sums and counts; the host divides).
"""

from __future__ import annotations

import dataclasses
from concurrent.futures import ThreadPoolExecutor
from typing import Any

import jax
import jax.numpy as jnp
import numpy as np
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
    lane_error: jax.Array | None = None  # float32 [2], the offset [m] and heading error [rad]
    # where obs was taken (the labels of an auxiliary head: `networks.NetConfig.aux`)


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


def advance(net: policies_networks.PolicyNet, env, params: Any, state, key: jax.Array,
            t: jax.Array, beta: jax.Array, noise_std: jax.Array, ppo: jax.Array, sums: dict,
            *, length: int):
    """Step `t` (traced) of a rollout of `length` steps from `key`: the network or the
    teacher acts on `state`'s observation and every world advances (`step_advance`: no
    reset, no frame). Returns (worlds, the step's Transition [B, ...], `sums` with the
    episodes that ended)."""
    mean, log_std, value = net.apply(params, state.obs)
    k_noise, k_mix = jax.random.split(jax.random.split(key, length)[t])
    teacher = state.info["teacher_action"]
    use_teacher = jax.random.uniform(k_mix, value.shape) < beta
    base = jnp.where(use_teacher[:, None], teacher, mean)
    scale = jnp.where(ppo, jnp.exp(log_std), noise_std)
    a = base + scale * jax.random.normal(k_noise, mean.shape)
    nxt = env.step_advance(state, a)
    tr = Transition(obs=state.obs, action=a, log_prob=policies_networks.log_prob(mean, log_std, a),
                    value=value, reward=nxt.reward, done=nxt.done,
                    truncation=nxt.info["truncation"], teacher=teacher,
                    lane_error=state.info.get("lane_error"))
    return nxt, tr, _stats(nxt, sums)


def value(net: policies_networks.PolicyNet, params: Any, obs: dict) -> jax.Array:
    """The network's value of every world's observation (a rollout's bootstrap) [B]."""
    return net.apply(params, obs)[2]


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
    `env.randomize.Pool` its resets draw a share from, or None) as one program. Returns (new
    state, Transition [length, B, ...], bootstrap values [B] of the final observations,
    episode stats {name: (sum, count)}). Pure: jit it with `env`, `net` and `length` static
    (closure). `Stepwise` runs the same steps as three programs each."""

    def body(carry, t):
        st, sums = carry
        nxt, tr, sums = advance(net, env, params, st, key, t, beta, noise_std, ppo, sums,
                                length=length)
        return (env.step_observe(env.step_reset(nxt, pool)), sums), tr

    (state, sums), traj = jax.lax.scan(body, (state, sums0(state)), jnp.arange(length))
    return state, traj, value(net, params, state.obs), sums


@dataclasses.dataclass(frozen=True)
class Stepwise:
    """One environment's rollout of `length` steps as a host loop over its compiled parts:
    `advance` (params, worlds, key, t, beta, noise_std, ppo, sums) → (worlds, Transition,
    sums), `reset` (worlds, pool) → worlds, `observe` (worlds) → worlds (`advance`, and the
    environment's `step_reset` and `step_observe`), and `value` (params, obs) → [B]. Called
    as `unroll` is (its arguments less `length`), it returns the same, but with the steps'
    transitions as a list (`join` stacks them); the calls are asynchronous."""

    advance: Any
    reset: Any
    observe: Any
    value: Any
    length: int

    def __call__(self, params, state, key, beta, noise_std, ppo, pool=None):
        sums = sums0(state)
        trs = []
        for t in range(self.length):
            state, tr, sums = self.advance(params, state, key, np.int32(t), beta, noise_std,
                                           ppo, sums)
            state = self.observe(self.reset(state, pool))
            trs.append(tr)
        return state, trs, self.value(params, state.obs), sums


def sums0(state) -> dict:
    """A rollout's episode stats before its first step: {name: (0, 0)} (host zeros)."""
    m = state.metrics
    names = [k for k in episode_keys() if k in m] + [k for k in m if k.startswith("reward/")]
    zero = np.zeros((), np.float32)
    return {k: (zero, zero) for k in (*names, "episodes")}


def advance_structure(state) -> Any:
    """The tree structure of `advance`'s result on worlds `state` (arrays or shapes), without
    tracing it: for a traced program kept as data (`runtime.exported`), whose results come
    back as leaves."""
    x = jnp.zeros(())
    tr = Transition(obs=state.obs, action=x, log_prob=x, value=x, reward=x, done=x,
                    truncation=x, teacher=x, lane_error=x if "lane_error" in state.info else None)
    return jax.tree.structure((state, tr, sums0(state)))


def summarise_stats(sums: dict) -> dict[str, float]:
    """Host means of `unroll`'s stats: episode metrics over the episodes that ended, reward
    terms over all steps, and `episodes` (how many ended)."""
    out = {}
    for k, (s, n) in sums.items():
        s, n = float(s), float(n)
        out[k] = s if k == "episodes" else (s / n if n > 0 else float("nan"))
    return out


def join(trs: list, boots: list, sums: list) -> tuple:
    """Several environments' rollouts as one (jit it): `Stepwise`'s per-step transitions of
    each ([[Transition [B_i, ...]] * T]) as one Transition [T, ΣB_i, ...], their bootstrap
    values [ΣB_i] and their episode stats summed. The worlds stay each environment's own."""
    steps = [jax.tree.map(lambda *x: jnp.concatenate(x), *at_t) for at_t in zip(*trs,
                                                                               strict=True)]
    return (jax.tree.map(lambda *x: jnp.stack(x), *steps), jnp.concatenate(boots),
            jax.tree.map(lambda *x: sum(x[1:], x[0]), *sums))


def side_by_side(rollouts: list, join_fn, params, worlds: tuple, key: jax.Array, beta,
                 noise_std, ppo, pools: list) -> tuple:
    """Every environment's rollout (`Stepwise`, or any function called as one; environment
    i's key folded in i), each in a thread of its own: a reset's loop waits for the device at
    each pass (its condition is read on the host), and meanwhile the other threads queue their
    steps. Returns (their worlds, then `join_fn`'s transitions [T, ΣB_i], bootstrap values and
    episode stats summed, then each environment's stats)."""
    keys = [jax.random.fold_in(key, i) for i in range(len(rollouts))]
    with ThreadPoolExecutor(len(rollouts), thread_name_prefix="rollout") as ex:
        outs = list(ex.map(lambda u, st, k, pool: u(params, st, k, beta, noise_std, ppo, pool),
                           rollouts, worlds, keys, pools))
    worlds, trs, boots, sums = (list(x) for x in zip(*outs, strict=True))
    return (tuple(worlds), *join_fn(trs, boots, sums), sums)


def per_preset_success(presets: tuple[str, ...], stats: list) -> dict[str, float]:
    """`success/<preset>`: the success rate of each preset's episodes that ended in the
    iteration (NaN where none did), where several presets train together."""
    if len(presets) < 2:
        return {}
    return {f"success/{p}": summarise_stats(st)["nav/success"]
            for p, st in zip(presets, stats, strict=True) if "nav/success" in st}
