"""Training wrappers, with Brax's conventions (`brax/envs/wrappers/training.py`):

    env = AutoResetWrapper(VmapWrapper(EpisodeWrapper(Env(run, cfg), episode_length),
                                       batch_size))

- `EpisodeWrapper` (one world): counts steps in `info["steps"]`, ends an episode after
  `episode_length` steps with `info["truncation"]` = 1 (also set at the environment's own
  timeout), repeats each action `action_repeat` times summing the rewards.
- `VmapWrapper`: the one place that vmaps `reset` and `step` over a batch of worlds.
- `AutoResetWrapper` (batched): where a step ended an episode, `data` and the new episode's
  info (`RESET_INFO`) come from a fresh `reset_world` — a NEW world, unlike Brax's, which
  returns to the first state — while `reward`, `done`, `metrics` and `truncation` stay those of
  the ending step; then every world is observed (`obs`: the new worlds' first frames). A
  reset costs a field and a plant table, so only the worlds that ended are reset, gathered
  `max_resets` at a time into one small vmapped reset (a loop of as many passes as needed: one
  when at most `max_resets` ended; the compiled step holds one reset). The frames are
  rendered once per step, after the resets, so the compiled step holds one renderer. Its
  three parts (`step_advance`, `step_reset`, `step_observe`) are also methods: a trainer
  compiles them as three programs, which XLA compiles side by side in half the time of one.
  `info["rng"]` holds each world's next key. `reset` and `step` take an optional
  `randomize.Pool` (traced): a share of every batch of resets takes fields from it (the
  adversarial curriculum's searched failures) instead of the uniform draw. `blank` makes a
  batch for a first `step` to replace whole, without a reset program of its own.

The environment provides `reset = observe ∘ reset_world` and `step = observe ∘ advance`; the
wrappers pass the parts through.
"""

from __future__ import annotations

from typing import Any

import jax
import jax.numpy as jnp

from mjxrow import runtime
from mjxrow.env.core import State
from mjxrow.env.randomize import Pool, pool_draws

RESET_INFO = ("steps",)  # info entries that belong to the new episode (observe sets the
# teacher's action)


class Wrapper:
    """Passes reset / step through; other attributes read through to the wrapped env."""

    def __init__(self, env: Any):
        self.env = env

    def reset(self, rng: jax.Array) -> State:
        return self.env.reset(rng)

    def step(self, state: State, action: jax.Array) -> State:
        return self.env.step(state, action)

    @property
    def unwrapped(self) -> Any:
        return getattr(self.env, "unwrapped", self.env)

    def __getattr__(self, name: str) -> Any:
        if name == "env":
            raise AttributeError(name)
        return getattr(self.env, name)


class EpisodeWrapper(Wrapper):
    """Episodes of at most `episode_length` control steps (None: the environment's own
    timeout only), each action applied `action_repeat` times."""

    def __init__(self, env: Any, episode_length: int | None = None, action_repeat: int = 1):
        super().__init__(env)
        if episode_length is not None and episode_length < 1:
            raise ValueError(f"episode_length: must be at least 1, got {episode_length}")
        if action_repeat < 1:
            raise ValueError(f"action_repeat: must be at least 1, got {action_repeat}")
        self.episode_length, self.action_repeat = episode_length, action_repeat

    def reset(self, rng: jax.Array, given: jax.Array | None = None) -> State:
        return self.observe(self.reset_world(rng, given))

    def reset_world(self, rng: jax.Array, given: jax.Array | None = None) -> State:
        # `given` only where a pool gives it (an environment without pools takes just rng)
        state = self.env.reset_world(rng) if given is None else self.env.reset_world(rng, given)
        return state.replace(info={**state.info, "steps": jnp.int32(0)})

    def observe(self, state: State) -> State:
        return self.env.observe(state)

    def step(self, state: State, action: jax.Array) -> State:
        return self.observe(self.advance(state, action))

    def advance(self, state: State, action: jax.Array) -> State:
        def once(s, _):
            s = self.env.advance(s, action)
            return s, s.reward

        state, rewards = jax.lax.scan(once, state, None, length=self.action_repeat)
        steps = state.info["steps"] + self.action_repeat
        trunc = state.info["truncation"]
        done = state.done
        if self.episode_length is not None:
            over = steps >= self.episode_length
            trunc = jnp.where(over & (done == 0), 1.0, trunc)
            done = jnp.where(over, 1.0, done)
        info = {**state.info, "steps": steps, "truncation": trunc}
        return state.replace(reward=jnp.sum(rewards, 0), done=done, info=info)


class VmapWrapper(Wrapper):
    """Batched reset / step (and their parts). `reset` takes one key (split into
    `batch_size`) or a [B] array of keys."""

    def __init__(self, env: Any, batch_size: int | None = None):
        super().__init__(env)
        self.batch_size = batch_size

    def _keys(self, rng: jax.Array) -> jax.Array:
        if rng.ndim == 0:
            if self.batch_size is None:
                raise ValueError("VmapWrapper.reset: one key needs a batch_size")
            rng = jax.random.split(rng, self.batch_size)
        return rng

    def reset(self, rng: jax.Array, given: jax.Array | None = None) -> State:
        return self._vmapped(self.env.reset, rng, given)

    def reset_world(self, rng: jax.Array, given: jax.Array | None = None) -> State:
        return self._vmapped(self.env.reset_world, rng, given)

    def _vmapped(self, fn, rng: jax.Array, given: jax.Array | None) -> State:
        """`fn` over the batch's keys, and over the rows of `given` [B, k] unless None."""
        keys = self._keys(rng)
        if given is None:
            return jax.vmap(fn)(keys)
        return jax.vmap(fn)(keys, given)

    def step(self, state: State, action: jax.Array) -> State:
        return jax.vmap(self.env.step)(state, action)

    def advance(self, state: State, action: jax.Array) -> State:
        return jax.vmap(self.env.advance)(state, action)

    def observe(self, state: State) -> State:
        return jax.vmap(self.env.observe)(state)


def _where(done: jax.Array, x: jax.Array, y: jax.Array) -> jax.Array:
    return jnp.where(done.reshape(done.shape + (1,) * (x.ndim - done.ndim)), x, y)


def _take_reset(state: State, fresh: State) -> State:
    """`state` with the world and the episode bookkeeping of `fresh` (same batch)."""
    info = {**state.info, **{k: fresh.info[k] for k in RESET_INFO if k in fresh.info}}
    return state.replace(data=fresh.data, info=info)


class AutoResetWrapper(Wrapper):
    """Resets the worlds whose episode ended, each to a new world (see the module doc). Wraps
    a batched environment of `batch_size` worlds with `reset_world`, `advance` and `observe`
    (the parts of reset and step); `max_resets` (None: the batch) worlds are reset per pass of
    the reset loop."""

    def __init__(self, env: Any, batch_size: int, max_resets: int | None = None):
        super().__init__(env)
        self.batch_size = batch_size
        self.max_resets = min(max_resets or batch_size, batch_size)

    def reset(self, rng: jax.Array, pool: Pool | None = None) -> State:
        keys = jax.random.split(rng, self.batch_size)
        given = None if pool is None else pool_draws(pool, keys, jnp.ones(len(keys), bool))
        state = self.env.reset(keys, given)
        nxt = jax.vmap(lambda k: jax.random.fold_in(k, 1))(keys)
        return state.replace(info={**state.info, "rng": nxt})

    def blank(self, rng: jax.Array) -> State:
        """A batch of worlds that the next `step` replaces, every one (pure; jit it): zeros of
        `reset`'s shapes, each world's episode clock at its time limit (`Env.expired`: the
        step ends every episode, then resets each world) and its key as `reset` gives it. A
        first rollout can start from it instead of `reset`'s worlds, so a trainer needs no
        reset program (its step holds one); the transition of that first step belongs to no
        episode (its observation is zeros, its reward, done and metrics the blank's): drop
        it."""
        keys = jax.random.split(rng, self.batch_size)
        shapes = jax.eval_shape(self.env.reset_world, keys)  # no frame: reset's own shapes

        def zeros(s):
            if runtime.is_key(s):
                data = jax.eval_shape(jax.random.key_data, s)
                return jax.random.wrap_key_data(jnp.zeros(data.shape, data.dtype),
                                                impl=jax.random.key_impl(rng))
            return jnp.zeros(s.shape, s.dtype)

        state = self.env.expired(jax.tree.map(zeros, shapes))
        nxt = jax.vmap(lambda k: jax.random.fold_in(k, 1))(keys)
        return state.replace(info={**state.info, "rng": nxt})

    def step(self, state: State, action: jax.Array, pool: Pool | None = None) -> State:
        """Advance every world, reset those whose episode ended, observe every world: the
        three parts `step_advance`, `step_reset` and `step_observe` in one (a trainer may
        compile them as three programs: smaller ones, which XLA compiles side by side)."""
        return self.step_observe(self.step_reset(self.step_advance(state, action), pool))

    def step_advance(self, state: State, action: jax.Array) -> State:
        """`step`'s first part: every world advanced (reward, done, metrics), no reset, no
        frame."""
        if "steps" in state.info:
            steps = jnp.where(state.done > 0, 0, state.info["steps"])
            state = state.replace(info={**state.info, "steps": steps})
        state = state.replace(done=jnp.zeros_like(state.done))
        return self.env.advance(state, action)

    @staticmethod
    def _split(state: State) -> tuple[jax.Array, jax.Array]:
        """Each world's (next key, reset key), from its key before the step's resets."""
        split = jax.vmap(jax.random.split)(state.info["rng"])
        return split[:, 0], split[:, 1]

    def step_reset(self, state: State, pool: Pool | None = None) -> State:
        """`step`'s second part, on `step_advance`'s worlds: each world whose episode ended
        replaced by a new one (its key and its draw from `pool`, if given), unobserved."""
        done = state.done > 0
        reset_keys = self._split(state)[1]
        B, K = self.batch_size, self.max_resets
        given = None if pool is None else pool_draws(pool, reset_keys, done)
        part = lambda s: (s.data, {k: s.info[k] for k in RESET_INFO  # noqa: E731
                                   if k in s.info})

        def reset_some(carry):
            state, left = carry
            idx = jnp.nonzero(left, size=K, fill_value=B)[0]  # the first K worlds left
            real = idx < B
            src = jnp.minimum(idx, B - 1)
            fresh = self.env.reset_world(reset_keys[src], None if given is None else given[src])
            # the unused slots point past the batch, each at its own index (dropped): the
            # indices are unique and sorted, so the scatter writes K rows in place, also under
            # XLA's deterministic ops (which turn a scatter of repeated indices into a loop)
            idx = jnp.where(real, idx, B + jnp.arange(K))
            put = lambda x, r: x.at[idx].set(r, mode="drop", unique_indices=True,  # noqa: E731
                                             indices_are_sorted=True)
            merged = jax.tree.map(put, part(state), part(_take_reset(state, fresh)))
            state = state.replace(data=merged[0], info={**state.info, **merged[1]})
            return state, put(left, jnp.zeros(K, bool))

        # K worlds per pass, as many passes as needed (one when at most K ended): the program
        # holds one reset of K worlds
        return jax.lax.while_loop(lambda c: jnp.any(c[1]), reset_some, (state, done))[0]

    def step_observe(self, state: State) -> State:
        """`step`'s last part, on `step_reset`'s worlds: every world's frame (the new worlds'
        included) and observation; the worlds that were reset take their next key."""
        done = state.done > 0
        nxt = self._split(state)[0]
        state = self.env.observe(state)
        info = {**state.info, "rng": jnp.where(done, nxt, state.info["rng"])}
        return state.replace(info=info)
