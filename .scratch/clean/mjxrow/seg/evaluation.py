"""Evaluation of a segmenter on a dataset folder (default: its test split) or on renders: the
work of `python -m mjxrow.seg.eval` (its parser and docs: `mjxrow.seg.eval`), and the counts,
scores and summaries that training and the tables use.

Weeds are not crop: the ground truth is the crop mask, and where the class image is known
(renders, folders with class images) the summary also tells how the model treats the weeds:
the IoU over the weedy images (those with at least one weed pixel) and the share of weed
pixels it calls crop.
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

from mjxrow import crops, files, render
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


def image_counts(logits: jax.Array, mask: jax.Array, threshold: float = THRESHOLD,
                 weed: jax.Array | None = None) -> dict[str, jax.Array]:
    """Per-image pixel counts (float32 [B] each): inter, union, correct, total; with the weed
    pixels `weed` bool [B, H, W] also weed (their number) and weed_crop (those predicted crop)."""
    pred = jax.nn.sigmoid(logits.astype(jnp.float32)) > threshold
    s = lambda a: jnp.sum(a.astype(jnp.float32), axis=(1, 2))  # noqa: E731
    total = jnp.full(mask.shape[:1], mask.shape[1] * mask.shape[2], jnp.float32)
    out = {"inter": s(pred & mask), "union": s(pred | mask), "correct": s(pred == mask),
           "total": total}
    if weed is not None:
        out.update(weed=s(weed), weed_crop=s(pred & weed))
    return out


def count_batches(module: SegNet, variables: dict, batches, threshold: float = THRESHOLD,
                  progress: bool = True) -> pd.DataFrame:
    """Per-image counts over batches [(rgb, mask, weight)] or [(rgb, mask, weight, weed)];
    padded images (weight 0) dropped."""
    fn = jax.jit(lambda v, rgb, mask, weed: image_counts(apply(module, v, rgb), mask, threshold,
                                                         weed))
    rows = []
    for rgb, mask, weight, *weed in tqdm(batches, desc="evaluate", disable=not progress,
                                         leave=False):
        c = jax.device_get(fn(variables, rgb, mask, weed[0] if weed else None))
        keep = np.asarray(weight, bool)
        rows.append(pd.DataFrame({k: np.asarray(v)[keep] for k, v in c.items()}))
    return pd.concat(rows, ignore_index=True)


SUMMARY = ("images", "accuracy", "iou", "weedy_images", "weedy_iou", "weed_as_crop")


def summarise(df: pd.DataFrame, by: tuple[str, ...] = ("crop", "condition")) -> pd.DataFrame:
    """Pooled accuracy and IoU per group of `by` columns, per crop ("all" conditions) and over
    everything: columns [*by, images, accuracy, iou, weedy_images, weedy_iou, weed_as_crop].
    weedy_images: images with weed pixels; weedy_iou: the IoU pooled over them; weed_as_crop:
    the share of weed pixels predicted crop (NaN without weeds, or counts without them)."""
    def pooled(g: pd.DataFrame) -> pd.Series:
        union = g["union"].sum()
        out = {"images": len(g), "accuracy": g["correct"].sum() / g["total"].sum(),
               "iou": g["inter"].sum() / union if union > 0 else 1.0,
               "weedy_images": 0, "weedy_iou": np.nan, "weed_as_crop": np.nan}
        if "weed" in g.columns:
            weedy = g[g["weed"] > 0]
            out["weedy_images"] = len(weedy)
            if len(weedy):
                w_union = weedy["union"].sum()
                out["weedy_iou"] = weedy["inter"].sum() / w_union if w_union > 0 else 1.0
                out["weed_as_crop"] = weedy["weed_crop"].sum() / weedy["weed"].sum()
        return pd.Series(out)

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
    out = pd.concat(parts, ignore_index=True)[[*by, *SUMMARY]]
    out["images"] = out["images"].astype(int)
    out["weedy_images"] = out["weedy_images"].astype(int)
    return out


def evaluate_folder(module: SegNet, variables: dict, root: str | Path, crop: str | None = None,
                    split: str | None = "test", size: int | None = None, batch: int = 32,
                    threshold: float = THRESHOLD, workers: int = 4) -> pd.DataFrame:
    """Per-image counts with the index columns (crop, condition, ...) of the selected rows (the
    weed counts too where the folder has class images)."""
    rows = seg_data.select(seg_data.read_index(root), crop, split)
    if len(rows) == 0:
        raise ValueError(f"dataset {str(root)!r}: no images of crop {crop!r} in split {split!r}")
    rgb, mask = seg_data.load_arrays(root, rows, size, workers)
    weed = seg_data.load_weeds(root, rows, size, workers)
    counts = count_batches(module, variables, seg_data.batches(rgb, mask, batch, weed),
                           threshold)
    return pd.concat([rows.reset_index(drop=True), counts], axis=1)


def render_set(crop: str, n: int, size: int, batch: int = 32, seed: int = 0,
               variety: str = "fields") -> tuple[list, pd.DataFrame]:
    """The fixed test renders: ⌈n / batch⌉ batches [(rgb, mask, weight, weed)] (seed
    20,000 + seed) and their images' crop and condition (a frame, one row per image)."""
    fn = seg_data.onthefly(crop, size, batch, variety=variety, labels=True)
    rendered = seg_data.fixed_set(fn, max(1, -(-n // batch)), 20_000 + seed)
    names = crops.names()
    per_batch = [crop] * batch if crop != "all" else list(np.repeat(names, batch // len(names)))
    conds = np.concatenate([b[4] for b in rendered])
    labels = pd.DataFrame({"crop": per_batch * len(rendered),
                           "condition": np.asarray(render.CONDITIONS)[conds]})
    return [(rgb, mask, w, classes == render.WEED)
            for rgb, mask, w, classes, _ in rendered], labels


def evaluate_renders(module: SegNet, variables: dict, crop: str, n: int, size: int,
                     batch: int = 32, seed: int = 0, threshold: float = THRESHOLD,
                     variety: str = "fields") -> pd.DataFrame:
    """Per-image counts (weeds included) on `render_set`'s renders, with their crop and
    condition."""
    batches, labels = render_set(crop, n, size, batch, seed, variety)
    counts = count_batches(module, variables, batches, threshold)
    return pd.concat([labels, counts], axis=1)


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
                              args.threshold, args.variety)
    table = summarise(df)
    with pd.option_context("display.float_format", "{:.4f}".format, "display.width", 120):
        print(table.to_string(index=False))
    if args.csv:
        files.atomic_write_text(args.csv, table.to_csv(index=False))
    return table

