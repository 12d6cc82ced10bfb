"""Batched closed-loop episodes: the one place where jit(vmap(scan)) is composed for evaluation.

`episode(...)` runs ONE world for `cfg.n_steps` control steps in a `lax.scan` (pure, not
jitted); `rollout(...)` vmaps it over B fields and keys and jits it, once per (policy, static
config, policy-params axes): fields, lanes, keys, per-episode start-pose noise and the policy's
params (per episode or shared, `params_axes`) are traced arrays, so new FieldParams, gains,
noise or segmenter weights never retrace. `TRACES` counts the traces. Perception policies
(render → segment → SegZeros) come from `closed_loop`.

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

CLI: `python -m mjxrow.episode --preset vineyard --controller oracle --n 8 --seed 0 --out DIR
[--set key=value ...]` (see `main`).
"""

from __future__ import annotations

import argparse
import contextlib
import dataclasses
import functools
import math
import sys
import threading
import time
from pathlib import Path
from typing import Any

import jax
import jax.numpy as jnp
import numpy as np
import pandas as pd
from tqdm.auto import tqdm

from mjxrow import control
from mjxrow import field as F
from mjxrow.control import perception as closed_loop
from mjxrow.overrides import parse_sets
from mjxrow.physics import sim
from mjxrow.rollout import metrics as M
from mjxrow.rollout.metrics import Log

TRACES = 0  # times the episode function was traced (each one is a compile)
CHUNK = 25  # control steps per scan between checks for the end of every episode of a batch


@dataclasses.dataclass(frozen=True)
class EpisodeConfig:
    """Static episode settings (hashable). `crop` picks the plants' collision footprint.

    The path length (`sim.path_length`, 20 m), the control rate (`sim.control_hz`, 15 Hz) and
    the flip threshold (`sim.max_tilt_deg`) live in the simulation config `sim`."""

    crop: str
    n_steps: int = 600  # control steps before timeout (600 at 15 Hz = 40 s)
    goal_radius: float = 0.40  # m, goal reached within this distance
    stuck_window: int = 45  # control steps between stuck checks (3 s at 15 Hz)
    stuck_dist: float = 0.05  # m, moving less than this over a window is stuck
    collision_window: int = 4  # plants checked each side along a row (metrics.collides)
    end_off_patch: bool = True  # end an episode that leaves the terrain patch as off_patch
    end_missed_goal: bool = True  # end an episode that passes the goal's line as missed_goal
    sim: sim.SimConfig = sim.SimConfig()

    def __post_init__(self):
        if self.crop not in F.CROPS:
            raise ValueError(f"crop: unknown crop {self.crop!r}; expected one of {F.CROPS}")
        for name in ("n_steps", "stuck_window", "collision_window"):
            if int(getattr(self, name)) < 1:
                raise ValueError(f"{name}: must be at least 1, got {getattr(self, name)}")
        for name in ("goal_radius", "stuck_dist"):
            if not getattr(self, name) > 0:
                raise ValueError(f"{name}: must be positive, got {getattr(self, name)}")

    @property
    def control_dt(self) -> float:
        """s, one control period."""
        return 1.0 / self.sim.control_hz

    @property
    def path_length(self) -> float:
        """m, start → goal along the lane (sim.path_length)."""
        return self.sim.path_length


def _select(c, a, b):
    """Per leaf: a where c else b."""
    return jax.tree.map(lambda x, y: jnp.where(c, x, y), a, b)


def episode(mx, field: F.Field, lane: jax.Array, key: jax.Array, noise: sim.PoseNoise,
            policy: control.Policy, policy_params: Any, cfg: EpisodeConfig) -> Log:
    """One world's episode (pure; not jitted: `rollout` composes jit and vmap).

    mx: the shape's MJX model (sim.make_model); field: one Field; lane: int32 [] lane index;
    key: PRNG key (start-pose noise and the policy's per-step keys); noise: this episode's
    start-pose noise (sim.PoseNoise of scalars);
    policy: `control.Policy` (or any callable `(params, state, obs, key) -> (state, cmd)`,
    stateless: its state is None); cfg: static settings. Returns the Log ([T] per step)."""
    global TRACES
    TRACES += 1
    scfg = cfg.sim
    rn = sim.robot_numbers(mx)
    half = (0.5 * rn["length"], 0.5 * rn["width"])
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

    def body(carry, t):
        s, ps, done, anchor = carry
        cam_pos, cam_rot = sim.camera_pose(s)
        obs = control.Obs(pose=sim.pose(s), lane_y=lane_y, lane_end_x=goal[0], goal=goal,
                          cam_pos=cam_pos, cam_rot=cam_rot, field=field, aux=aux)
        ps_new, cmd = policy(policy_params, ps, obs, jax.random.fold_in(k_policy, t))
        cmd = jnp.asarray(cmd, jnp.float32)
        s_new = sim.step(m, s, cmd, scfg)
        bad = sim.is_bad(s_new, scfg) | ~jnp.all(jnp.isfinite(cmd))
        p = sim.pose(s_new)
        check = (t + 1) % cfg.stuck_window == 0
        events = [  # lowest precedence first: later entries win
            (t == cfg.n_steps - 1, M.TIMEOUT),
            (check & (jnp.linalg.norm(p[:2] - anchor) < cfg.stuck_dist), M.STUCK),
            (sim.off_patch(m, s_new, scfg) if cfg.end_off_patch else False, M.OFF_PATCH),
            (p[0] > goal[0] + cfg.goal_radius if cfg.end_missed_goal else False,
             M.MISSED_GOAL),
            (jnp.linalg.norm(p[:2] - goal) <= cfg.goal_radius, M.GOAL),
            (M.collides(p, field, cfg.crop, half, cfg.collision_window), M.COLLISION),
            (sim.is_flipped(s_new, scfg), M.FLIPPED),
            (bad, M.SIM_ERROR),
        ]
        reason = jnp.int32(M.RUNNING)
        for happened, code in events:
            reason = jnp.where(happened, code, reason)
        event = jnp.where(done, M.RUNNING, reason).astype(jnp.int32)
        keep_old = done | bad
        s_next = _select(keep_old, s, s_new)
        ps_next = _select(done, ps, ps_new)
        anchor = jnp.where(check, p[:2], anchor)
        out = dict(pose=jnp.where(done, jnp.nan, p), cmd=cmd, alive=~done, event=event,
                   vel=jnp.where(done | bad, jnp.nan, sim.velocity(s_new)))
        return (s_next, ps_next, done | (reason != M.RUNNING), anchor), out

    carry = (s0, ps0, jnp.zeros((), bool), p0[:2])
    out = _run_until_done(body, carry, cfg.n_steps)
    return Log(pose=out["pose"], cmd=out["cmd"], alive=out["alive"], event=out["event"],
               start=p0, goal=goal, lane_y=lane_y, reason=jnp.max(out["event"]),
               steps=jnp.sum(out["alive"]).astype(jnp.int32), vel=out["vel"])


def _run_until_done(body, carry, n_steps: int) -> dict:
    """`lax.scan(body, carry, arange(n_steps))[1]`, stopped early once the episode is done.

    Steps run in chunks of CHUNK (a scan each) inside a while loop that ends after the chunk in
    which `carry[2]` (done) became True; under vmap it ends when every episode of the batch is
    done, so a batch whose episodes all end early skips the rest of the timeout. Steps that did
    not run read as steps after the end: pose and vel NaN, cmd 0, alive False, event RUNNING."""
    chunk = min(n_steps, CHUNK)
    n_chunks = -(-n_steps // chunk)
    shapes = jax.eval_shape(body, carry, jnp.int32(0))[1]
    fill = dict(pose=jnp.nan, vel=jnp.nan, cmd=0, alive=False, event=M.RUNNING)
    buf0 = {k: jnp.full((n_chunks * chunk,) + v.shape, fill[k], v.dtype)
            for k, v in shapes.items()}

    def more(state):
        c, (_, _, done, _), _ = state
        return (c < n_chunks) & ~done

    def run_chunk(state):
        c, carry, buf = state
        carry, out = jax.lax.scan(body, carry, c * chunk + jnp.arange(chunk))
        buf = {k: jax.lax.dynamic_update_slice_in_dim(buf[k], out[k], c * chunk, 0) for k in buf}
        return c + 1, carry, buf

    _, _, buf = jax.lax.while_loop(more, run_chunk, (jnp.int32(0), carry, buf0))
    return {k: v[:n_steps] for k, v in buf.items()}


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
    """jit(vmap(episode)) for one policy, static config and policy-params axes: a function
    `(mx, fields [B], lanes [B], keys [B], noise [B], policy_params) -> Log [B]`. params_axes:
    vmap in_axes prefix of the policy params (None: all shared, 0: all per episode, or a
    pytree such as `((None, 0), 0)`). Cached, so equal (policy, cfg, axes) reuse one compiled
    function."""
    return _compiled(policy, cfg, canonical_axes(params_axes))


@functools.lru_cache(maxsize=64)
def _compiled(policy, cfg: EpisodeConfig, axes: tuple):
    treedef, leaves = axes

    def one(mx, field, lane, key, noise, params):
        return episode(mx, field, lane, key, noise, policy, params, cfg)

    in_axes = (None, 0, 0, 0, 0, jax.tree.unflatten(treedef, leaves))
    return jax.jit(jax.vmap(one, in_axes=in_axes))


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
            lambda *xs: jnp.stack([jnp.asarray(x) for x in xs]), *parts))
    return treedef.unflatten(out)


def batch_noise(noise: sim.PoseNoise | None, batch: int) -> sim.PoseNoise:
    """Start-pose noise of every episode: float32 [batch] stds, from scalars (the same for
    all), [batch] arrays or None (no noise). ValueError for negative or non-finite stds."""
    noise = noise if noise is not None else sim.pose_noise()
    out = {}
    for name in ("lateral_std", "heading_std"):
        x = jnp.asarray(getattr(noise, name), jnp.float32)
        if x.ndim > 1 or (x.ndim == 1 and x.shape[0] != batch):
            raise ValueError(f"noise.{name}: expected a scalar or shape ({batch},), got "
                             f"{x.shape}")
        if not np.all(np.isfinite(np.asarray(x)) & (np.asarray(x) >= 0)):
            raise ValueError(f"noise.{name}: must be finite and non-negative, got {x}")
        out[name] = jnp.broadcast_to(x, (batch,))
    return sim.PoseNoise(**out)


def rollout_args(mx, fields: F.Field, lanes: jax.Array | None, keys: jax.Array,
                 policy_params: Any = None, params_axes: Any = None,
                 noise: sim.PoseNoise | None = None) -> tuple:
    """Checked arguments of the compiled function (host): (mx, fields, lanes, keys, noise [B],
    policy_params)."""
    valid = np.asarray(fields.valid)
    if valid.ndim != 1:
        raise ValueError(f"fields: expected a batch (leading [B] axis), valid has shape "
                         f"{valid.shape}")
    if not valid.all():
        raise ValueError(f"fields: field {int(np.argmin(valid))} is not a valid field "
                         "(field.validate names the parameter)")
    B = valid.shape[0]
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
    """B episodes in one compiled call: jit(vmap(scan)).

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


# ---------------------------------------------------------------------------------------------
# CLI

CSV_METRICS = ("success", "collision", "reason", "cha", "mae", "mse", "omega_std", "v_mean",
               "time", "path_ratio", "max_offset")


@contextlib.contextmanager
def _ticker(desc: str, enabled: bool = True):
    """Progress while a blocking call runs: on a terminal a line with the elapsed time,
    refreshed every second; otherwise one line at the start and one at the end."""
    if not enabled:
        yield
        return
    t0 = time.perf_counter()
    if not sys.stderr.isatty():
        print(f"{desc} ...", file=sys.stderr, flush=True)
        yield
        print(f"{desc}: done in {time.perf_counter() - t0:.1f} s", file=sys.stderr, flush=True)
        return
    bar = tqdm(total=None, desc=desc, bar_format="{desc}: {elapsed}")
    stop = threading.Event()

    def tick():
        while not stop.wait(1.0):
            bar.refresh()

    thread = threading.Thread(target=tick, daemon=True)
    thread.start()
    try:
        yield
    finally:
        stop.set()
        thread.join()
        bar.close()


def make_policy(controller: str, shape: F.FieldShape, args: argparse.Namespace):
    """(policy, params, params_axes) for the CLI's controller choice: the oracle, or a mask
    controller in the perception loop (closed_loop.make), segmenter weights shared."""
    if controller == "oracle":
        return control.as_policy("oracle"), control.oracle_params(lookahead=args.lookahead), None
    from mjxrow import render

    w, _, h = args.image.partition("x")
    try:
        intr = render.Intrinsics(int(w), int(h), args.fovy)
    except ValueError as e:
        raise ValueError(f"--image: expected WIDTHxHEIGHT, got {args.image!r} ({e})") from None
    method = "zeros" if controller == "segzeros" else "min"
    cparams = control.seg_params(method, args.variant, image_hw=(intr.height, intr.width))
    policy, pparams = closed_loop.make(controller, shape, intr, args.perception,
                                      args.checkpoint, args.condition)
    return policy, (pparams, cparams), None


def results_table(params: F.FieldParams, seeds: np.ndarray, lanes: np.ndarray,
                  summary: dict[str, Any]) -> pd.DataFrame:
    """One row per episode: seed, lane, field parameters, metrics (reason as its name)."""
    cols: dict[str, Any] = {"seed": seeds, "lane": lanes}
    cols.update({k: np.asarray(getattr(params, k)) for k in F.PARAM_NAMES})
    for k in CSV_METRICS:
        v = np.asarray(summary[k])
        cols[k] = np.asarray(M.REASONS)[v] if k == "reason" else v
    return pd.DataFrame(cols)


def _parser() -> argparse.ArgumentParser:
    p = argparse.ArgumentParser(prog="python -m mjxrow.episode",
                                description="Run one batch of episodes and score them.")
    p.add_argument("--preset", default="vineyard", choices=F.CROPS)
    p.add_argument("--controller", default="oracle", choices=tuple(control.CONTROLLERS))
    p.add_argument("--n", type=int, default=8, help="episodes (one field each)")
    p.add_argument("--seed", type=int, default=0, help="episode i uses seed + i")
    p.add_argument("--out", required=True, help="output directory (episodes.csv)")
    p.add_argument("--set", action="append", default=[], metavar="KEY=VALUE",
                   help="field parameter override (repeatable), e.g. --set d_rr=3.0")
    p.add_argument("--steps", type=int, default=600, help="control steps before timeout")
    p.add_argument("--path-length", type=float, default=20.0, help="m, start → goal")
    p.add_argument("--goal-radius", type=float, default=0.40, help="m")
    p.add_argument("--lateral-std", type=float, default=0.0, help="m, start offset std")
    p.add_argument("--heading-std-deg", type=float, default=0.0, help="deg, start heading std")
    p.add_argument("--lookahead", type=float, default=1.0, help="m, oracle look-ahead")
    p.add_argument("--variant", default="paper", choices=("paper", "public"),
                   help="SegZeros/SegMin law: the paper's or the authors' public code's")
    p.add_argument("--perception", default="ground_truth", choices=closed_loop.SOURCES,
                   help="mask source of segzeros/segmin")
    p.add_argument("--checkpoint", default="", help="segmenter checkpoint (default: the crop's)")
    p.add_argument("--image", default="112x64", help="camera image WIDTHxHEIGHT [px]")
    p.add_argument("--fovy", type=float, default=42.0, help="deg, vertical field of view")
    p.add_argument("--condition", default="sunny",
                   choices=("sunny", "cloudy", "crepuscular", "long_shadows"))
    p.add_argument("--no-progress", action="store_true", help="no progress lines")
    return p


def run_cli(args: argparse.Namespace) -> pd.DataFrame:
    if args.n < 1:
        raise ValueError(f"--n: must be at least 1, got {args.n}")
    if args.seed < 0:
        raise ValueError(f"--seed: must be non-negative, got {args.seed}")
    for flag, v in (("--lateral-std", args.lateral_std),
                    ("--heading-std-deg", args.heading_std_deg)):
        if not (math.isfinite(v) and v >= 0):
            raise ValueError(f"{flag}: must be finite and non-negative, got {v}")
    sets = parse_sets(args.set)
    params = F.make_params(args.preset, **sets)
    params = jax.tree.map(lambda x: jnp.broadcast_to(x, (args.n,)), params)
    big = 1 << 20  # limits of the static shape are checked once it is fitted
    F.validate(params, F.FieldShape(args.preset, big, big, (2, 2), big))
    shape = F.fit_shape(params, args.preset)
    F.validate(params, shape)
    row_len = float(params.row_length[0] * params.scale[0])
    if args.path_length > row_len:
        raise ValueError(f"--path-length: {args.path_length} m is longer than the rows "
                         f"({row_len:g} m)")
    cfg = EpisodeConfig(crop=args.preset, n_steps=args.steps, goal_radius=args.goal_radius,
                        sim=sim.SimConfig(path_length=args.path_length))
    policy, pparams, axes = make_policy(args.controller, shape, args)
    seeds = args.seed + np.arange(args.n)
    keys = jax.vmap(lambda s: jax.random.split(jax.random.key(s)))(jnp.asarray(seeds))
    show = not args.no_progress
    with _ticker(f"fields ({args.n} × {args.preset})", show):
        gen = jax.jit(jax.vmap(F.generate, in_axes=(0, None, 0)), static_argnums=1)
        fields = jax.block_until_ready(gen(params, shape, keys[:, 0]))
        _, mx = sim.make_model(shape, cfg.sim)
    noise = sim.pose_noise(args.lateral_std, math.radians(args.heading_std_deg))
    call_args = rollout_args(mx, fields, None, keys[:, 1], pparams, axes, noise)
    fn = compiled(policy, cfg, axes)
    t0 = time.perf_counter()
    with _ticker("compiling", show):
        exe = fn.lower(*call_args).compile()
    t1 = time.perf_counter()
    with _ticker(f"running {args.n} episodes × {cfg.n_steps} steps", show):
        log = jax.block_until_ready(exe(*call_args))
    t2 = time.perf_counter()
    summary = jax.tree.map(np.asarray, summarise(log, cfg))
    table = results_table(params, seeds, np.asarray(call_args[2]), summary)
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    table.to_csv(out / "episodes.csv", index=False)
    print(f"{args.controller} on {args.preset}: {args.n} episodes, compile {t1 - t0:.1f} s, "
          f"run {t2 - t1:.1f} s ({args.n * cfg.n_steps / (t2 - t1):.0f} env-steps/s)")
    print(M.format_table({k: summary[k] for k in CSV_METRICS}))
    print(f"wrote {out / 'episodes.csv'}")
    return table


def main(argv: list[str] | None = None) -> None:
    args = _parser().parse_args(argv)
    try:
        run_cli(args)
    except ValueError as e:
        print(f"error: {e}", file=sys.stderr)
        sys.exit(2)


if __name__ == "__main__":
    main()
