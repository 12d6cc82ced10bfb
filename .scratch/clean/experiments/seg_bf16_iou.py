"""Does the segmenter's mask change in bfloat16? IoU against the renderer's plant mask of the
shipped checkpoint computing in float32 and in bfloat16 (weights stay float32), and the IoU of
the two predictions with each other, on the same renders.

    python experiments/seg_bf16_iou.py [--crops zucchini pear ...] [--n 256] [--size 64]
                                       [--out FILE.jsonl]

Renders: `seg.evaluation.evaluate_renders`'s fixed set (seed 20,000), as `python -m mjxrow.seg.eval`
without `--data`. IoU is pooled over the images: Σ|M ∩ Y| / Σ|M ∪ Y|, threshold 0.7.
"""

from __future__ import annotations

import argparse
import functools
import json
import sys
from pathlib import Path

import jax
import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))  # run from a checkout
from mjxrow import crops  # noqa: E402
from mjxrow.seg import checkpoint as ckpt  # noqa: E402
from mjxrow.seg import data as D  # noqa: E402
from mjxrow.seg.model import predict_mask  # noqa: E402


def compare(crop: str, n: int, size: int, batch: int = 32) -> dict[str, float]:
    """Pooled IoU vs the true mask in float32 and bfloat16, and between the two predictions."""
    module, variables = ckpt.load(crop)
    batches = D.fixed_set(D.onthefly(crop, size, batch), max(1, -(-n // batch)), 20_000)
    fns = {dt: jax.jit(functools.partial(predict_mask, module.clone(dtype=dt)))
           for dt in ("float32", "bfloat16")}
    tot = {k: 0.0 for k in ("i32", "u32", "i16", "u16", "iab", "uab")}
    for rgb, mask, weight in batches:
        keep = np.asarray(weight, bool)
        y = np.asarray(mask)[keep]
        a, b = (np.asarray(fns[dt](variables, rgb))[keep] for dt in ("float32", "bfloat16"))
        for tag, p, q in (("32", a, y), ("16", b, y), ("ab", a, b)):
            tot["i" + tag] += float(np.sum(p & q))
            tot["u" + tag] += float(np.sum(p | q))
    iou = {tag: tot["i" + tag] / tot["u" + tag] if tot["u" + tag] else 1.0
           for tag in ("32", "16", "ab")}
    return {"images": len(batches) * batch, "iou_float32": iou["32"],
            "iou_bfloat16": iou["16"], "iou_between": iou["ab"]}


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--crops", nargs="+", default=["zucchini"], choices=crops.names())
    p.add_argument("--n", type=int, default=256, help="rendered images per crop")
    p.add_argument("--size", type=int, default=64, help="image side [px]")
    p.add_argument("--out", help="also append one JSON line per crop to this file")
    args = p.parse_args(argv)
    print(f"| crop | images ({args.size} x {args.size}) | IoU float32 | IoU bfloat16 | "
          "IoU float32 vs bfloat16 |\n|---|---|---|---|---|")
    for crop in args.crops:
        r = compare(crop, args.n, args.size)
        print(f"| {crop} | {r['images']} | {r['iou_float32']:.4f} | {r['iou_bfloat16']:.4f} | "
              f"{r['iou_between']:.4f} |", flush=True)
        if args.out:
            with open(args.out, "a") as f:
                f.write(json.dumps({"stage": "seg_bf16_iou", "crop": crop, "size": args.size,
                                    "device": jax.devices()[0].device_kind, **r}) + "\n")
    return 0


if __name__ == "__main__":
    sys.exit(main())
