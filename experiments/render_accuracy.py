"""How much the renderer's speed knobs lose: agreement of `render.geometry` with a reference
configuration on the dataset's camera poses.

    python experiments/render_accuracy.py [--presets ...] [--poses 16] [--res 64]
        [--views dataset along headland] [--set terrain_steps=16 ...] [--shading] [--chunk 8]

The reference tests every ray on its own (1-pixel tiles) against 64 plants (its shadow rays
against 32) and marches the terrain with 128 samples and 10 bisections; the candidate is the
default `RenderConfig` with the `--set KEY=VALUE` overrides. Per preset it prints the
plant-mask IoU, the share of pixels whose class differs, and the median and 99th-percentile
depth difference over pixels both call terrain; with --shading also the share of non-sky
pixels of the same class in both whose colour differs by more than 8 levels (mostly shadows
the candidate's shadow rays miss).

Views (`--views`): `dataset` draws the dataset's camera poses (`seg.synthesis.sample_pose`);
`along` puts the robot's camera (0.40 m high, pitched 10° down) on a lane's centre line looking
along the rows, from 1 m before the rows to their middle, both ways; `headland` puts it 2.5 m
beyond the row ends, looking along the headland and 30° and 60° into the rows. For every view
kind the table gives the pooled IoU and the minimum of the per-frame IoUs (frames whose plants
cover at least 5 % of the pixels in the reference: below that one pixel moves it by more
than 0.5 %), with the preset's worst view.
"""

from __future__ import annotations

import argparse
import dataclasses
import sys

import jax
import jax.numpy as jnp
import numpy as np

from mjxrow import crops
from mjxrow import field as F
from mjxrow import render as RD
from mjxrow.bench import render as BR
from mjxrow.physics.robot import RobotConfig

REFERENCE = RD.RenderConfig(tile=1, row_blocks=16, block_keep=64, keep=64, deep_keep=0,
                            terrain_steps=128, terrain_refine=10, shadow_row_blocks=8,
                            shadow_block_keep=32, shadow_keep=32, obstacle_keep=8)


VIEWS = ("dataset", "along", "headland")
_ROBOT = RobotConfig()  # the robot's camera: its height and pitch
CAM_HEIGHT, CAM_PITCH = _ROBOT.cam_height, np.deg2rad(_ROBOT.cam_pitch_deg)
MIN_PLANT_SHARE = 0.05  # per-frame IoU only where plants cover this share of the reference


def _view(field, x, y, yaw):
    z = F.terrain_height(field.terrain, field.terrain_size, x, y) + CAM_HEIGHT
    return jnp.stack([x, y, z]).astype(jnp.float32), RD.camera_rot(yaw, CAM_PITCH)


def _lane_views(field, key, n: int, kind: str):
    """n camera poses of one kind in `field` (see the module's doc)."""
    lanes = jnp.flatnonzero(field.lane_active, size=field.lane_active.shape[0], fill_value=0)
    n_lanes = jnp.maximum(jnp.sum(field.lane_active), 1)
    k_lane, k_x = jax.random.split(key)
    pick = lanes[jax.random.randint(k_lane, (n,), 0, n_lanes)]
    x0, x1 = field.row_x[0], field.row_x[1]
    y = field.lane_y[pick]
    i = jnp.arange(n)
    if kind == "along":
        s = jax.random.uniform(k_x, (n,))
        forward = i % 2 == 0  # from the start end looking +x, or from the far end looking -x
        depth = -1.0 + s * (0.5 * (x1 - x0) + 1.0)  # 1 m before the rows to their middle
        x = jnp.where(forward, x0 + depth, x1 - depth)
        yaw = jnp.where(forward, 0.0, jnp.pi)
    else:  # headland: along it (±90°) or into the rows at 30° / 60°
        end = i % 2 == 0
        x = jnp.where(end, x0 - 2.5, x1 + 2.5)
        into = jnp.deg2rad(jnp.array([90.0, 60.0, 30.0, -30.0, -60.0, -90.0]))[(i // 2) % 6]
        yaw = jnp.where(end, into, jnp.pi - into)
    return jax.vmap(lambda a, b, c: _view(field, a, b, c))(x, y, yaw)


def views(preset: str, n: int, kind: str, seed: int = 0):
    """(shape, fields [n], pos [n, 3], rot [n, 3, 3], conds [n]) for `n` views of `kind`."""
    shape, fields, pos, rot, conds = BR.worlds(preset, n, seed)
    if kind == "dataset":
        return shape, fields, pos, rot, conds
    per = 4  # views per field: field i // per for view i
    m = -(-n // per)
    keys = jax.random.split(jax.random.key(seed + 1), m)
    pos, rot = jax.jit(jax.vmap(lambda f, k: _lane_views(f, k, per, kind)))(
        jax.tree.map(lambda x: x[:m], fields), keys)
    fields = jax.tree.map(lambda x: x[np.arange(n) // per], fields)
    return shape, fields, pos.reshape(-1, 3)[:n], rot.reshape(-1, 3, 3)[:n], conds


def compare(preset: str, n: int, res: int, cfg: RD.RenderConfig, seed: int = 0,
            shading: bool = False, kind: str = "dataset", chunk: int = 8) -> dict:
    shape, fields, pos, rot, conds = views(preset, n, kind, seed)
    intr = RD.Intrinsics(res, res)
    chunk = min(chunk, n)

    def in_chunks(draw, *args):  # `chunk` frames per vmapped call: the reference's buffers
        # at 224 px and 32 poses would need 80 GB at once
        run = jax.jit(lambda xs: jax.lax.map(lambda x: draw(*x), xs, batch_size=chunk))
        return jax.tree.map(np.asarray, run(args))

    def geo(c):
        return in_chunks(lambda f, p, r: RD.geometry(f, shape, p, r, intr, c), fields, pos, rot)

    d_ref, c_ref = geo(REFERENCE)
    d, c = geo(cfg)
    m_ref, m = c_ref == RD.PLANT, c == RD.PLANT
    inter, union = np.sum(m & m_ref), np.sum(m | m_ref)
    fi, fu = np.sum(m & m_ref, (1, 2)), np.sum(m | m_ref, (1, 2))
    seen = np.sum(m_ref, (1, 2)) >= MIN_PLANT_SHARE * res * res
    per = np.where(seen, fi / np.maximum(fu, 1), np.inf)
    soil = (c == RD.SOIL) & (c_ref == RD.SOIL)
    err = np.abs(d - d_ref)[soil]
    out = {"iou": inter / max(union, 1), "iou_min": float(np.min(per)) if seen.any() else 1.0,
           "worst": int(np.argmin(per)), "frames": int(seen.sum()),
           "class_diff": float(np.mean(c != c_ref)),
           "depth_med": float(np.median(err)) if err.size else 0.0,
           "depth_p99": float(np.percentile(err, 99)) if err.size else 0.0}
    if shading:  # shadows and shading: pixels of the same class whose colour differs
        def rgb(c):
            return in_chunks(lambda f, p, r, k: RD.render(f, shape, p, r, intr, k, cfg=c).rgb,
                             fields, pos, rot, conds).astype(int)
        a, b = rgb(REFERENCE), rgb(cfg)
        same = (c == c_ref) & (c != RD.SKY)
        out["rgb_diff"] = float(np.mean(np.max(np.abs(a - b), -1)[same] > 8))
    return out


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--presets", nargs="+", default=list(crops.names()), choices=crops.names())
    p.add_argument("--poses", type=int, default=16)
    p.add_argument("--res", type=int, default=64)
    p.add_argument("--views", nargs="+", default=["dataset"], choices=VIEWS,
                   help="camera poses: the dataset's, along the rows in a lane, in the "
                        "headland (see above)")
    p.add_argument("--set", action="append", default=[], metavar="KEY=VALUE")
    p.add_argument("--chunk", type=int, default=8,
                   help="frames per jitted call (bounds the memory of the reference's buffers)")
    p.add_argument("--shading", action="store_true",
                   help="also render RGB (with shadows) and count same-class ground and plant "
                        "pixels whose colour differs by more than 8 levels")
    args = p.parse_args(argv)
    if args.poses < 1 or args.res < 1 or args.chunk < 1:
        p.error("--poses, --res and --chunk must be positive")
    try:
        cfg = dataclasses.replace(RD.DEFAULT_CONFIG, **BR.parse_sets(args.set))
    except ValueError as e:
        p.error(str(e))
    print(f"candidate: {' '.join(args.set) or 'defaults'}; {args.poses} poses per preset, "
          f"{args.res}x{args.res}")
    extra = " colour differs |" if args.shading else ""
    print("| preset | views | plant IoU | min per frame (frames) | class differs | "
          "depth median [m] | depth p99 [m] |" + extra)
    print("|---|---|---|---|---|---|---|" + ("---|" if args.shading else ""))
    worst = 1.0
    for preset in args.presets:
        for kind in args.views:
            r = compare(preset, args.poses, args.res, cfg, shading=args.shading, kind=kind,
                        chunk=args.chunk)
            worst = min(worst, r["iou_min"])
            print(f"| {preset} | {kind} | {r['iou']:.4f} | {r['iou_min']:.4f} ({r['frames']}) | "
                  f"{r['class_diff']:.4%} | {r['depth_med']:.4f} | {r['depth_p99']:.4f} |"
                  + (f" {r['rgb_diff']:.4%} |" if args.shading else ""), flush=True)
    print(f"\nminimum per-frame plant IoU over every preset and view: {worst:.4f}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
