"""Segmenter inference frames/s: single-image latency (batch 1) and batched throughput.

Single-image: jit(apply) on one uint8 image, median of `--single-repeats` calls, for every
`--single` config (arch:width:size). Batched: `--batch` images per call at each `--sizes` side.
Random weights (speed does not depend on their values) unless `--ckpt` names a checkpoint.
CPU-sized run: `python -m mjxrow.bench segmenter --batch 16 --repeats 3`.
"""

from __future__ import annotations

import argparse

import jax
import numpy as np

from mjxrow.bench.timing import time_call
from mjxrow.seg import checkpoint as seg_checkpoint
from mjxrow.seg import convs as seg_convs
from mjxrow.seg import model as seg_model

SINGLE = ("small:1.0:224", "small:0.75:224", "small:0.5:224", "small:1.0:192", "small:1.0:160",
          "small:1.0:128", "large:1.0:224")


def add_args(p: argparse.ArgumentParser) -> None:
    p.add_argument("--single", nargs="*", default=list(SINGLE),
                   help="arch:width:size configs timed at batch 1 (none to skip)")
    p.add_argument("--single-repeats", type=int, default=50)
    p.add_argument("--arch", default="small", help="batched throughput: architecture")
    p.add_argument("--width", type=float, default=1.0, help="batched throughput: width")
    p.add_argument("--sizes", type=int, nargs="*", default=[224, 128],
                   help="batched throughput: image sides (none to skip)")
    p.add_argument("--batch", type=int, nargs="+", default=[256])
    p.add_argument("--repeats", type=int, default=5)
    p.add_argument("--dtype", default="float32", choices=("float32", "bfloat16"))
    p.add_argument("--dw-impl", default="auto", choices=("auto",) + seg_convs.DW_IMPLS,
                   help=f"depthwise conv implementation ({seg_convs.auto_rule('depthwise')})")
    p.add_argument("--pw-impl", default="auto", choices=("auto",) + seg_convs.PW_IMPLS,
                   help=f"1x1 conv implementation ({seg_convs.auto_rule('pointwise')})")
    p.add_argument("--ckpt", help="checkpoint folder or crop to time instead of random weights")


def _model(arch: str, width: float, size: int, args) -> tuple[seg_model.SegNet, dict]:
    if args.ckpt:
        module, variables = seg_checkpoint.load(args.ckpt)
        return module.clone(dtype=args.dtype, dw_impl=args.dw_impl, pw_impl=args.pw_impl), variables
    return seg_model.create(arch, width, 0, size, dtype=args.dtype, dw_impl=args.dw_impl,
                            pw_impl=args.pw_impl)


def _config(module: seg_model.SegNet, size: int) -> str:
    dw, pw = (
        seg_convs.resolve(module.dw_impl, "depthwise"),
        seg_convs.resolve(module.pw_impl, "pointwise"),
    )
    return (f"MobileNetV3-{module.arch.capitalize()} w{module.width:g} + LR-ASPP, "
            f"{size}x{size}, {module.dtype}, dw {dw}, 1x1 {pw}")


def run(args: argparse.Namespace) -> list[dict]:
    rows = []
    rng = np.random.default_rng(0)
    for spec in args.single:
        try:
            arch, width, size = spec.split(":")
            width, size = float(width), int(size)
        except ValueError:
            msg = f"--single {spec!r}: expected arch:width:size, e.g. small:1.0:224"
            raise ValueError(msg) from None
        module, variables = _model(arch, width, size, args)
        fn = jax.jit(lambda v, x, m=module: seg_model.apply(m, v, x))
        x = jax.device_put(rng.integers(0, 256, (1, size, size, 3), dtype=np.uint8))
        t = time_call(fn, variables, x, repeats=args.single_repeats)
        rows.append({"stage": "segmenter", "config": _config(module, size) + ", single image",
                     "batch": 1, "value": 1.0 / t["median_s"], "unit": "frames/s",
                     "latency_ms": 1e3 * t["median_s"], "compile_s": t["compile_s"],
                     "params": seg_model.param_count(variables["params"])})
        print(f"{rows[-1]['config']}: {rows[-1]['value']:.1f} frames/s "
              f"(compile {t['compile_s']:.1f} s)", flush=True)
    for size in args.sizes:
        module, variables = _model(args.arch, args.width, size, args)
        fn = jax.jit(lambda v, x, m=module: seg_model.apply(m, v, x))
        for b in args.batch:
            x = jax.device_put(rng.integers(0, 256, (b, size, size, 3), dtype=np.uint8))
            t = time_call(fn, variables, x, repeats=args.repeats)
            rows.append({"stage": "segmenter", "config": _config(module, size) + ", batched",
                         "batch": b, "value": b / t["median_s"], "unit": "frames/s",
                         "compile_s": t["compile_s"], "runs_s": t["runs_s"]})
            print(f"{rows[-1]['config']} B={b}: {rows[-1]['value']:.1f} frames/s "
                  f"(compile {t['compile_s']:.1f} s)", flush=True)
    return rows
