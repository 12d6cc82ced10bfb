"""The segmenter's implementations side by side in one process: compile each, then time them in
interleaved rounds, so that no other process's compilation or autotuning shares the GPU with a
timed call.

    python experiments/seg_variants.py [--ckpt zucchini] [--size 224] [--batch 1024]
        [--variants float32:conv:conv float32:phases:dot ...] [--rounds 5] [--out FILE.jsonl]

A variant is DTYPE:DW:PW (compute dtype; depthwise implementation, `seg.convs.DW_IMPLS`; 1×1
implementation, `seg.convs.PW_IMPLS`). Inputs are renders of the shipped checkpoint's crop
(`seg.evaluation`'s fixed set, seed 20,000, cycled up to the batch), so the masks can be
compared: for each variant the largest logit difference and the share of pixels whose mask
(threshold 0.7) differs from the first variant's. Prints a table (median ms per call over the
rounds, frames/s, compile s) and appends one `segmenter` row per variant to `--out` (default
benchmarks.jsonl).
"""

from __future__ import annotations

import argparse
import functools
import statistics
import sys
import time
from pathlib import Path

import jax
import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))  # run from a checkout
from mjxrow.bench import closed_loop as CL  # noqa: E402
from mjxrow.bench import timing as bench  # noqa: E402
from mjxrow.seg import checkpoint as ckpt  # noqa: E402
from mjxrow.seg import data as D  # noqa: E402
from mjxrow.seg import model as M  # noqa: E402

LOGIT_07 = float(np.log(0.7 / 0.3))  # sigmoid(logit) > 0.7
DEFAULT = ("float32:conv:conv", "float32:conv:dot", "float32:mixed:dot", "float32:phases:dot",
           "float32:shift:dot", "bfloat16:phases:dot", "bfloat16:mixed:dot")


def parse(spec: str) -> dict[str, str]:
    dtype, _, impls = spec.partition(":")
    try:
        if dtype not in ("float32", "bfloat16"):
            raise ValueError(f"DTYPE {dtype!r} is not float32 or bfloat16")
        return {"dtype": dtype, **CL.seg_impl(impls)}
    except ValueError as e:
        raise SystemExit(f"--variants {spec!r}: expected DTYPE:DW:PW ({e})") from None


UNIQUE = 64  # distinct renders; the batch repeats them


def renders(crop: str, n: int, size: int) -> tuple[np.ndarray, np.ndarray]:
    """RGB uint8 [n, size, size, 3] of `crop` (`seg.evaluation`'s fixed renders, seed 20,000, the
    first UNIQUE cycled) and the true plant masks of the first UNIQUE."""
    rgb, mask, _ = D.fixed_set(D.onthefly(crop, size, UNIQUE), 1, 20_000)[0]
    rgb = np.asarray(rgb)
    return np.resize(rgb, (n,) + rgb.shape[1:]), np.asarray(mask, bool)


def main(argv: list[str] | None = None) -> None:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--ckpt", default="zucchini", help="checkpoint folder or crop")
    p.add_argument("--size", type=int, default=224)
    p.add_argument("--batch", type=int, default=1024)
    p.add_argument("--variants", nargs="+", default=list(DEFAULT), metavar="DTYPE:DW:PW")
    p.add_argument("--rounds", type=int, default=5)
    p.add_argument("--out", default="benchmarks.jsonl")
    args = p.parse_args(argv)
    specs = [(v, parse(v)) for v in args.variants]
    module, variables = ckpt.load(args.ckpt)
    rgb, truth = renders(module_crop(args.ckpt), args.batch, args.size)
    x = jax.device_put(rgb)
    fns, compile_s, logits = {}, {}, {}
    for name, change in specs:
        variant = module.clone(**change)
        fn = jax.jit(lambda v, x, m=variant: M.apply(m, v, x))
        t0 = time.perf_counter()
        exe = fn.lower(variables, x).compile()
        compile_s[name] = time.perf_counter() - t0
        logits[name] = np.asarray(jax.block_until_ready(exe(variables, x)))
        fns[name] = exe
        print(f"{name}: compiled in {compile_s[name]:.1f} s", flush=True)
    times = bench.time_interleaved(
        {name: functools.partial(fns[name], variables, x) for name, _ in specs}, args.rounds)
    n = min(UNIQUE, args.batch)
    truth = truth[:n]
    ref = logits[specs[0][0]][:n]
    ref_mask = ref > LOGIT_07
    rows = []
    print(f"\n{args.ckpt} segmenter, {args.size} x {args.size}, B = {args.batch}, "
          f"{bench.device_name()}\n| variant | median ms | frames/s | compile s | max |Δlogit| "
          f"| mask pixels differing | IoU vs true masks |\n|---|---|---|---|---|---|---|")
    for name, change in specs:
        med = statistics.median(times[name])
        mask = logits[name][:n] > LOGIT_07
        differ = float(np.mean(mask != ref_mask))
        dmax = float(np.max(np.abs(logits[name][:n] - ref)))
        iou = float(np.sum(mask & truth) / max(1, np.sum(mask | truth)))
        print(f"| {name} | {1e3 * med:.2f} | {args.batch / med:,.0f} | {compile_s[name]:.1f} | "
              f"{dmax:.2e} | {100 * differ:.4f} % | {iou:.4f} |")
        rows.append({"stage": "segmenter", "batch": args.batch, "value": args.batch / med,
                     "unit": "frames/s", "compile_s": compile_s[name], "runs_s": times[name],
                     "config": f"MobileNetV3-Small + LR-ASPP ({args.ckpt}), {args.size}x"
                               f"{args.size}, {change['dtype']}, dw {change['dw_impl']}, 1x1 "
                               f"{change['pw_impl']}, interleaved (seg_variants.py)",
                     "max_logit_diff": dmax, "mask_differ": differ, "iou": iou})
    bench.record(rows, args.out, command="python experiments/seg_variants.py " + " ".join(
        argv if argv is not None else sys.argv[1:]))


def module_crop(spec: str) -> str:
    """The crop whose renders feed a checkpoint: its name, or the folder's config crop."""
    from mjxrow import crops

    if spec in crops.names():
        return spec
    crop = ckpt.read_config(spec).get("crop", "zucchini")
    return crop if crop in crops.names() else "zucchini"


if __name__ == "__main__":
    main()
