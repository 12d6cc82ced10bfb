"""Time to write a synthetic dataset: `dataset.write_dataset` of N samples into a fresh folder
(default: the paper-size zucchini set, 19,456 samples at 224×224)."""

from __future__ import annotations

import argparse
import shutil
import tempfile
import time
from pathlib import Path

from mjxrow import crops
from mjxrow.seg import synthesis as seg_synth


def add_args(p: argparse.ArgumentParser) -> None:
    p.add_argument("--crop", default="zucchini", choices=crops.names())
    p.add_argument("--n", type=int, default=seg_synth.PAPER_N["zucchini"], help="samples to write")
    p.add_argument("--size", type=int, default=224, help="image side [px]")
    p.add_argument("--batch", type=int, default=256, help="images rendered per call")
    p.add_argument("--workers", type=int, default=8, help="PNG-encoding threads")
    p.add_argument("--dir", default=None,
                   help="where to write (default: a temporary folder, deleted afterwards)")


def run(args: argparse.Namespace) -> list[dict]:
    root = Path(args.dir) if args.dir else Path(tempfile.mkdtemp(prefix="mjxrow_ds_"))
    try:
        # warm-up: the same compiled shapes as the timed run (render batch, meta batch)
        n_warm = min(args.n, max(args.batch, 512))
        t0 = time.perf_counter()
        seg_synth.write_dataset(
            args.crop,
            n_warm,
            root / "warmup",
            size=args.size,
            batch=args.batch,
            workers=args.workers,
            progress=False,
        )
        warm_s = time.perf_counter() - t0
        out = root / "timed"
        t0 = time.perf_counter()
        seg_synth.write_dataset(args.crop, args.n, out, size=args.size, batch=args.batch,
                                workers=args.workers)
        total_s = time.perf_counter() - t0
        written = len(list(out.glob("*/rgb/*.png")))
    finally:
        if not args.dir:
            shutil.rmtree(root, ignore_errors=True)
    if written != args.n:
        raise RuntimeError(f"wrote {written} RGB images, expected {args.n}")
    paper = seg_synth.PAPER_N[args.crop]
    row = {"stage": "dataset", "config": f"{args.crop} {args.n} samples {args.size}x{args.size}, "
           f"batch {args.batch}, {args.workers} PNG threads", "batch": args.batch,
           "value": total_s, "unit": "s", "samples_per_s": args.n / total_s,
           "warmup_s": warm_s, "warmup_samples": n_warm}
    if args.n != paper:
        row["extrapolated_paper_s"] = paper * total_s / args.n  # labelled: not measured
    print(f"dataset {row['config']}: {total_s:.1f} s ({args.n / total_s:,.1f} samples/s; "
          f"warm-up with compile {warm_s:.1f} s)", flush=True)
    return [row]
