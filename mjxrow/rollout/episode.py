"""Batched closed-loop episodes: the one place where the jitted batch of episodes is composed
for evaluation.

`episode(...)` runs ONE world for `cfg.n_steps` control steps in a `lax.scan` (pure, not
jitted); `episodes(...)` runs B of them with the same numbers (the loop over control steps
outside, the step vmapped inside: traced once); `rollout(...)` jits it over B fields and keys,
once per (policy, static config, policy-params axes): fields, lanes, keys, per-episode
start-pose noise and the policy's params (per episode or shared, `params_axes`) are traced
arrays, so new FieldParams, gains, noise or segmenter weights never retrace. `TRACES` counts
the traces. Perception policies (render → segment → SegZeros) come from `closed_loop`.

An episode starts at rest `sim_cfg.path_length` before the end of its lane (sim.reset), the goal
is the lane's end point (row end x, lane centre y). Each step: observation → policy → one
control period of physics → events. It ends at the first event, in this order of precedence:
sim_error (NaN or exploded state), flipped, collision (robot footprint touching a plant's
collision footprint, metrics.collides), goal (within `goal_radius`), missed_goal (past the
goal's line: x beyond the goal's x + `goal_radius`, beside the goal; the row has ended there,
so a robot that drives on along +x can no longer reach it), off_patch (the robot left the
simulated terrain), stuck (moved less than `stuck_dist` over `stuck_window` steps), timeout
(after `n_steps`). Once ended, the state stays frozen and the remaining steps are masked; a
batch stops stepping once every one of its episodes has ended (checked every `CHUNK` steps), so
the timeout costs only batches in which some episode runs that long.

The assembly of model, fields, policy and keys from a config is `rollout.build`; the CLI is
`python -m mjxrow.episode`.
"""

from __future__ import annotations

import dataclasses
import functools
import math
from typing import Any, ClassVar

import jax
import jax.numpy as jnp
import numpy as np

from mjxrow import control, crops
from mjxrow import field as F
from mjxrow.physics import sim
from mjxrow.rollout import metrics as M
from mjxrow.rollout.metrics import Log

TRACES = 0  # times the episode function was traced (each one is a compile)
CHUNK = 25  # control steps per scan between checks for the end of every episode of a batch
CMD_SHAPE = (2,)  # a policy's command: (v [m/s], omega [rad/s])


@dataclasses.dataclass(frozen=True)
class EpisodeConfig:
    """Episode settings (YAML section `episode`; hashable). `crop` picks the plants' collision
    footprint and `sim` holds the physics (control rate, path length, flip threshold); the YAML
    sets those through `preset` and the `sim` section. Everything is static except the
    start-pose noise (`TRACED`), which the rollout takes per episode."""

    crop: str
    max_time: float = 60.0  # s, timeout; an episode has ceil(max_time · sim.control_hz)
    # control steps
    goal_radius: float = 0.40  # m, goal reached within this distance
    stuck_window: int = 45  # control steps between stuck checks (3 s at 15 Hz)
    stuck_dist: float = 0.05  # m, moving less than this over a window is stuck
    collision_window: int = 4  # plants checked each side along a row (metrics.collides)
    end_off_patch: bool = True  # end an episode that leaves the terrain patch as off_patch
    end_missed_goal: bool = True  # end an episode that passes the goal's line as missed_goal
    start_offset_std: float = 0.0  # m, std of the start's lateral offset from the lane centre
    start_yaw_std: float = 0.0  # deg, std of the start heading about the row direction
    sim: sim.SimConfig = sim.SimConfig()

    TRACED: ClassVar[tuple[str, ...]] = ("start_offset_std", "start_yaw_std")

    def __post_init__(self):
        if self.crop not in crops.CROPS:
            raise ValueError(f"episode.crop: unknown crop {self.crop!r}; expected one of "
                             f"{crops.names()}")
        for name in ("stuck_window", "collision_window"):
            if int(getattr(self, name)) < 1:
                raise ValueError(f"episode.{name}: must be at least 1, got {getattr(self, name)}")
        for name in ("max_time", "goal_radius", "stuck_dist"):
            if not getattr(self, name) > 0:
                raise ValueError(f"episode.{name}: must be positive, got {getattr(self, name)}")
        for name in ("start_offset_std", "start_yaw_std"):
            v = getattr(self, name)
            if not (math.isfinite(v) and v >= 0):
                raise ValueError(f"episode.{name}: must be finite and non-negative, got {v}")

    @property
    def n_steps(self) -> int:
        """Control steps before the timeout: ceil(max_time · control_hz)."""
        return max(1, math.ceil(self.max_time * self.sim.control_hz - 1e-9))

    @property
    def control_dt(self) -> float:
        """s, one control period."""
        return 1.0 / self.sim.control_hz

    @property
    def path_length(self) -> float:
        """m, start → goal along the lane (sim.path_length)."""
        return self.sim.path_length

    @property
    def noise(self) -> sim.PoseNoise:
        """The start-pose noise (traced): lateral std [m], heading std [rad]."""
        return sim.pose_noise(self.start_offset_std, math.radians(self.start_yaw_std))

    def static(self) -> EpisodeConfig:
        """This config with the traced fields at their defaults: the compile key."""
        return dataclasses.replace(self, start_offset_std=0.0, start_yaw_std=0.0)


def end_reason(m, s_new: sim.SimState, bad: jax.Array, t: jax.Array, anchor: jax.Array,
               goal: jax.Array, field: F.Field, half: tuple[float, float],
               cfg: EpisodeConfig) -> jax.Array:
    """int32 [] `metrics.REASONS` code of the step that produced `s_new` (RUNNING if none), for
    the episode here and the training environment alike. m: the world's model; bad: the step
    failed (NaN, exploded, non-finite command); t: int32 [] index of the step; anchor [2]: the
    position at the last stuck check; goal [2]; half: the robot's half length and width [m].
    Precedence: sim_error > flipped > collision > goal > missed_goal > off_patch > stuck >
    timeout."""
    scfg = cfg.sim
    p = sim.pose(s_new)
    check = (t + 1) % cfg.stuck_window == 0
    events = [  # lowest precedence first: later entries win
        (t >= cfg.n_steps - 1, M.TIMEOUT),
        (check & (jnp.linalg.norm(p[:2] - anchor) < cfg.stuck_dist), M.STUCK),
        (sim.off_patch(m, s_new, scfg) if cfg.end_off_patch else False, M.OFF_PATCH),
        (p[0] > goal[0] + cfg.goal_radius if cfg.end_missed_goal else False, M.MISSED_GOAL),
        (jnp.linalg.norm(p[:2] - goal) <= cfg.goal_radius, M.GOAL),
        (M.collides(p, field, cfg.crop, half, cfg.collision_window), M.COLLISION),
        (sim.is_flipped(s_new, scfg), M.FLIPPED),
        (bad, M.SIM_ERROR),
    ]
    reason = jnp.int32(M.RUNNING)
    for happened, code in events:
        reason = jnp.where(happened, code, reason)
    return reason


def _select(c, a, b):
    """Per leaf: a where c else b."""
    return jax.tree.map(lambda x, y: jnp.where(c, x, y), a, b)


def _world(mx, field: F.Field, lane: jax.Array, key: jax.Array, noise: sim.PoseNoise,
           policy: control.Policy, policy_params: Any, cfg: EpisodeConfig):
    """One world's set-up: (context for every step, initial carry, start pose [3])."""
    scfg = cfg.sim
    m = sim.world_model(mx, field, lane, scfg)
    k_reset, k_policy = jax.random.split(key)
    s0 = sim.reset(m, field, lane, k_reset, scfg, noise)
    lane_y = field.lane_y[lane]
    goal = jnp.stack([field.row_x[1], lane_y])
    p0 = sim.pose(s0)
    init = getattr(policy, "init", None)
    ps0 = init(policy_params) if init is not None else None
    prepare = getattr(policy, "prepare", None)
    aux = prepare(policy_params, field) if prepare is not None else None  # once per episode
    rn = sim.robot_numbers(mx)
    half = (0.5 * rn["length"], 0.5 * rn["width"])
    ctx = dict(m=m, field=field, lane_y=lane_y, goal=goal, aux=aux, k_policy=k_policy, half=half)
    return ctx, (s0, ps0, jnp.zeros((), bool), p0[:2]), p0


def _step(ctx: dict, policy_params: Any, carry: tuple, t: jax.Array, policy: control.Policy,
          cfg: EpisodeConfig) -> tuple[tuple, dict]:
    """One world's control step t: observation → policy → physics → events."""
    scfg = cfg.sim
    m, field, goal, half = ctx["m"], ctx["field"], ctx["goal"], ctx["half"]
    s, ps, done, anchor = carry
    cam_pos, cam_rot = sim.camera_pose(s)
    obs = control.Obs(pose=sim.pose(s), lane_y=ctx["lane_y"], lane_end_x=goal[0], goal=goal,
                      cam_pos=cam_pos, cam_rot=cam_rot, field=field, aux=ctx["aux"])
    with jax.named_scope("cl_policy"):  # the scopes name the stages in profiles
        ps_new, cmd = policy(policy_params, ps, obs, jax.random.fold_in(ctx["k_policy"], t))
    cmd = jnp.asarray(cmd, jnp.float32)
    if cmd.shape != CMD_SHAPE:
        raise ValueError(f"policy: the command must be float [2] = (v [m/s], omega [rad/s]), "
                         f"got shape {cmd.shape}")
    with jax.named_scope("cl_physics"):
        s_new = sim.step(m, s, cmd, scfg)
    bad = sim.is_bad(s_new, scfg) | ~jnp.all(jnp.isfinite(cmd))
    p = sim.pose(s_new)
    check = (t + 1) % cfg.stuck_window == 0
    with jax.named_scope("cl_events"):
        reason = end_reason(m, s_new, bad, t, anchor, goal, field, half, cfg)
    event = jnp.where(done, M.RUNNING, reason).astype(jnp.int32)
    keep_old = done | bad
    s_next = _select(keep_old, s, s_new)
    ps_next = _select(done, ps, ps_new)
    anchor = jnp.where(check, p[:2], anchor)
    out = dict(pose=jnp.where(done, jnp.nan, p), cmd=cmd, alive=~done, event=event,
               vel=jnp.where(done | bad, jnp.nan, sim.velocity(s_new)))
    return (s_next, ps_next, done | (reason != M.RUNNING), anchor), out


def _log(out: dict, p0: jax.Array, goal: jax.Array, lane_y: jax.Array) -> Log:
    """One world's Log from its per-step outputs ([T] each)."""
    return Log(pose=out["pose"], cmd=out["cmd"], alive=out["alive"], event=out["event"],
               start=p0, goal=goal, lane_y=lane_y, reason=jnp.max(out["event"]),
               steps=jnp.sum(out["alive"]).astype(jnp.int32), vel=out["vel"])


def _out_shapes(s0: sim.SimState) -> dict:
    """Shapes of one world's per-step outputs (without tracing the step)."""
    one = lambda f: jax.eval_shape(f, s0)  # noqa: E731
    return dict(pose=one(sim.pose), cmd=jax.ShapeDtypeStruct(CMD_SHAPE, jnp.float32),
                alive=jax.ShapeDtypeStruct((), jnp.bool_),
                event=jax.ShapeDtypeStruct((), jnp.int32), vel=one(sim.velocity))


def episode(mx, field: F.Field, lane: jax.Array, key: jax.Array, noise: sim.PoseNoise,
            policy: control.Policy, policy_params: Any, cfg: EpisodeConfig) -> Log:
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
    out = _run_until_done(body, carry, cfg.n_steps, _out_shapes(carry[0]))
    return _log(out, p0, ctx["goal"], ctx["lane_y"])


def episodes(mx, fields: F.Field, lanes: jax.Array, keys: jax.Array, noise: sim.PoseNoise,
             policy: control.Policy, policy_params: Any, cfg: EpisodeConfig,
             params_axes: Any = None) -> Log:
    """A batch of episodes: `vmap(episode)` (the same numbers), written as a loop over the
    control steps of the whole batch with the step vmapped inside it, so that JAX traces the
    step once and never batches the loops afterwards (half the tracing time).
    fields, lanes, keys, noise: [B]; params_axes: as `compiled`. Returns the Log [B]."""
    global TRACES
    TRACES += 1
    p_axes = jax.tree.unflatten(*canonical_axes(params_axes))
    ctx_axes = dict(m=sim.model_axes(mx), field=0, lane_y=0, goal=0, aux=0, k_policy=0, half=0)
    ctx, carry, p0 = jax.vmap(
        lambda f, ln, k, nz, pp: _world(mx, f, ln, k, nz, policy, pp, cfg),
        in_axes=(0, 0, 0, 0, p_axes), out_axes=(ctx_axes, 0, 0))(
            fields, lanes, keys, noise, policy_params)
    step = jax.vmap(functools.partial(_step, policy=policy, cfg=cfg),
                    in_axes=(ctx_axes, p_axes, 0, None))
    body = functools.partial(step, ctx, policy_params)
    s0 = jax.tree.map(lambda x: x[0], carry[0])
    out = _run_until_done(body, carry, cfg.n_steps, _out_shapes(s0))
    return jax.vmap(_log)(out, p0, ctx["goal"], ctx["lane_y"])


def steps_run(n_steps: int) -> int:
    """Control steps that a batch whose episodes all run `n_steps` steps computes: whole
    chunks of CHUNK (one chunk of n_steps below that), e.g. 75 for 60."""
    chunk = min(n_steps, CHUNK)
    return -(-n_steps // chunk) * chunk


def _run_until_done(body, carry, n_steps: int, shapes: dict) -> dict:
    """`lax.scan(body, carry, arange(n_steps))[1]`, stopped early once the episode is done,
    for one world or a batch (`carry[2]` (done) [] or [B]; outputs [T, ...] or [B, T, ...]).

    Steps run in chunks of CHUNK (a scan each) inside a while loop that ends after the chunk
    in which the last episode became done, so a batch whose episodes all end early skips the
    rest of the timeout. An episode done before a chunk keeps its carry through the chunk and
    records nothing in it (what `vmap` of a one-world loop does). Steps that did not run read
    as steps after the end: pose and vel NaN, cmd 0, alive False, event RUNNING.
    shapes: one world's per-step outputs (`_out_shapes`)."""
    chunk = min(n_steps, CHUNK)
    n_chunks = steps_run(n_steps) // chunk
    lead = jnp.shape(carry[2])  # () or (B,)
    fill = dict(pose=jnp.nan, vel=jnp.nan, cmd=0, alive=False, event=M.RUNNING)
    buf0 = {k: jnp.full((n_chunks * chunk,) + lead + v.shape, fill[k], v.dtype)
            for k, v in shapes.items()}

    def more(state):
        c, (_, _, done, _), _ = state
        return (c < n_chunks) & ~jnp.all(done)

    def per_world(on, a, b):  # a where `on` [B] (broadcast over the trailing axes) else b
        return jnp.where(on.reshape(on.shape + (1,) * (a.ndim - on.ndim)), a, b)

    def run_chunk(state):
        c, carry, buf = state
        new, out = jax.lax.scan(body, carry, c * chunk + jnp.arange(chunk))
        if lead:  # the episodes done before this chunk keep their carry and record nothing
            on = ~carry[2]
            new = jax.tree.map(functools.partial(per_world, on), new, carry)
            out = {k: per_world(on[None], v, jnp.full_like(v, fill[k])) for k, v in out.items()}
        buf = {k: jax.lax.dynamic_update_slice_in_dim(buf[k], out[k], c * chunk, 0) for k in buf}
        return c + 1, new, buf

    _, _, buf = jax.lax.while_loop(more, run_chunk, (jnp.int32(0), carry, buf0))
    return {k: jnp.moveaxis(v[:n_steps], 0, len(lead)) for k, v in buf.items()}


def canonical_axes(params_axes: Any) -> tuple:
    """A hashable form of a vmap in_axes prefix pytree for policy params: (treedef, leaves),
    each leaf None (shared by the batch) or 0 (per episode). ValueError for other leaves."""
    leaves, treedef = jax.tree.flatten(params_axes, is_leaf=lambda x: x is None)
    for a in leaves:
        if a is not None and (isinstance(a, bool) or a != 0):
            raise ValueError(f"params_axes: leaves must be None (shared) or 0 (per episode), "
                             f"got {a!r} in {params_axes!r}")
    return treedef, tuple(leaves)


def compiled(policy, cfg: EpisodeConfig, params_axes: Any = None):
    """jit(episodes) for one policy, static config and policy-params axes: a function
    `(mx, fields [B], lanes [B], keys [B], noise [B], policy_params) -> Log [B]`. params_axes:
    vmap in_axes prefix of the policy params (None: all shared, 0: all per episode, or a
    pytree such as `((None, 0), 0)`). Cached, so equal (policy, cfg, axes) reuse one compiled
    function."""
    return _compiled(policy, cfg, canonical_axes(params_axes))


@functools.lru_cache(maxsize=64)
def _compiled(policy, cfg: EpisodeConfig, axes: tuple):
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
            lambda *xs: F.stack_leaves(xs), *parts))
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


def check_fields(fields: F.Field) -> int:
    """The batch size of `fields` (host); ValueError unless it is a batch of valid fields."""
    valid = np.asarray(fields.valid)
    if valid.ndim != 1:
        raise ValueError(f"fields: expected a batch (leading [B] axis), valid has shape "
                         f"{valid.shape}")
    if not valid.all():
        raise ValueError(f"fields: field {int(np.argmin(valid))} is not a valid field "
                         "(field.validate names the parameter)")
    return valid.shape[0]


def rollout_args(mx, fields: F.Field, lanes: jax.Array | None, keys: jax.Array,
                 policy_params: Any = None, params_axes: Any = None,
                 noise: sim.PoseNoise | None = None) -> tuple:
    """Checked arguments of the compiled function (host): (mx, fields, lanes, keys, noise [B],
    policy_params)."""
    B = check_fields(fields)
    if keys.shape[0] != B:
        raise ValueError(f"keys: {keys.shape[0]} keys for {B} fields")
    if lanes is None:
        lanes = jax.vmap(F.robot_lane)(fields)
    lanes = jnp.asarray(lanes, jnp.int32)
    if lanes.shape != (B,):
        raise ValueError(f"lanes: expected shape ({B},), got {lanes.shape}")
    noise = batch_noise(noise, B)
    check_params(policy_params, params_axes, B)
    return mx, fields, lanes, keys, noise, policy_params


def rollout(mx, fields: F.Field, lanes: jax.Array | None, keys: jax.Array, policy,
            policy_params: Any, ep_cfg: EpisodeConfig, params_axes: Any = None,
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


def summarise(log: Log, ep_cfg: EpisodeConfig) -> dict[str, jax.Array]:
    """metrics.summarise with this config's control period."""
    return M.summarise(log, ep_cfg.control_dt)
