"""How much the renderer's speed knobs lose: agreement of `render.geometry` with a reference
configuration on the dataset's camera poses.

    python experiments/render_accuracy.py [--presets ...] [--poses 16] [--res 64]
        [--set terrain_steps=16 --set deep_keep=24 ...] [--shading]

The reference tests every ray on its own (1-pixel tiles) against 64 plants (its shadow rays
against 32) and marches the terrain with 128 samples and 10 bisections; the candidate is the
default `RenderConfig` with the `--set KEY=VALUE` overrides. Per preset it prints the
plant-mask IoU, the share of pixels whose class differs, and the median and 99th-percentile
depth difference over pixels both call terrain; with --shading also the share of non-sky
pixels of the same class in both whose colour differs by more than 8 levels (mostly shadows
the candidate's shadow rays miss).
"""

from __future__ import annotations

import argparse
import dataclasses
import sys

import jax
import numpy as np

from mjxrow import crops
from mjxrow import render as RD
from mjxrow.bench import render as BR

REFERENCE = RD.RenderConfig(tile=1, row_blocks=16, block_keep=64, keep=64, deep_keep=0,
                            terrain_steps=128, terrain_refine=10, shadow_row_blocks=8,
                            shadow_block_keep=32, shadow_keep=32, obstacle_keep=8)


def compare(preset: str, n: int, res: int, cfg: RD.RenderConfig, seed: int = 0,
            shading: bool = False) -> dict:
    shape, fields, pos, rot, conds = BR.worlds(preset, n, seed)
    intr = RD.Intrinsics(res, res)

    def geo(c):
        return jax.jit(jax.vmap(lambda f, p, r: RD.geometry(f, shape, p, r, intr, c)))

    d_ref, c_ref = map(np.asarray, geo(REFERENCE)(fields, pos, rot))
    d, c = map(np.asarray, geo(cfg)(fields, pos, rot))
    m_ref, m = c_ref == RD.PLANT, c == RD.PLANT
    inter, union = np.sum(m & m_ref), np.sum(m | m_ref)
    soil = (c == RD.SOIL) & (c_ref == RD.SOIL)
    err = np.abs(d - d_ref)[soil]
    out = {"iou": inter / max(union, 1), "class_diff": float(np.mean(c != c_ref)),
           "depth_med": float(np.median(err)) if err.size else 0.0,
           "depth_p99": float(np.percentile(err, 99)) if err.size else 0.0}
    if shading:  # shadows and shading: pixels of the same class whose colour differs
        def rgb(c):
            return jax.jit(jax.vmap(lambda f, p, r, k: RD.render(f, shape, p, r, intr, k,
                                                                 cfg=c).rgb))
        a = np.asarray(rgb(REFERENCE)(fields, pos, rot, conds), int)
        b = np.asarray(rgb(cfg)(fields, pos, rot, conds), int)
        same = (c == c_ref) & (c != RD.SKY)
        out["rgb_diff"] = float(np.mean(np.max(np.abs(a - b), -1)[same] > 8))
    return out


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--presets", nargs="+", default=list(crops.names()), choices=crops.names())
    p.add_argument("--poses", type=int, default=16)
    p.add_argument("--res", type=int, default=64)
    p.add_argument("--set", action="append", default=[], metavar="KEY=VALUE")
    p.add_argument("--shading", action="store_true",
                   help="also render RGB (with shadows) and count same-class ground and plant "
                        "pixels whose colour differs by more than 8 levels")
    args = p.parse_args(argv)
    if args.poses < 1 or args.res < 1:
        p.error("--poses and --res must be positive")
    try:
        cfg = dataclasses.replace(RD.DEFAULT_CONFIG, **BR.parse_sets(args.set))
    except ValueError as e:
        p.error(str(e))
    print(f"candidate: {' '.join(args.set) or 'defaults'}; {args.poses} poses per preset, "
          f"{args.res}x{args.res}")
    extra = " colour differs |" if args.shading else ""
    print("| preset | plant IoU | class differs | depth median [m] | depth p99 [m] |" + extra)
    print("|---|---|---|---|---|" + ("---|" if args.shading else ""))
    for preset in args.presets:
        r = compare(preset, args.poses, args.res, cfg, shading=args.shading)
        print(f"| {preset} | {r['iou']:.4f} | {r['class_diff']:.4%} | {r['depth_med']:.4f} | "
              f"{r['depth_p99']:.4f} |" + (f" {r['rgb_diff']:.4%} |" if args.shading else ""),
              flush=True)
    return 0


if __name__ == "__main__":
    sys.exit(main())
