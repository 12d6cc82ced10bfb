"""The episode loop: control steps in chunks of CHUNK (a `lax.scan` each) inside a
`lax.while_loop` that stops after the chunk in which the last episode of a batch ended, for one
world or a batch; its state can also be advanced a few chunks at a time from the host
(`rollout.episode.staged`). Pure jnp; the step itself is the caller's (`rollout.episode`)."""

from __future__ import annotations

import functools

import jax
import jax.numpy as jnp

from mjxrow.rollout import metrics

CHUNK = 25  # control steps per scan between checks for the end of every episode of a batch


def steps_run(n_steps: int) -> int:
    """Control steps that a batch whose episodes all run `n_steps` steps computes: whole
    chunks of CHUNK (one chunk of n_steps below that), e.g. 75 for 60."""
    chunk = min(n_steps, CHUNK)
    return -(-n_steps // chunk) * chunk


FILL = dict(pose=jnp.nan, vel=jnp.nan, cmd=0, alive=False, event=metrics.RUNNING)


def loop_start(carry, n_steps: int, shapes: dict) -> tuple:
    """The chunk loop's state before its first chunk: (chunks done int32 [], carry, the
    output buffers [n_chunks·chunk, (B,) ...], filled as steps that did not run)."""
    lead = jnp.shape(carry[0].done)  # () or (B,)
    buf0 = {k: jnp.full((steps_run(n_steps),) + lead + v.shape, FILL[k], v.dtype)
            for k, v in shapes.items()}
    return jnp.int32(0), carry, buf0


def loop_run(body, state: tuple, n_steps: int, max_chunks: int | None = None) -> tuple:
    """Chunks of CHUNK steps (a scan each) from `state` (`loop_start`'s) in a while loop that
    ends after the chunk in which the last episode became done, after the last chunk, or
    after `max_chunks` chunks (None: no limit); returns the state after them."""
    chunk = min(n_steps, CHUNK)
    n_chunks = steps_run(n_steps) // chunk
    lead = jnp.shape(state[1][0].done)
    c_start = state[0]

    def more(st):
        c, carry, _ = st
        go = (c < n_chunks) & ~jnp.all(carry[0].done)
        return go if max_chunks is None else go & (c < c_start + max_chunks)

    def per_world(on, a, b):  # a where `on` [B] (broadcast over the trailing axes) else b
        return jnp.where(on.reshape(on.shape + (1,) * (a.ndim - on.ndim)), a, b)

    def run_chunk(st):
        c, carry, buf = st
        new, out = jax.lax.scan(body, carry, c * chunk + jnp.arange(chunk))
        if lead:  # the episodes done before this chunk keep their carry and record nothing
            on = ~carry[0].done
            new = jax.tree.map(functools.partial(per_world, on), new, carry)
            out = {k: per_world(on[None], v, jnp.full_like(v, FILL[k]))
                   for k, v in out.items()}
        buf = {k: jax.lax.dynamic_update_slice_in_dim(buf[k], out[k], c * chunk, 0) for k in buf}
        return c + 1, new, buf

    return jax.lax.while_loop(more, run_chunk, state)


def loop_outputs(buf: dict, n_steps: int, lead: tuple) -> dict:
    return {k: jnp.moveaxis(v[:n_steps], 0, len(lead)) for k, v in buf.items()}


def run_until_done(body, carry, n_steps: int, shapes: dict) -> dict:
    """`lax.scan(body, carry, arange(n_steps))[1]`, stopped early once the episode is done,
    for one world or a batch (`carry[0].done` [] or [B]; outputs [T, ...] or [B, T, ...]).

    Steps run in chunks of CHUNK (a scan each) inside a while loop that ends after the chunk
    in which the last episode became done, so a batch whose episodes all end early skips the
    rest of the timeout. An episode done before a chunk keeps its carry through the chunk and
    records nothing in it (what `vmap` of a one-world loop does). Steps that did not run read
    as steps after the end: pose and vel NaN, cmd 0, alive False, event RUNNING.
    shapes: one world's per-step outputs (`_out_shapes`)."""
    _, _, buf = loop_run(body, loop_start(carry, n_steps, shapes), n_steps)
    return loop_outputs(buf, n_steps, jnp.shape(carry[0].done))
