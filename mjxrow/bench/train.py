"""Segmenter training steps/s: the jitted AdamW + IoU-loss step (with flip / greyscale
augmentation) on a fixed random batch, or with `--on-the-fly` the step that renders its batch.

Each timed call chains `--steps` steps; the value is steps / median call time. CPU-sized run:
`python -m mjxrow.bench train --arch tiny --size 64 --batch 8 --steps 5 --repeats 3`.
"""

from __future__ import annotations

import argparse

import jax
import numpy as np

from mjxrow import crops
from mjxrow.bench.timing import time_call
from mjxrow.seg import convs as seg_convs
from mjxrow.seg import model as seg_model
from mjxrow.seg import step as seg_step
from mjxrow.seg.data import onthefly


def add_args(p: argparse.ArgumentParser) -> None:
    p.add_argument("--arch", default="small", choices=seg_model.ARCHS)
    p.add_argument("--width", type=float, default=1.0)
    p.add_argument("--size", type=int, nargs="+", default=[224])
    p.add_argument("--batch", type=int, nargs="+", default=[64])
    p.add_argument("--steps", type=int, default=20, help="steps chained in one timed call")
    p.add_argument("--repeats", type=int, default=5)
    p.add_argument("--loss", default="iou", choices=tuple(seg_step.LOSSES))
    p.add_argument("--dtype", default="float32", choices=("float32", "bfloat16"))
    p.add_argument("--dw-impl", default="auto", choices=("auto",) + seg_convs.DW_IMPLS,
                   help=f"depthwise conv implementation ({seg_convs.auto_rule('depthwise')})")
    p.add_argument("--pw-impl", default="auto", choices=("auto",) + seg_convs.PW_IMPLS,
                   help=f"1x1 conv implementation ({seg_convs.auto_rule('pointwise')})")
    p.add_argument("--on-the-fly", action="store_true", help="render each batch in the step")
    p.add_argument("--crop", default="zucchini", choices=(*crops.names(), "all"))


def run(args: argparse.Namespace) -> list[dict]:
    rows = []
    rng = np.random.default_rng(0)
    for size in args.size:
        module, variables = seg_model.create(args.arch, args.width, 0, size, dtype=args.dtype,
                                             dw_impl=args.dw_impl, pw_impl=args.pw_impl)
        tx = seg_step.make_optimizer(seg_step.make_schedule(1e-3, 10_000, 100))
        for b in args.batch:
            state = seg_step.init_state(variables, tx)
            if args.on_the_fly:
                step = jax.jit(seg_step.make_step(module, tx, args.loss,
                                                   batch_fn=onthefly(args.crop, size, b)))
                batch = ()
                src = f"rendered {args.crop}"
            else:
                step = jax.jit(seg_step.make_step(module, tx, args.loss))
                batch = (jax.device_put(rng.integers(0, 256, (b, size, size, 3), np.uint8)),
                         jax.device_put(rng.random((b, size, size)) < 0.3))
                src = "fixed batch"

            def chain(state, *batch, step=step):
                for _ in range(args.steps):
                    state, m = step(state, *batch)
                return m["loss"]

            t = time_call(chain, state, *batch, repeats=args.repeats)
            rate = args.steps / t["median_s"]
            rows.append({"stage": "train",
                         "config": f"MobileNetV3-{args.arch.capitalize()} w{args.width:g} + "
                                   f"LR-ASPP, {size}x{size}, {args.dtype}, {args.loss} loss, "
                                   f"AdamW, flip+grey aug, {src}",
                         "batch": b, "value": rate, "unit": "steps/s",
                         "images_per_s": rate * b,
                         "compile_s": max(t["compile_s"] - t["median_s"], 0.0),
                         "runs_s": t["runs_s"]})
            print(f"{rows[-1]['config']} B={b}: {rate:.2f} steps/s ({rate * b:.0f} images/s, "
                  f"compile {rows[-1]['compile_s']:.1f} s)", flush=True)
    return rows
