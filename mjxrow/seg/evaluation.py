"""Evaluation of a segmenter on a dataset folder (default: its test split) or on renders: the
work of `python -m mjxrow.seg.eval` (its parser and docs: `mjxrow.seg.eval`), and the counts,
scores and summaries that training and the tables use.
"""

from __future__ import annotations

import sys
from pathlib import Path
from typing import Any

import jax
import jax.numpy as jnp
import numpy as np
import pandas as pd
from tqdm.auto import tqdm

from mjxrow import crops, files
from mjxrow.seg import checkpoint
from mjxrow.seg import data as seg_data
from mjxrow.seg import eval as command
from mjxrow.seg.model import SegNet, apply

THRESHOLD = command.THRESHOLD  # the paper's threshold on sigmoid(logit)


def counts(logits: jax.Array, mask: jax.Array, weight: jax.Array | None = None,
           threshold: float = THRESHOLD) -> dict[str, jax.Array]:
    """Pixel counts of a batch for pooled metrics: intersection, union, correct, total (float32
    scalars); the prediction is sigmoid(logit) > threshold. weight [B] drops padded images."""
    pred = jax.nn.sigmoid(logits.astype(jnp.float32)) > threshold
    w = jnp.ones(mask.shape[0]) if weight is None else weight.astype(jnp.float32)
    s = lambda a: jnp.sum(jnp.sum(a.astype(jnp.float32), axis=(1, 2)) * w)  # noqa: E731
    return {"inter": s(pred & mask), "union": s(pred | mask), "correct": s(pred == mask),
            "total": jnp.sum(w) * mask.shape[1] * mask.shape[2]}


def scores(c: dict[str, Any]) -> dict[str, float]:
    """Pooled IoU and pixel accuracy in [0, 1] from summed `counts` (IoU 1 when both are empty)."""
    inter, union = float(c["inter"]), float(c["union"])
    return {"iou": inter / union if union > 0 else 1.0,
            "acc": float(c["correct"]) / max(float(c["total"]), 1.0)}


def make_eval(module: SegNet, threshold: float = THRESHOLD):
    """`eval(variables, rgb, mask, weight) -> counts` (pure; jit it)."""
    def ev(variables, rgb, mask, weight):
        return counts(module.apply(variables, rgb, train=False), mask, weight, threshold)
    return ev


def evaluate(eval_fn, variables: dict, batches) -> dict[str, float]:
    """Pooled IoU / accuracy of `variables` over batches [(rgb, mask, weight)]."""
    total: dict[str, float] = {}
    for rgb, mask, weight in batches:
        c = jax.device_get(eval_fn(variables, rgb, mask, weight))
        for k, v in c.items():
            total[k] = total.get(k, 0.0) + float(v)
    return scores(total)


def image_counts(logits: jax.Array, mask: jax.Array,
                 threshold: float = THRESHOLD) -> dict[str, jax.Array]:
    """Per-image pixel counts (float32 [B] each): inter, union, correct, total."""
    pred = jax.nn.sigmoid(logits.astype(jnp.float32)) > threshold
    s = lambda a: jnp.sum(a.astype(jnp.float32), axis=(1, 2))  # noqa: E731
    total = jnp.full(mask.shape[:1], mask.shape[1] * mask.shape[2], jnp.float32)
    return {"inter": s(pred & mask), "union": s(pred | mask), "correct": s(pred == mask),
            "total": total}


def count_batches(module: SegNet, variables: dict, batches, threshold: float = THRESHOLD,
                  progress: bool = True) -> pd.DataFrame:
    """Per-image counts over batches [(rgb, mask, weight)]; padded images (weight 0) dropped."""
    fn = jax.jit(lambda v, rgb, mask: image_counts(apply(module, v, rgb), mask, threshold))
    rows = []
    for rgb, mask, weight in tqdm(batches, desc="evaluate", disable=not progress, leave=False):
        c = jax.device_get(fn(variables, rgb, mask))
        keep = np.asarray(weight, bool)
        rows.append(pd.DataFrame({k: np.asarray(v)[keep] for k, v in c.items()}))
    return pd.concat(rows, ignore_index=True)


def summarise(df: pd.DataFrame, by: tuple[str, ...] = ("crop", "condition")) -> pd.DataFrame:
    """Pooled accuracy and IoU per group of `by` columns, per crop ("all" conditions) and over
    everything: columns [*by, images, accuracy, iou]."""
    def pooled(g: pd.DataFrame) -> pd.Series:
        union = g["union"].sum()
        return pd.Series({"images": len(g), "accuracy": g["correct"].sum() / g["total"].sum(),
                          "iou": g["inter"].sum() / union if union > 0 else 1.0})

    parts = [df.groupby(list(by)).apply(pooled, include_groups=False).reset_index()]
    if len(by) > 1:
        per_first = df.groupby(by[0]).apply(pooled, include_groups=False).reset_index()
        for col in by[1:]:
            per_first[col] = "all"
        parts.append(per_first)
    total = pooled(df).to_frame().T
    for col in by:
        total[col] = "all"
    parts.append(total)
    out = pd.concat(parts, ignore_index=True)[[*by, "images", "accuracy", "iou"]]
    out["images"] = out["images"].astype(int)
    return out


def evaluate_folder(module: SegNet, variables: dict, root: str | Path, crop: str | None = None,
                    split: str | None = "test", size: int | None = None, batch: int = 32,
                    threshold: float = THRESHOLD, workers: int = 4) -> pd.DataFrame:
    """Per-image counts with the index columns (crop, condition, ...) of the selected rows."""
    rows = seg_data.select(seg_data.read_index(root), crop, split)
    if len(rows) == 0:
        raise ValueError(f"dataset {str(root)!r}: no images of crop {crop!r} in split {split!r}")
    rgb, mask = seg_data.load_arrays(root, rows, size, workers)
    counts = count_batches(module, variables, seg_data.batches(rgb, mask, batch), threshold)
    return pd.concat([rows.reset_index(drop=True), counts], axis=1)


def evaluate_renders(module: SegNet, variables: dict, crop: str, n: int, size: int,
                     batch: int = 32, seed: int = 0,
                     threshold: float = THRESHOLD) -> pd.DataFrame:
    """Per-image counts on ⌈n / batch⌉ batches rendered on the fly (fixed seed 20,000 + seed)."""
    fn = seg_data.onthefly(crop, size, batch)
    batches = seg_data.fixed_set(fn, max(1, -(-n // batch)), 20_000 + seed)
    counts = count_batches(module, variables, batches, threshold)
    names = crops.names()
    per_batch = [crop] * batch if crop != "all" else list(np.repeat(names, batch // len(names)))
    return counts.assign(crop=per_batch * len(batches), condition="mixed")


def cli(argv: list[str] | None = None) -> int:
    """`main` as a command: exit code 0, or 2 with a one-line error (a missing, empty or damaged
    checkpoint, an unreadable dataset or output file)."""
    try:
        main(argv)
    except (ValueError, OSError) as e:
        print(f"error: {e}", file=sys.stderr)
        return 2
    except KeyboardInterrupt:
        return 130
    return 0


def main(argv: list[str] | None = None) -> pd.DataFrame:
    """`python -m mjxrow.seg.eval ARGS` as a function: the summary table (printed too)."""
    args = command.parser().parse_args(argv)
    if args.crop != "all":
        crops.get(args.crop)  # ValueError naming an unknown crop, before any work
    if args.csv:
        files.check_out_file(args.csv, "--csv")
    if args.ckpt and not Path(args.ckpt).exists():
        raise checkpoint.CheckpointError(f"--ckpt {args.ckpt}: no such folder")
    module, variables = checkpoint.load(args.ckpt or args.crop)
    size = args.size or checkpoint.read_config(args.ckpt or args.crop)["meta"].get(
        "image_size", 224
    )
    if args.data:
        df = evaluate_folder(module, variables, args.data, args.crop,
                             None if args.split == "all" else args.split, size, args.batch,
                             args.threshold)
    else:
        df = evaluate_renders(module, variables, args.crop, args.n, size, args.batch, args.seed,
                              args.threshold)
    table = summarise(df)
    with pd.option_context("display.float_format", "{:.4f}".format, "display.width", 120):
        print(table.to_string(index=False))
    if args.csv:
        files.atomic_write_text(args.csv, table.to_csv(index=False))
    return table

