"""Batched closed-loop episodes: the one place where the jitted batch of episodes is composed
for evaluation.

`episode(...)` runs ONE world for `cfg.n_steps` control steps in a `lax.scan` (pure, not
jitted); `episodes(...)` runs B of them with the same numbers (the loop over control steps
outside, the step vmapped inside: traced once); `rollout(...)` jits it over B fields and keys,
once per (policy, static config, policy-params axes): fields, lanes, keys, per-episode
start-pose noise and the policy's params (per episode or shared, `params_axes`) are traced
arrays, so new FieldParams, gains, noise or segmenter weights never retrace. `TRACES` counts
the traces. Perception policies (render → segment → SegZeros) come from
`mjxrow.policies.perception`.

An episode starts at rest `sim_cfg.path_length` before the end of its lane (sim.reset), the goal
is the lane's end point (row end x, lane centre y). Each step: observation → policy →
`rollout.step.step` (physics, end events, log row; its docstring lists the events and their
precedence). Once ended, the state stays frozen and the remaining steps are masked; a batch
stops stepping once every one of its episodes has ended (checked every `CHUNK` steps,
`rollout.loop`), so the timeout costs only batches in which some episode runs that long.
`staged(...)` cuts the same batch into three programs that the host advances a few chunks at a
time (a progress bar inside a long batch).

The assembly of model, fields, policy and keys from a config is `rollout.build`; the CLI is
`python -m mjxrow.episode`.
"""

from __future__ import annotations

import functools
from typing import Any, NamedTuple

import jax
import jax.numpy as jnp
import numpy as np

from mjxrow import control
from mjxrow import field as mjxrow_field
from mjxrow.field import lanes as field_lanes
from mjxrow.physics import sim
from mjxrow.rollout import metrics
from mjxrow.rollout import step as rollout_step
from mjxrow.rollout.loop import CHUNK, steps_run  # noqa: F401  (the episode loop's, re-exported)
from mjxrow.rollout.loop import loop_outputs as _loop_outputs
from mjxrow.rollout.loop import loop_run as _loop_run
from mjxrow.rollout.loop import loop_start as _loop_start
from mjxrow.rollout.loop import run_until_done as _run_until_done
from mjxrow.rollout.metrics import Log

TRACES = 0  # times the episode function was traced (each one is a compile)


def _world(mx, field: mjxrow_field.Field, lane: jax.Array, key: jax.Array, noise: sim.PoseNoise,
           policy: control.Policy, policy_params: Any, cfg: rollout_step.EpisodeConfig):
    """One world's set-up: (context for every step, initial carry (step carry, policy state),
    start pose [3])."""
    scfg = cfg.sim
    m = sim.world_model(mx, field, lane, scfg)
    k_reset, k_policy = jax.random.split(key)
    s0 = sim.reset(m, field, lane, k_reset, scfg, noise)
    lane_line = field_lanes.lane(field, lane)
    init = getattr(policy, "init", None)
    ps0 = init(policy_params) if init is not None else None
    prepare = getattr(policy, "prepare", None)
    aux = prepare(policy_params, field) if prepare is not None else None  # once per episode
    rn = sim.robot_numbers(mx)
    half = (0.5 * rn["length"], 0.5 * rn["width"])
    ctx = dict(m=m, field=field, lane=lane_line, aux=aux, k_policy=k_policy, half=half)
    return ctx, (rollout_step.start(s0), ps0), sim.pose(s0)


def _step(ctx: dict, policy_params: Any, carry: tuple, t: jax.Array, policy: control.Policy,
          cfg: rollout_step.EpisodeConfig) -> tuple[tuple, dict]:
    """One world's control step t: observation → policy → `rollout.step.step`."""
    c, ps = carry
    obs = rollout_step.observation(c.sim, ctx["field"], ctx["lane"], ctx["aux"])
    with jax.named_scope("cl_policy"):  # the scopes name the stages in profiles
        ps_new, cmd = policy(policy_params, ps, obs, jax.random.fold_in(ctx["k_policy"], t))
    c_new, row, _ = rollout_step.step(ctx["m"], ctx["field"], ctx["lane"], ctx["half"], c, cmd,
                                      t, cfg)
    ps_next = jax.tree.map(lambda x, y: jnp.where(c.done, x, y), ps, ps_new)
    return (c_new, ps_next), row._asdict()


def _log(out: dict, p0: jax.Array, lane: field_lanes.Lane) -> Log:
    """One world's Log from its per-step outputs ([T] each)."""
    return Log(pose=out["pose"], cmd=out["cmd"], alive=out["alive"], event=out["event"],
               start=p0, goal=field_lanes.goal(lane), lane=lane, reason=jnp.max(out["event"]),
               steps=jnp.sum(out["alive"]).astype(jnp.int32), vel=out["vel"])


def _out_shapes(s0: sim.SimState) -> dict:
    """Shapes of one world's per-step outputs (without tracing the step)."""
    one = lambda f: jax.eval_shape(f, s0)  # noqa: E731
    return dict(pose=one(sim.pose), cmd=jax.ShapeDtypeStruct(rollout_step.CMD_SHAPE, jnp.float32),
                alive=jax.ShapeDtypeStruct((), jnp.bool_),
                event=jax.ShapeDtypeStruct((), jnp.int32), vel=one(sim.velocity))


def episode(mx, field: mjxrow_field.Field, lane: jax.Array, key: jax.Array, noise: sim.PoseNoise,
            policy: control.Policy, policy_params: Any, cfg: rollout_step.EpisodeConfig) -> Log:
    """One world's episode (pure; not jitted; `compiled` runs a batch of them).

    mx: the shape's MJX model (sim.make_model); field: one Field; lane: int32 [] lane index;
    key: PRNG key (start-pose noise and the policy's per-step keys); noise: this episode's
    start-pose noise (sim.PoseNoise of scalars);
    policy: `control.Policy` (or any callable `(params, state, obs, key) -> (state, cmd)`,
    stateless: its state is None); cfg: static settings. Returns the Log ([T] per step)."""
    global TRACES
    TRACES += 1
    ctx, carry, p0 = _world(mx, field, lane, key, noise, policy, policy_params, cfg)
    body = functools.partial(_step, ctx, policy_params, policy=policy, cfg=cfg)
    out = _run_until_done(body, carry, cfg.n_steps, _out_shapes(carry[0].sim))
    return _log(out, p0, ctx["lane"])


def _axes(mx, params_axes) -> tuple:
    """vmap axes of a batch's policy params and of its per-world context."""
    p_axes = jax.tree.unflatten(*canonical_axes(params_axes))
    ctx_axes = dict(m=sim.model_axes(mx), field=0, lane=0, aux=0, k_policy=0, half=0)
    return p_axes, ctx_axes


def _start(mx, fields, lanes, keys, noise, policy, policy_params, cfg, params_axes):
    """A batch's set-up: (ctx, carry, start poses p0 [B, 3]) (`episodes`)."""
    p_axes, ctx_axes = _axes(mx, params_axes)
    return jax.vmap(
        lambda f, ln, k, nz, pp: _world(mx, f, ln, k, nz, policy, pp, cfg),
        in_axes=(0, 0, 0, 0, p_axes), out_axes=(ctx_axes, 0, 0))(
            fields, lanes, keys, noise, policy_params)


def _batch_body(mx, ctx, policy_params, policy, cfg, params_axes):
    """The vmapped control step of a batch, as `lax.scan`'s body over t."""
    p_axes, ctx_axes = _axes(mx, params_axes)
    step = jax.vmap(functools.partial(_step, policy=policy, cfg=cfg),
                    in_axes=(ctx_axes, p_axes, 0, None))
    return functools.partial(step, ctx, policy_params)


def episodes(
    mx,
    fields: mjxrow_field.Field,
    lanes: jax.Array,
    keys: jax.Array,
    noise: sim.PoseNoise,
    policy: control.Policy,
    policy_params: Any,
    cfg: rollout_step.EpisodeConfig,
    params_axes: Any = None,
) -> Log:
    """A batch of episodes: `vmap(episode)` (the same numbers), written as a loop over the
    control steps of the whole batch with the step vmapped inside it, so that JAX traces the
    step once and never batches the loops afterwards (half the tracing time).
    fields, lanes, keys, noise: [B]; params_axes: as `compiled`. Returns the Log [B]."""
    global TRACES
    TRACES += 1
    ctx, carry, p0 = _start(mx, fields, lanes, keys, noise, policy, policy_params, cfg,
                            params_axes)
    body = _batch_body(mx, ctx, policy_params, policy, cfg, params_axes)
    s0 = jax.tree.map(lambda x: x[0], carry[0].sim)
    out = _run_until_done(body, carry, cfg.n_steps, _out_shapes(s0))
    return jax.vmap(_log)(out, p0, ctx["lane"])


class Staged(NamedTuple):
    """`episodes` cut into three jitted programs, so that the host sees a batch advance:
    `start(mx, fields, lanes, keys, noise, params) -> state`, `advance(mx, state, params) ->
    state` (at most `chunks` chunks of `chunk` control steps) and `finish(state) -> Log`;
    `status(state)` reads the state on the host. The same step and loop as `compiled`'s one
    program, so the same numbers (tests/test_build.py)."""
    start: Any
    advance: Any
    finish: Any
    n_chunks: int
    chunk: int

    def status(self, state) -> tuple[int, int, bool]:
        """(control steps run, episodes ended, whether the batch is finished), in one
        transfer from the device."""
        c, done = jax.device_get((state[1][0], state[1][1][0].done))
        ended = int(np.sum(done))
        return int(c) * self.chunk, ended, int(c) >= self.n_chunks or ended == done.size


def staged(policy, cfg: rollout_step.EpisodeConfig, params_axes: Any = None,
           chunks: int = 4) -> Staged:
    """`compiled`'s batch as a `Staged` triple (cached like `compiled`)."""
    return _staged(policy, cfg, canonical_axes(params_axes), int(chunks))


@functools.lru_cache(maxsize=16)
def _staged(policy, cfg: rollout_step.EpisodeConfig, axes: tuple, chunks: int) -> Staged:
    params_axes = jax.tree.unflatten(*axes)

    def start(mx, fields, lanes, keys, noise, params):
        global TRACES
        TRACES += 1
        ctx, carry, p0 = _start(mx, fields, lanes, keys, noise, policy, params, cfg,
                                params_axes)
        s0 = jax.tree.map(lambda x: x[0], carry[0].sim)
        return ctx, _loop_start(carry, cfg.n_steps, _out_shapes(s0)), p0

    def advance(mx, state, params):
        ctx, loop, p0 = state
        body = _batch_body(mx, ctx, params, policy, cfg, params_axes)
        return ctx, _loop_run(body, loop, cfg.n_steps, chunks), p0

    def finish(state):
        ctx, (_, carry, buf), p0 = state
        out = _loop_outputs(buf, cfg.n_steps, jnp.shape(carry[0].done))
        return jax.vmap(_log)(out, p0, ctx["lane"])

    chunk = min(cfg.n_steps, CHUNK)
    return Staged(jax.jit(start), jax.jit(advance), jax.jit(finish),
                  steps_run(cfg.n_steps) // chunk, chunk)


def canonical_axes(params_axes: Any) -> tuple:
    """A hashable form of a vmap in_axes prefix pytree for policy params: (treedef, leaves),
    each leaf None (shared by the batch) or 0 (per episode). ValueError for other leaves."""
    leaves, treedef = jax.tree.flatten(params_axes, is_leaf=lambda x: x is None)
    for a in leaves:
        if a is not None and (isinstance(a, bool) or a != 0):
            raise ValueError(f"params_axes: leaves must be None (shared) or 0 (per episode), "
                             f"got {a!r} in {params_axes!r}")
    return treedef, tuple(leaves)


def compiled(policy, cfg: rollout_step.EpisodeConfig, params_axes: Any = None):
    """jit(episodes) for one policy, static config and policy-params axes: a function
    `(mx, fields [B], lanes [B], keys [B], noise [B], policy_params) -> Log [B]`. params_axes:
    vmap in_axes prefix of the policy params (None: all shared, 0: all per episode, or a
    pytree such as `((None, 0), 0)`). Cached, so equal (policy, cfg, axes) reuse one compiled
    function."""
    return _compiled(policy, cfg, canonical_axes(params_axes))


@functools.lru_cache(maxsize=64)
def _compiled(policy, cfg: rollout_step.EpisodeConfig, axes: tuple):
    treedef, leaves = axes

    def batch(mx, fields, lanes, keys, noise, params):
        return episodes(mx, fields, lanes, keys, noise, policy, params, cfg,
                        jax.tree.unflatten(treedef, leaves))

    return jax.jit(batch)


def check_params(policy_params: Any, params_axes: Any, batch: int) -> None:
    """ValueError unless `params_axes` is a prefix of the policy params' structure and every
    per-episode leaf has a leading [batch] axis; the message names the leaf's path."""
    treedef, leaves = canonical_axes(params_axes)
    axes_tree = jax.tree.unflatten(treedef, leaves)
    paths = [p for p, _ in jax.tree_util.tree_flatten_with_path(
        axes_tree, is_leaf=lambda x: x is None)[0]]
    try:
        parts = treedef.flatten_up_to(policy_params)
    except (ValueError, TypeError) as e:
        raise ValueError(f"params_axes: {axes_tree!r} is not a prefix of the policy params' "
                         f"structure ({e})") from None
    for prefix, axis, part in zip(paths, leaves, parts, strict=True):
        for path, x in jax.tree_util.tree_leaves_with_path(part) if axis is not None else ():
            shape = np.shape(x)
            if not shape or shape[0] != batch:
                raise ValueError(f"policy_params{jax.tree_util.keystr(tuple(prefix) + path)}: "
                                 f"per-episode (axis 0) but has shape {shape}, expected a "
                                 f"leading [{batch}]")


def stack_params(trees: list, params_axes: Any = 0) -> Any:
    """Batch per-episode policy params: leaves under a 0 axis are stacked into [B, ...]; parts
    under a None axis (shared, e.g. segmenter weights) are taken from the first tree."""
    treedef, leaves = canonical_axes(params_axes)
    cut = [treedef.flatten_up_to(t) for t in trees]
    out = []
    for i, axis in enumerate(leaves):
        parts = [c[i] for c in cut]
        out.append(parts[0] if axis is None else jax.tree.map(
            lambda *xs: mjxrow_field.stack_leaves(xs), *parts))
    return treedef.unflatten(out)


def batch_noise(noise: sim.PoseNoise | None, batch: int) -> sim.PoseNoise:
    """Start-pose noise of every episode: float32 [batch] stds (host arrays), from scalars
    (the same for all), [batch] arrays or None (no noise). ValueError for negative or
    non-finite stds."""
    noise = noise if noise is not None else sim.pose_noise()
    out = {}
    for name in ("lateral_std", "heading_std"):
        x = np.asarray(getattr(noise, name), np.float32)
        if x.ndim > 1 or (x.ndim == 1 and x.shape[0] != batch):
            raise ValueError(f"noise.{name}: expected a scalar or shape ({batch},), got "
                             f"{x.shape}")
        if not np.all(np.isfinite(x) & (x >= 0)):
            raise ValueError(f"noise.{name}: must be finite and non-negative, got {x}")
        out[name] = np.broadcast_to(x, (batch,)).copy()
    return sim.PoseNoise(**out)


def check_fields(fields: mjxrow_field.Field) -> int:
    """The batch size of `fields` (host); ValueError unless it is a batch of valid fields."""
    valid = np.asarray(fields.valid)
    if valid.ndim != 1:
        raise ValueError(f"fields: expected a batch (leading [B] axis), valid has shape "
                         f"{valid.shape}")
    if not valid.all():
        raise ValueError(f"fields: field {int(np.argmin(valid))} is not a valid field "
                         "(field.validate names the parameter)")
    return valid.shape[0]


def rollout_args(mx, fields: mjxrow_field.Field, lanes: jax.Array | None, keys: jax.Array,
                 policy_params: Any = None, params_axes: Any = None,
                 noise: sim.PoseNoise | None = None) -> tuple:
    """Checked arguments of the compiled function (host): (mx, fields, lanes, keys, noise [B],
    policy_params)."""
    B = check_fields(fields)
    if keys.shape[0] != B:
        raise ValueError(f"keys: {keys.shape[0]} keys for {B} fields")
    if lanes is None:
        lanes = jax.vmap(mjxrow_field.robot_lane)(fields)
    lanes = jnp.asarray(lanes, jnp.int32)
    if lanes.shape != (B,):
        raise ValueError(f"lanes: expected shape ({B},), got {lanes.shape}")
    noise = batch_noise(noise, B)
    check_params(policy_params, params_axes, B)
    return mx, fields, lanes, keys, noise, policy_params


def rollout(mx, fields: mjxrow_field.Field, lanes: jax.Array | None, keys: jax.Array, policy,
            policy_params: Any, ep_cfg: rollout_step.EpisodeConfig, params_axes: Any = None,
            noise: sim.PoseNoise | None = None) -> Log:
    """B episodes in one compiled call (`compiled`).

    mx: MJX model of the fields' static shape (sim.make_model); fields: Field with a leading
    [B] axis (all valid); lanes: int32 [B] lane per field, or None for each field's
    `field.robot_lane`; keys: PRNG keys [B]; policy: a `control.Policy` (e.g.
    `control.as_policy("oracle")`, `closed_loop.perception_policy(...)`), hashable: the same
    object reuses the compiled function; policy_params: its params; params_axes: which of them
    are per episode (a vmap in_axes prefix pytree): None (default) shares them all, 0 gives
    every leaf a leading [B] axis, and a pytree mixes the two, e.g. `((None, 0), 0)` for
    `((segmenter weights, conditions), controller gains)`: weights shared, the rest per
    episode. New values of any of them never recompile; other axes do. noise: start-pose
    noise (sim.PoseNoise: lateral std [m], heading std [rad]), scalars for all episodes or
    [B] arrays, one per episode (traced: any values, one compile); None: start on the lane
    centre line, heading +x. Returns a Log with a leading [B] axis."""
    args = rollout_args(mx, fields, lanes, keys, policy_params, params_axes, noise)
    return compiled(policy, ep_cfg, params_axes)(*args)


def summarise(log: Log, ep_cfg: rollout_step.EpisodeConfig) -> dict[str, jax.Array]:
    """metrics.summarise with this config's control period."""
    return metrics.summarise(log, ep_cfg.control_dt)
