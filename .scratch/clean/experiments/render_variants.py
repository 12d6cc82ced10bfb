"""Renderer configurations side by side in one process: compile every (variant, resolution) in
threads, then time them in interleaved rounds, so that no other process's compilation or
autotuning shares the GPU with a timed call.

    python experiments/render_variants.py [--preset zucchini] [--batch 1024] [--res 64 224]
        [--variants "" settle=barrier "settle=barrier,tile=8"] [--rounds 5] [--chunk 0]
        [--out FILE.jsonl]

A variant is a comma-separated list of RenderConfig fields (`bench render --set`'s KEY=VALUE);
"" is the defaults. The worlds are `bench render`'s (the dataset's fields, poses, conditions).
For each variant and resolution: median ms per call over the rounds, frames/s, compile s, and
against the first variant the largest RGB difference (8-bit levels), the share of RGB values
that differ, the share of pixels whose class differs and the plant-mask IoU. Prints a table
per resolution and appends one `render` row per variant and resolution to `--out` (default
benchmarks.jsonl).
"""

from __future__ import annotations

import argparse
import concurrent.futures
import dataclasses
import functools
import statistics
import sys
import time
from pathlib import Path

import jax
import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))  # run from a checkout
from mjxrow import crops  # noqa: E402
from mjxrow import render as RD  # noqa: E402
from mjxrow.bench import render as BR  # noqa: E402
from mjxrow.bench import timing as bench  # noqa: E402


def parse(spec: str) -> RD.RenderConfig:
    items = [s for s in spec.split(",") if s.strip()]
    try:
        return dataclasses.replace(RD.RenderConfig(), **BR.parse_sets(items))
    except (ValueError, TypeError) as e:
        raise SystemExit(f"--variants {spec!r}: {e}") from None


def main(argv: list[str] | None = None) -> None:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--preset", default="zucchini", choices=crops.names())
    p.add_argument("--batch", type=int, default=1024)
    p.add_argument("--res", type=int, nargs="+", default=[64, 224])
    p.add_argument("--variants", nargs="+", default=["", "settle=barrier"], metavar="K=V,...")
    p.add_argument("--rounds", type=int, default=5)
    p.add_argument("--chunk", type=int, default=0,
                   help="frames per vmapped chunk (0: `bench render`'s automatic size)")
    p.add_argument("--threads", type=int, default=4, help="compiles at once")
    p.add_argument("--out", default="benchmarks.jsonl")
    args = p.parse_args(argv)
    variants = [(v, parse(v)) for v in args.variants]
    shape, fields, pos, rot, conds = BR.worlds(args.preset, args.batch)
    inputs = (fields, pos, rot, conds)
    jobs = [(name, cfg, res) for res in args.res for name, cfg in variants]

    def compile_one(job):
        name, cfg, res = job
        intr = RD.Intrinsics(res, res)
        chunk = BR.auto_chunk(res, args.batch, args.chunk)
        fn = BR.batched_render(shape, intr, cfg, args.batch, chunk)
        t0 = time.perf_counter()
        exe = fn.lower(*inputs).compile()
        return exe, time.perf_counter() - t0

    with concurrent.futures.ThreadPoolExecutor(args.threads) as pool:
        compiled = dict(zip(jobs, pool.map(compile_one, jobs), strict=True))
    frames = {}
    for job, (exe, secs) in compiled.items():
        frames[job] = jax.tree.map(np.asarray, jax.block_until_ready(exe(*inputs)))
        print(f"{job[0] or 'defaults'} at {job[2]} px: compiled in {secs:.1f} s", flush=True)
    times = bench.time_interleaved(
        {job: functools.partial(compiled[job][0], *inputs) for job in jobs}, args.rounds)
    rows = []
    for res in args.res:
        ref = frames[(variants[0][0], variants[0][1], res)]
        print(f"\n{args.preset} renderer, {res} x {res}, B = {args.batch}, {bench.device_name()}"
              f"\n| variant | median ms | frames/s | compile s | max RGB diff | RGB values "
              f"differing | class pixels differing | plant-mask IoU |\n"
              f"|---|---|---|---|---|---|---|---|")
        for name, cfg in variants:
            job = (name, cfg, res)
            med = statistics.median(times[job])
            diff = np.abs(frames[job].rgb.astype(int) - ref.rgb.astype(int))
            cls_diff = float(np.mean(frames[job].classes != ref.classes))
            m, r = frames[job].mask, ref.mask
            iou = float(np.sum(m & r) / max(1, np.sum(m | r)))
            print(f"| {name or 'defaults'} | {1e3 * med:.2f} | {args.batch / med:,.0f} | "
                  f"{compiled[job][1]:.1f} | {diff.max()} | {100 * np.mean(diff > 0):.4f} % | "
                  f"{100 * cls_diff:.4f} % | {iou:.5f} |")
            used = RD.resolve(cfg, shape.crop, RD.Intrinsics(res, res))
            rows.append({"stage": "render", "batch": args.batch, "value": args.batch / med,
                         "unit": "frames/s", "compile_s": compiled[job][1],
                         "runs_s": times[job],
                         "config": f"{args.preset} {res}x{res}, tile {used.tile}, {used.kernel} "
                                   f"kernels, settle {used.settle}"
                                   f"{', ' + name if name else ''}, interleaved "
                                   f"(render_variants.py)",
                         "max_rgb_diff": int(diff.max()), "class_differ": cls_diff,
                         "mask_iou_vs_first": iou})
    bench.record(rows, args.out, command="python experiments/render_variants.py " + " ".join(
        argv if argv is not None else sys.argv[1:]))


if __name__ == "__main__":
    main()
