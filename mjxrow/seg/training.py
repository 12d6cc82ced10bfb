"""Training of the plant segmenter: the loop with resume over the step of `mjxrow.seg.step`
(losses, train state, optimiser), and the work of `python -m mjxrow.seg.train` (its parser
and docs: `mjxrow.seg.train`). Validation IoU uses a hard mask at threshold 0.7 (the paper's),
pooled over the validation set: Σ|M ∩ Y| / Σ|M ∪ Y|.
"""

from __future__ import annotations

import dataclasses
import functools
import json
import math
import shutil
import sys
import time
from collections.abc import Callable, Iterator
from pathlib import Path
from typing import Any

import jax
import jax.numpy as jnp
import numpy as np
import orbax.checkpoint as ocp
from tqdm.auto import tqdm

from mjxrow import crops
from mjxrow.files import check_out_dir
from mjxrow.seg import checkpoint
from mjxrow.seg import data as seg_data
from mjxrow.seg import train as train_cli
from mjxrow.seg.evaluation import THRESHOLD, evaluate, make_eval
from mjxrow.seg.model import SegNet, create
from mjxrow.seg.step import (
    batch_key,
    init_state,
    make_optimizer,
    make_schedule,
    make_step,
)


@dataclasses.dataclass
class Data:
    """Training data: exactly one of `batch_fn` (jittable key → (rgb, mask), fused into the step;
    a tuple of them, e.g. one per image size, is used in turn: step s takes fn[s % n]) or
    `batches` (start step → endless host iterator of numpy (rgb, mask), any image sizes);
    `val` batches [(rgb, mask, weight)], any sizes, pooled; `describe` says what it is."""

    val: list
    describe: str
    batch_fn: Callable | tuple[Callable, ...] | None = None
    batches: Callable[[int], Iterator[tuple[np.ndarray, np.ndarray]]] | None = None
    # fuse: batch_fn runs inside the jitted step (one program per function); False: it runs as
    # is before the step (an `onthefly` function: its renderers compiled once, shared with `val`)
    fuse: bool = True


@dataclasses.dataclass(frozen=True)
class TrainConfig:
    steps: int = 20000
    lr: float = 1e-3
    warmup: int = 500
    weight_decay: float = 1e-4
    loss: str = "iou"
    flip: float = 0.5
    grey: float = 0.2
    jitter: float = 0.0
    seed: int = 0
    eval_every: int = 500
    ckpt_every: int = 500
    log_every: int = 50
    threshold: float = THRESHOLD
    progress: bool = True


RUN_FILES = ("state", "best", "train_log.jsonl")  # a run folder's own entries (--restart)


def restart(out: Path) -> None:
    """Delete run folder `out`'s own entries (`RUN_FILES`), nothing else in it."""
    paths = [out / name for name in RUN_FILES]
    for p in paths:  # a link is not what seg.train writes: refuse before deleting anything
        if p.is_symlink():
            raise ValueError(f"--restart: {p} is a link, not this run's; it is not deleted")
    for p in paths:
        if p.is_dir():
            shutil.rmtree(p)
        elif p.is_file():
            p.unlink()


def _truncate_log(path: Path, step: int) -> None:
    """Drop log lines of steps after `step` (work lost by an interruption)."""
    if path.is_file():
        path.write_text("".join(ln + "\n" for ln in path.read_text().splitlines()
                                if _logged_step(ln) <= step))


def _logged_step(line: str) -> float:
    """The step of a log line; a blank, cut-short or foreign line counts as after every step
    (it is dropped)."""
    try:
        rec = json.loads(line)
        return float(rec.get("step", 0)) if isinstance(rec, dict) else math.inf
    except (ValueError, TypeError):
        return math.inf


@functools.lru_cache(maxsize=8)
def _compiled(module: SegNet, lr: float, steps: int, warmup: int, weight_decay: float, loss: str,
              flip: float, grey: float, jitter: float, threshold: float, batch_fns: tuple):
    """(schedule, optimizer, jitted steps (one per batch function, or one for host batches),
    jitted eval) for a run; cached so that runs with equal settings (a resumed run in the same
    process, tests) reuse the compiled functions."""
    sched = make_schedule(lr, steps, warmup)
    tx = make_optimizer(sched, weight_decay)
    steps_ = tuple(jax.jit(make_step(module, tx, loss, flip, grey, jitter, fn), donate_argnums=0)
                   for fn in batch_fns or (None,))
    return sched, tx, steps_, jax.jit(make_eval(module, threshold))


def _manager(out: Path) -> ocp.CheckpointManager:
    return ocp.CheckpointManager(out / "state", options=ocp.CheckpointManagerOptions(
        max_to_keep=2, create=True))


def fit(module: SegNet, variables: dict, data: Data, cfg: TrainConfig, out: str | Path,
        meta: dict[str, Any] | None = None) -> dict[str, Any]:
    """Train `module` from `variables` for cfg.steps steps, writing under `out`:
    `state/` (orbax: step, params, batch_stats, opt_state, rng, best IoU; resumed from if
    present), `best/` (inference checkpoint with the best validation IoU), `train_log.jsonl`.
    Returns {"step", "best_iou", "best_step", "final": last validation scores}.

    A run resumes from its last saved state (every cfg.ckpt_every steps); the log is cut back to
    that step. The model must match; a different cfg.steps changes the schedule from there on."""
    out = Path(out).resolve()
    out.mkdir(parents=True, exist_ok=True)
    run_meta = {"model": module.config(), "train": dataclasses.asdict(cfg),
                "data": data.describe, **(meta or {})}
    fns = data.batch_fn if isinstance(data.batch_fn, tuple) else \
        (() if data.batch_fn is None else (data.batch_fn,))
    sched, tx, step_fns, eval_fn = _compiled(module, cfg.lr, cfg.steps, cfg.warmup,
                                             cfg.weight_decay, cfg.loss, cfg.flip, cfg.grey,
                                             cfg.jitter, cfg.threshold, fns if data.fuse else ())
    state = init_state(jax.tree.map(jnp.copy, variables), tx, cfg.seed)  # donated below
    mngr = _manager(out)
    start = mngr.latest_step()
    best_step = -1
    if start is not None:
        restored = mngr.restore(start, args=ocp.args.Composite(
            state=ocp.args.StandardRestore(jax.eval_shape(lambda: state)),
            meta=ocp.args.JsonRestore()))
        old = restored.meta
        if old.get("model") != run_meta["model"]:
            raise ValueError(f"out {out}: holds a run of model {old.get('model')}, not "
                             f"{run_meta['model']}; use another --out or --restart")
        state, best_step = restored.state, old.get("best_step", -1)
        _truncate_log(out / "train_log.jsonl", start)
    log = open(out / "train_log.jsonl", "a")
    first = int(state.step)
    # fresh and restored states alike on the default device, committed: one compiled step
    state = jax.device_put(state, jax.sharding.SingleDeviceSharding(jax.devices()[0]))
    it = None if data.batch_fn is not None else data.batches(first)
    rng = jax.random.wrap_key_data(np.asarray(jax.device_get(state.rng)))  # constant
    bar = tqdm(total=cfg.steps, initial=first, desc="train", disable=not cfg.progress,
               dynamic_ncols=True)
    pending, t0, t_last, last_scores = [], time.perf_counter(), time.perf_counter(), {}
    rec: dict[str, Any] = {"loss": float("nan")}

    def save_state(step: int):
        mngr.save(step, args=ocp.args.Composite(
            state=ocp.args.StandardSave(state),
            meta=ocp.args.JsonSave({**run_meta, "best_step": best_step})))

    try:
        for step in range(first, cfg.steps):
            if it is None and data.fuse:
                state, m = step_fns[step % len(step_fns)](state)
            elif it is None:  # the fused step's batch: same key, made before the step
                rgb, mask = fns[step % len(fns)](batch_key(rng, step))
                state, m = step_fns[0](state, rgb, mask)
            else:
                rgb, mask = next(it)
                state, m = step_fns[0](state, rgb, mask)
            pending.append(m["loss"])
            done = step + 1
            if done % cfg.log_every == 0 or done == cfg.steps:
                losses = np.asarray(jax.device_get(pending), np.float32)
                now = time.perf_counter()
                rec = {"step": done, "loss": float(losses.mean()),
                       "lr": float(sched(done)), "steps_per_s": len(losses) / (now - t_last),
                       "elapsed_s": now - t0}
                log.write(json.dumps(rec) + "\n")
                log.flush()
                pending, t_last = [], now
                bar.set_postfix(loss=f"{rec['loss']:.4f}",
                                val_iou=f"{float(state.best_iou):.3f}", refresh=False)
            if done % cfg.eval_every == 0 or done == cfg.steps:
                last_scores = evaluate(eval_fn, state.variables(), data.val)
                improved = last_scores["iou"] > float(state.best_iou)
                if improved:
                    best = jax.device_put(np.float32(last_scores["iou"]), state.best_iou.sharding)
                    state = state.replace(best_iou=best)  # committed like the rest: no recompile
                    best_step = done
                    checkpoint.save(out / "best", module, jax.device_get(state.variables()),
                                    meta={**run_meta, "step": done, "val_iou": last_scores["iou"],
                                          "val_acc": last_scores["acc"]})
                log.write(json.dumps({"step": done, "val_iou": last_scores["iou"],
                                      "val_acc": last_scores["acc"],
                                      "best_iou": float(state.best_iou)}) + "\n")
                log.flush()
                bar.set_postfix(loss=f"{rec['loss']:.4f}", val_iou=f"{last_scores['iou']:.3f}",
                                refresh=False)
            if done % cfg.ckpt_every == 0 or done == cfg.steps:
                save_state(done)
            bar.update(1)
    finally:
        bar.close()
        log.close()
        mngr.wait_until_finished()
        mngr.close()
    return {"step": int(state.step), "best_iou": float(state.best_iou), "best_step": best_step,
            "final": last_scores}


def export(out: str | Path, dest: str | Path, weights_dtype: str = "float16",
           extra_meta: dict[str, Any] | None = None) -> Path:
    """Copy the best checkpoint of run `out` to `dest` (a shipped-checkpoint folder), stored as
    `weights_dtype`, with the run's training log beside it."""
    out = Path(out)
    module, variables = checkpoint.load(out / "best")
    meta = {**checkpoint.read_config(out / "best")["meta"], **(extra_meta or {})}
    path = checkpoint.save(dest, module, variables, weights_dtype=weights_dtype, meta=meta)
    if (out / "train_log.jsonl").is_file():
        (path / "train_log.jsonl").write_text((out / "train_log.jsonl").read_text())
    return path


def build_data(args) -> Data:
    """Data for the CLI: the dataset folder (`--data`) or the renderer (`--on-the-fly`)."""

    sizes = "x".join(map(str, args.size))
    if args.data:
        df = seg_data.select(seg_data.read_index(args.data), args.crop)
        train_df, val_df = seg_data.train_val(df, args.val_frac, args.seed)
        loader = seg_data.Loader(
            args.data, train_df, args.batch, args.size, args.seed, args.workers
        )
        val = []
        for size in args.size:
            val += seg_data.batches(
                *seg_data.load_arrays(args.data, val_df, size, args.workers,
                                      progress=not args.no_progress), args.batch
            )
        return Data(val=val, batches=loader,
                    describe=f"folder {Path(args.data).resolve()} crop {args.crop}: "
                             f"{len(train_df)} train / {len(val_df)} val images, sizes {sizes}")
    fns = tuple(seg_data.onthefly(args.crop, size, args.batch, variety=args.variety)
                for size in args.size)
    t0 = time.perf_counter()
    seg_data.warm(*fns)  # every size's renderers side by side, before the validation set
    print(f"renderers of {len(fns)} size(s) compiled in {time.perf_counter() - t0:.0f} s",
          file=sys.stderr, flush=True)
    n_val = max(1, -(-args.val_n // args.batch))
    val = [
        b for i, fn in enumerate(fns) for b in seg_data.fixed_set(fn, n_val, 10_000 + args.seed + i)
    ]
    return Data(val=val, batch_fn=fns, fuse=False,
                describe=f"on-the-fly renders crop {args.crop} (variety {args.variety}), "
                         f"sizes {sizes}, "
                         f"{n_val * args.batch} val images per size (seed {10_000 + args.seed})")


def main(argv: list[str] | None = None) -> dict[str, Any]:
    """`python -m mjxrow.seg.train ARGS` as a function: the fit's result (raises ValueError)."""
    args = train_cli.parser().parse_args(argv)
    for name in ("steps", "batch", "eval_every", "log_every"):
        if getattr(args, name) < 1:
            raise ValueError(f"--{name.replace('_', '-')}: must be ≥ 1, got {getattr(args, name)}")
    for size in args.size:
        if size < 16 or size % 16:
            raise ValueError(f"--size: {size} is not a positive multiple of 16 (output stride)")
    if args.crop != "all":
        crops.get(args.crop)  # ValueError naming an unknown crop, before any work
    out = Path(args.out or f"runs/seg_{args.crop}_{args.arch}")
    check_out_dir(out, "--out")  # OutputError (a ValueError) before any work
    if args.init:
        module, variables = checkpoint.load(args.init)  # ValueError names a missing checkpoint
        init_from = str(checkpoint.resolve(args.init))
    else:
        module, variables = create(args.arch, args.width, jax.random.key(args.seed),
                                   args.size[0], reduced_tail=args.reduced_tail, dtype=args.dtype)
        init_from = "random"
    cfg = TrainConfig(steps=args.steps, lr=args.lr, warmup=args.warmup,
                      weight_decay=args.weight_decay, loss=args.loss, flip=args.flip,
                      grey=args.grey, jitter=args.jitter, seed=args.seed,
                      eval_every=args.eval_every, ckpt_every=args.eval_every,
                      log_every=args.log_every, progress=not args.no_progress)
    data = build_data(args)  # a bad --data names itself here, before anything is deleted
    if args.restart and out.is_dir() and any(out.iterdir()):
        if not (out / "train_log.jsonl").is_file():  # no run of ours: the user's folder
            raise ValueError(f"--restart: {out} holds no seg.train run (no train_log.jsonl); "
                             "it is not deleted: give an --out of its own")
        restart(out)
    command = "python -m mjxrow.seg.train " + " ".join(sys.argv[1:] if argv is None else argv)
    meta = {"command": command, "crop": args.crop, "image_size": args.size[0],
            "image_sizes": args.size,
            "batch": args.batch, "device": jax.devices()[0].device_kind, "init": init_from}
    result = fit(module, variables, data, cfg, out, meta)
    print(json.dumps(result))
    if args.export_to:
        if result["best_step"] < 0 and not (out / "best").exists():
            raise ValueError(f"--export-to: run {out} has no best checkpoint to export")
        path = export(out, args.export_to, args.export_dtype)
        print(f"exported {path} ({checkpoint.size_bytes(path) / 1e6:.2f} MB)")
    return result


def cli(argv: list[str] | None = None) -> int:
    """`main` as a command: a bad flag, output folder or checkpoint is one line and exit 2,
    Ctrl-C exit 130 (the last saved checkpoint is kept; the same command resumes)."""
    try:
        main(argv)
    except ValueError as e:
        print(f"error: {str(e).splitlines()[0] if str(e) else type(e).__name__}", file=sys.stderr)
        return 2
    except KeyboardInterrupt:
        print("interrupted: the last saved checkpoint is kept; run the same command again to "
              "resume", file=sys.stderr)
        return 130
    return 0

