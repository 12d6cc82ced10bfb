"""Closed-loop throughput: render → segment → SegZeros → physics for B worlds, in control
steps/s and episodes/min.

One control step = one rendered frame, one segmenter call, one controller call and the physics
substeps of a control period (7 at 15 Hz). The program is the one the sweep and
`python -m mjxrow.episode` run: a RunConfig (`sweep.config.from_dict`, any `--set KEY=VALUE`
of the sweep YAML) assembled by `rollout.build`, fields of episodes 0..B-1 of seed 0, the batch
sharded over the devices (on a CPU-only machine one device per core, as the sweep). Each call
runs `--steps` control steps (episode.max_time = steps / control_hz; the path is longer than
the robot drives in that time, so episodes run their full length and the figure is the steady
rate); episodes/min = 60 · control steps/s / `--episode-steps` (600: the paper's 20 m at
0.5 m/s and 15 Hz). Compile time (lower + compile, or the load from the persistent cache)
apart from the median of `--repeats` calls after a first, untimed one (which sets up what
the program runs once, e.g. its CUDA graphs; its time is kept as `first_run_s`).

GPU: `--batch 1024 --image 64` (fast configuration) and `--batch 512 --image 224` (paper's
224 × 224); CPU: `--batch 2 --image 64 --steps 25 --repeats 2`.
"""

from __future__ import annotations

import argparse
import dataclasses
import statistics
import time

import numpy as np

from mjxrow import control, crops, runtime, stopwatch
from mjxrow.bench.timing import time_runs
from mjxrow.policies import perception
from mjxrow.rollout import build as rollout_build
from mjxrow.rollout import episode as rollout_episode
from mjxrow.rollout.config import RunConfig
from mjxrow.seg import checkpoint as seg_checkpoint
from mjxrow.seg import convs as seg_convs
from mjxrow.sweep import config as sweep_config
from mjxrow.sweep import grid as sweep_grid


def add_args(p: argparse.ArgumentParser) -> None:
    p.add_argument("--preset", default="zucchini", choices=crops.names())
    p.add_argument("--batch", type=int, nargs="+", default=[256, 1024])
    p.add_argument("--image", type=int, default=64, help="camera image side [px]")
    p.add_argument(
        "--steps",
        type=int,
        default=150,
        help=f"control steps per timed call (above {rollout_episode.CHUNK}, rounded up to a "
        f"multiple of {rollout_episode.CHUNK}: the episode loop runs whole chunks)",
    )
    p.add_argument("--episode-steps", type=int, default=600,
                   help="control steps of one episode, for episodes/min (default: 20 m at "
                        "0.5 m/s and 15 Hz)")
    p.add_argument("--perception", default="learned", choices=("learned", "ground_truth"))
    p.add_argument("--controller", default="segzeros", choices=("segzeros", "segmin", "oracle"))
    p.add_argument("--seg-dtype", default="float32", choices=("float32", "bfloat16"),
                   help="the segmenter's compute dtype (weights stay float32)")
    p.add_argument(
        "--seg-impl",
        default="auto:auto",
        metavar="DW:PW",
        help=f"the segmenter's depthwise (auto, {', '.join(seg_convs.DW_IMPLS)}; "
        f"{seg_convs.auto_rule('depthwise')}) and 1x1 (auto, {', '.join(seg_convs.PW_IMPLS)}; "
        f"{seg_convs.auto_rule('pointwise')}) conv implementations",
    )
    p.add_argument("--set", action="append", default=[], metavar="KEY=VALUE",
                   help="a key of the sweep YAML, e.g. --set sim.iterations=2 (repeatable)")
    p.add_argument("--repeats", type=int, default=3)


def run_config(args: argparse.Namespace) -> RunConfig:
    """The RunConfig of the command line (ConfigError naming the key)."""
    hz = sweep_config.from_dict({}, sets=args.set).sim.control_hz
    raw = {"preset": args.preset, "controller": {"name": args.controller},
           "perception": {"source": args.perception},
           "camera": {"width": args.image, "height": args.image},
           "episode": {"max_time": rollout_episode.steps_run(args.steps) / hz}}
    return sweep_grid.expand(sweep_config.from_dict(raw, sets=args.set))[0].cfg


def seg_impl(spec: str) -> dict[str, str]:
    """`--seg-impl DW:PW` → SegNet attributes (ValueError naming a bad part)."""
    dw, sep, pw = spec.partition(":")
    if (
        not sep
        or dw not in ("auto",) + seg_convs.DW_IMPLS
        or pw not in ("auto",) + seg_convs.PW_IMPLS
    ):
        raise ValueError(
            f"--seg-impl {spec!r}: expected DW:PW with DW one of auto, "
            f"{', '.join(seg_convs.DW_IMPLS)} and PW one of auto, {', '.join(seg_convs.PW_IMPLS)}"
        )
    return {"dw_impl": dw, "pw_impl": pw}


def with_segmenter(
    built: rollout_build.Built, run: RunConfig, **changes: str
) -> rollout_build.Built:
    """`built` whose segmenter module has `changes` (compute dtype, conv implementations);
    its weights, shared params, are unchanged."""
    if built.base is None:
        return built

    module = seg_checkpoint.module_from_config(
        seg_checkpoint.read_config(run.checkpoint_path() or run.preset)["model"])
    if all(getattr(module, k) == v for k, v in changes.items()):
        return built
    policy = perception.perception_policy(run.controller.name, built.shape, run.camera,
                                          "learned", module.clone(**changes), run.render)
    note = ", ".join(f"{k} {v}" for k, v in sorted(changes.items()))
    return dataclasses.replace(built, policy=policy, placed={},
                               key=built.key and f"{built.key}\nsegmenter {note}")


def measure(built: rollout_build.Built, run: RunConfig, b: int, repeats: int) -> dict:
    """Compile (or cache load) seconds, the run times of `repeats` calls and the summary of
    the last one, for episodes 0..b-1 of `run`."""
    batch = built.batch([(run, e) for e in range(b)])
    args = batch.args(built.mx)
    watch = stopwatch.Stopwatch()
    t0 = time.perf_counter()
    exe = built.executable(args)
    compile_s = time.perf_counter() - t0
    split = watch.split()
    t = time_runs(exe, *args, repeats=repeats)
    log = t["out"]
    summary = built.summarise(log, b)
    return {"compile_s": compile_s, "cache_hits": split["cache_hits"],
            "first_run_s": t["first_s"], "runs_s": t["runs_s"],
            "alive_end": int(np.sum(runtime.to_host(log.alive[:, -1]))),
            "success": float(np.mean(summary["success"]))}


def run(args: argparse.Namespace) -> list[dict]:
    try:
        cfg = run_config(args)
    except sweep_config.ConfigError as e:
        raise SystemExit(f"bench closed_loop: {e}") from None
    try:
        impl = seg_impl(args.seg_impl)
    except ValueError as e:
        raise SystemExit(f"bench closed_loop: {e}") from None
    rows = []
    if rollout_episode.steps_run(args.steps) != args.steps:
        print(
            f"note: --steps {args.steps} → {rollout_episode.steps_run(args.steps)}, a whole "
            f"number of the episode loop's {rollout_episode.CHUNK}-step chunks (it would run "
            f"them and count {args.steps})",
            flush=True,
        )
    for b in args.batch:
        built = with_segmenter(rollout_build.build(cfg), cfg, dtype=args.seg_dtype, **impl)
        m = measure(built, cfg, built.padded(b), args.repeats)
        med = statistics.median(m["runs_s"])
        steps_s = b * cfg.episode.n_steps / med
        per_min = 60.0 * steps_s / args.episode_steps
        seg = "" if not (control.get(cfg.controller.name).needs_mask and
                         cfg.perception.source == "learned") else \
            f", segmenter {args.seg_dtype}" + ("" if args.seg_impl == "auto:auto" else
                                                f" {args.seg_impl}")
        config = (f"{cfg.preset}, {cfg.controller.name} on {cfg.perception.source} masks, "
                  f"{args.image}x{args.image} px, {cfg.episode.n_steps} control steps{seg}"
                  + "".join(f", {s}" for s in args.set))
        print(f"B={b}: {steps_s:,.0f} control steps/s = {per_min:,.0f} episodes/min of "
              f"{args.episode_steps} steps (compile {m['compile_s']:.1f} s"
              f"{', from the cache' if m['cache_hits'] else ''}, median run {med:.2f} s on "
              f"{built.devices} device(s)), alive at end {m['alive_end']}/{b}, success "
              f"{m['success']:.2f}", flush=True)
        rows.append({"stage": "closed_loop", "config": config, "batch": b, "value": steps_s,
                     "unit": "control steps/s", "episodes_per_min": per_min,
                     "episode_steps": args.episode_steps, "devices": built.devices, **m})
    return rows
