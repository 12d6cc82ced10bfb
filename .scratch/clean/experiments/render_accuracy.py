"""How much the renderer's speed knobs lose: agreement of `render.geometry` with a reference
configuration on the dataset's camera poses.

    python experiments/render_accuracy.py [--presets ...] [--poses 16] [--res 64]
        [--views dataset along headland] [--set terrain_steps=16 ...] [--shading] [--chunk 8]
        [--fields straight arc sine] [--fps] [--fps-batch 64] [--repeats 5]

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
than 0.5 %), with the preset's worst view. On curved rows the along and headland views follow
the lane (`mjxrow.field.lanes`: its centre line and heading).

Fields (`--fields`): without the flag the dataset's own fields (`bench.render.worlds`). With
it, the dataset's geometry without its variety (`seg.synthesis.random_params(variety="none")`)
and rows of each named kind: `straight`; `arc`, concentric arcs of curvature 0.03 / m; `sine`,
a sinusoid of amplitude 0.5 m and wavelength 10 m; the curved ones also with weeds (0.5 per
m²) and gap runs (one per 10 m). All kinds of a preset share one static shape (their weed
slots included), so the candidate and the reference compile once per preset for every kind and
view. `--fps` then also times the renderer (`--res` pixels, the `along` views, `--fps-batch`
frames per call, `--repeats` interleaved rounds, one compiled program for every kind) and, for
reference, the straight fields in the same shape without weed slots. A short table comes last:
per preset and kind of rows, the minimum per-frame IoU of each view kind and (with --fps) the
frames/s and their change against straight rows in the same program.
"""

from __future__ import annotations

import argparse
import dataclasses
import functools
import sys

import jax
import jax.numpy as jnp
import numpy as np

from mjxrow import crops
from mjxrow import field as F
from mjxrow import render as RD
from mjxrow.bench import render as BR
from mjxrow.bench import timing
from mjxrow.field import lanes as field_lanes
from mjxrow.physics.robot import RobotConfig
from mjxrow.seg import synthesis as seg_synth

REFERENCE = RD.RenderConfig(tile=1, row_blocks=16, block_keep=64, keep=64, deep_keep=0,
                            terrain_steps=128, terrain_refine=10, shadow_row_blocks=8,
                            shadow_block_keep=32, shadow_keep=32, obstacle_keep=8, weeds=256,
                            weed_keep=16)


VIEWS = ("dataset", "along", "headland")
FIELDS = ("straight", "arc", "sine")
# each kind of rows in metres (turned into the params' units by the preset's scale); every kind
# sets every key, so that one traced draw serves them all
_BENDS = {"straight": dict(row_curvature=0.0, row_amplitude=0.0, row_wavelength=10.0,
                           weed_density=0.0, gap_rate=0.0),
          "arc": dict(row_curvature=0.03, row_amplitude=0.0, row_wavelength=10.0,
                      weed_density=0.5, gap_rate=1.0),
          "sine": dict(row_curvature=0.0, row_amplitude=0.5, row_wavelength=10.0,
                       weed_density=0.5, gap_rate=1.0)}
_ROBOT = RobotConfig()  # the robot's camera: its height and pitch
CAM_HEIGHT, CAM_PITCH = _ROBOT.cam_height, np.deg2rad(_ROBOT.cam_pitch_deg)
MIN_PLANT_SHARE = 0.05  # per-frame IoU only where plants cover this share of the reference
PER_FIELD = 4  # lane views per field: view i in field i // PER_FIELD


def _view(field, x, y, yaw):
    z = F.terrain_height(field.terrain, field.terrain_size, x, y) + CAM_HEIGHT
    return jnp.stack([x, y, z]).astype(jnp.float32), RD.camera_rot(yaw, CAM_PITCH)


def _lane_views(field, key, n: int, kind: str):
    """n camera poses of one kind in `field` (see the module's doc), in field coordinates
    (s along the rows, u across) put into the world by the field's bend: the same poses as
    x = s, y = u, yaw along ±x on straight rows."""
    lanes = jnp.flatnonzero(field.lane_active, size=field.lane_active.shape[0], fill_value=0)
    n_lanes = jnp.maximum(jnp.sum(field.lane_active), 1)
    k_lane, k_x = jax.random.split(key)
    pick = lanes[jax.random.randint(k_lane, (n,), 0, n_lanes)]
    x0, x1 = field.row_x[0], field.row_x[1]
    u = field.lane_y[pick]
    i = jnp.arange(n)
    if kind == "along":
        r = jax.random.uniform(k_x, (n,))
        forward = i % 2 == 0  # from the start end looking +s, or from the far end looking -s
        depth = -1.0 + r * (0.5 * (x1 - x0) + 1.0)  # 1 m before the rows to their middle
        s = jnp.where(forward, x0 + depth, x1 - depth)
        turn = jnp.where(forward, 0.0, jnp.pi)
    else:  # headland: along it (±90°) or into the rows at 30° / 60°
        end = i % 2 == 0
        s = jnp.where(end, x0 - 2.5, x1 + 2.5)
        into = jnp.deg2rad(jnp.array([90.0, 60.0, 30.0, -30.0, -60.0, -90.0]))[(i // 2) % 6]
        turn = jnp.where(end, into, jnp.pi - into)
    bend = field_lanes.field_bend(field)
    x, y = field_lanes.to_world(bend, s, u)
    yaw = field_lanes.heading(bend, s, u) + turn
    return jax.vmap(lambda a, b, c: _view(field, a, b, c))(x, y, yaw)


@functools.cache
def _poser(kind: str):
    """jit of the lane views of `kind` over [m] fields (one compile per field shape)."""
    return jax.jit(jax.vmap(lambda f, k: _lane_views(f, k, PER_FIELD, kind)))


@functools.cache
def _drawer(preset: str):
    """jit of the params of fields of the dataset's geometry without its variety, with the
    rows, gaps and weeds of `bend` (a dict of _BENDS' keys, in metres): key [n] → params [n]."""
    def one(k, bend):
        base = seg_synth.random_params(preset, k, variety="none")
        s = base.scale
        return base.replace(row_curvature=bend["row_curvature"] * s,
                            row_amplitude=bend["row_amplitude"] / s,
                            row_wavelength=bend["row_wavelength"] / s,
                            weed_density=bend["weed_density"], gap_rate=bend["gap_rate"])
    return jax.jit(jax.vmap(one, in_axes=(0, None)))


@functools.cache
def _generator(shape: F.FieldShape):
    return jax.jit(jax.vmap(lambda p, k: F.generate(p, shape, k)))


def _union(shapes: list[F.FieldShape]) -> F.FieldShape:
    """The smallest shape holding every one of `shapes` (one crop)."""
    return dataclasses.replace(
        shapes[0], max_rows=max(s.max_rows for s in shapes),
        max_plants_per_row=max(s.max_plants_per_row for s in shapes),
        terrain_cells=tuple(max(s.terrain_cells[i] for s in shapes) for i in range(2)),
        obstacle_slots=max(s.obstacle_slots for s in shapes),
        weed_slots=max(s.weed_slots for s in shapes))


def field_sets(preset: str, n: int, kinds: list[str], seed: int = 0, weeds: bool = True):
    """(shape, {kind: fields [n]}, conds [n]): the dataset's geometry of `n` fields, each
    kind's rows (module doc) on the same draws, one shape holding all (with weeds=False, its
    weed slots 0 and no kind's weeds)."""
    keys = jax.random.split(jax.random.key(seed), n)
    params = {}
    for kind in kinds:
        bend = {k: jnp.float32(0.0 if k == "weed_density" and not weeds else v)
                for k, v in _BENDS[kind].items()}
        params[kind] = jax.tree.map(np.asarray, _drawer(preset)(keys, bend))
    shape = _union([F.fit_shape(p, preset) for p in params.values()])
    if not weeds:
        shape = dataclasses.replace(shape, weed_slots=0)
    for kind, p in params.items():
        try:
            F.validate(p, shape)
        except ValueError as e:
            raise ValueError(f"{preset}, {kind} rows: {e}") from None
    gen = _generator(shape)
    fields = {kind: gen(p, jax.random.split(jax.random.key(seed + 1), n))
              for kind, p in params.items()}
    conds = jax.vmap(RD.condition_by_index)(jnp.arange(n) % len(RD.CONDITIONS), keys)
    return shape, fields, conds


def _posed(fields, n: int, kind: str, seed: int):
    """(fields [n], pos [n, 3], rot [n, 3, 3]): views of `kind` in `fields` [n], PER_FIELD
    per field (module doc)."""
    m = -(-n // PER_FIELD)
    keys = jax.random.split(jax.random.key(seed + 1), m)
    pos, rot = _poser(kind)(jax.tree.map(lambda x: x[:m], fields), keys)
    fields = jax.tree.map(lambda x: x[np.arange(n) // PER_FIELD], fields)
    return fields, pos.reshape(-1, 3)[:n], rot.reshape(-1, 3, 3)[:n]


def views(preset: str, n: int, kind: str, seed: int = 0, fields: str | None = None):
    """(shape, fields [n], pos [n, 3], rot [n, 3, 3], conds [n]) for `n` views of `kind`, in
    the dataset's fields, or (`fields`: one of FIELDS) in fields of that kind of rows."""
    if fields is not None:
        if kind == "dataset":
            raise ValueError("views: the dataset's poses go with the dataset's fields")
        shape, sets, conds = field_sets(preset, n, [fields], seed)
        return (shape, *_posed(sets[fields], n, kind, seed), conds)
    shape, fields_, pos, rot, conds = BR.worlds(preset, n, seed)
    if kind == "dataset":
        return shape, fields_, pos, rot, conds
    return (shape, *_posed(fields_, n, kind, seed), conds)


@functools.cache
def _chunked(shape: F.FieldShape, intr: RD.Intrinsics, cfg: RD.RenderConfig, chunk: int,
             rgb: bool):
    """jit of `geometry` (rgb: `render`'s colours) over frames, `chunk` per vmapped call (the
    reference's buffers at 224 px and 32 poses would need 80 GB at once); one compile per
    shape, image, configuration and frame count, shared by every kind of rows and view."""
    def one(x):
        if rgb:
            return RD.render(x[0], shape, x[1], x[2], intr, x[3], cfg=cfg).rgb
        return RD.geometry(x[0], shape, x[1], x[2], intr, cfg)
    return jax.jit(lambda xs: jax.lax.map(one, xs, batch_size=chunk))


def agreement(shape, fields, pos, rot, conds, res: int, cfg: RD.RenderConfig,
              shading: bool = False, chunk: int = 8) -> dict:
    """The candidate `cfg` against REFERENCE on the given frames (module doc)."""
    intr = RD.Intrinsics(res, res)
    chunk = min(chunk, pos.shape[0])

    def geo(c):
        return jax.tree.map(np.asarray, _chunked(shape, intr, c, chunk, False)(
            (fields, pos, rot)))

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
            return np.asarray(_chunked(shape, intr, c, chunk, True)(
                (fields, pos, rot, conds))).astype(int)
        a, b = rgb(REFERENCE), rgb(cfg)
        same = (c == c_ref) & (c != RD.SKY)
        out["rgb_diff"] = float(np.mean(np.max(np.abs(a - b), -1)[same] > 8))
    return out


def compare(preset: str, n: int, res: int, cfg: RD.RenderConfig, seed: int = 0,
            shading: bool = False, kind: str = "dataset", chunk: int = 8,
            fields: str | None = None) -> dict:
    """`agreement` on `n` views of `kind` (in fields of the kind of rows `fields`)."""
    return agreement(*views(preset, n, kind, seed, fields), res, cfg, shading, chunk)


def frames_per_second(preset: str, n: int, res: int, cfg: RD.RenderConfig, kinds: list[str],
                      seed: int = 0, repeats: int = 5) -> dict[str, float]:
    """Frames/s of one jit(vmap(render)) call over `n` along-row views (res × res pixels), for
    the fields of each of `kinds` in one shape (one compiled program), and ("straight, no weed
    slots") the straight fields in that shape without weed slots; all timed in the same
    interleaved rounds."""
    intr = RD.Intrinsics(res, res)
    calls = {}
    for weeds in (True, False):
        shape, sets, conds = field_sets(preset, n, kinds, seed, weeds=weeds)
        fn = BR.batched_render(shape, intr, cfg, n, BR.auto_chunk(res, n))
        for name, fields in sets.items() if weeds else [("straight", sets["straight"])]:
            args = (*_posed(fields, n, "along", seed), conds)
            jax.block_until_ready(fn(*args))  # compiles once per shape
            calls[name if weeds else "straight, no weed slots"] = (
                lambda args=args, fn=fn: fn(*args))
    times = timing.time_interleaved(calls, repeats)
    return {name: n / float(np.median(t)) for name, t in times.items()}


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--presets", nargs="+", default=list(crops.names()), choices=crops.names())
    p.add_argument("--poses", type=int, default=16)
    p.add_argument("--res", type=int, default=64)
    p.add_argument("--views", nargs="+", choices=VIEWS,
                   help="camera poses: the dataset's, along the rows in a lane, in the "
                        "headland (see above; default: dataset, with --fields along headland)")
    p.add_argument("--fields", nargs="+", choices=FIELDS,
                   help="fields of these kinds of rows instead of the dataset's (see above; "
                        "with the along and headland views)")
    p.add_argument("--fps", action="store_true",
                   help="with --fields: also time the renderer on those kinds and on straight "
                        "rows")
    p.add_argument("--fps-batch", type=int, default=64, help="frames per timed call")
    p.add_argument("--repeats", type=int, default=5, help="timed rounds of every kind")
    p.add_argument("--set", action="append", default=[], metavar="KEY=VALUE")
    p.add_argument("--chunk", type=int, default=8,
                   help="frames per jitted call (bounds the memory of the reference's buffers)")
    p.add_argument("--shading", action="store_true",
                   help="also render RGB (with shadows) and count same-class ground and plant "
                        "pixels whose colour differs by more than 8 levels")
    args = p.parse_args(argv)
    if min(args.poses, args.res, args.chunk, args.fps_batch, args.repeats) < 1:
        p.error("--poses, --res, --chunk, --fps-batch and --repeats must be positive")
    args.views = args.views or (["along", "headland"] if args.fields else ["dataset"])
    if args.fields and "dataset" in args.views:
        p.error("--fields: the dataset's views go with the dataset's fields; use --views along "
                "headland")
    if args.fps and not args.fields:
        p.error("--fps: needs --fields (the kinds of rows to time)")
    try:
        cfg = dataclasses.replace(RD.DEFAULT_CONFIG, **BR.parse_sets(args.set))
    except ValueError as e:
        p.error(str(e))
    fields_kinds = list(dict.fromkeys(args.fields or []))
    print(f"candidate: {' '.join(args.set) or 'defaults'}; {args.poses} poses per preset, "
          f"{args.res}x{args.res}")
    extra = " colour differs |" if args.shading else ""
    print("| preset | views | plant IoU | min per frame (frames) | class differs | "
          "depth median [m] | depth p99 [m] |" + extra)
    print("|---|---|---|---|---|---|---|" + ("---|" if args.shading else ""))
    worst = 1.0
    mins: dict[tuple[str, str, str], str] = {}  # the short table's cells
    for preset in args.presets:
        if fields_kinds:  # every kind of rows in one shape: one compile per configuration
            shape, sets, conds = field_sets(preset, args.poses, fields_kinds)
            frames = {(f, v): (shape, *_posed(sets[f], args.poses, v, 0), conds)
                      for f in fields_kinds for v in args.views}
        else:
            frames = {(None, v): views(preset, args.poses, v) for v in args.views}
        for (fields, kind), fr in frames.items():
            r = agreement(*fr, args.res, cfg, shading=args.shading, chunk=args.chunk)
            worst = min(worst, r["iou_min"])
            mins[preset, fields, kind] = f"{r['iou_min']:.4f}" if r["frames"] else "no frame"
            label = kind if fields is None else f"{kind}, {fields} rows"
            print(f"| {preset} | {label} | {r['iou']:.4f} | {r['iou_min']:.4f} "
                  f"({r['frames']}) | {r['class_diff']:.4%} | {r['depth_med']:.4f} | "
                  f"{r['depth_p99']:.4f} |" + (f" {r['rgb_diff']:.4%} |" if args.shading
                                               else ""), flush=True)
    print(f"\nminimum per-frame plant IoU over every preset and view: {worst:.4f}")
    if not fields_kinds:
        return 0
    fps = {}
    if args.fps:
        kinds = ["straight"] + [k for k in fields_kinds if k != "straight"]
        for preset in args.presets:
            fps[preset] = frames_per_second(preset, args.fps_batch, args.res, cfg, kinds,
                                            repeats=args.repeats)
            print(f"{preset}: " + ", ".join(f"{k} {v:,.1f}" for k, v in fps[preset].items())
                  + f" frames/s ({args.fps_batch} per call, {timing.device_name()})", flush=True)
    # the short table: minimum per-frame IoU per view kind and kind of rows ("no frame": none
    # whose plants cover MIN_PLANT_SHARE of the reference), frames/s
    cols = list(args.views)
    print("\n| preset | rows | " + " | ".join(f"min IoU {v}" for v in cols)
          + (f" | frames/s at {args.res} px | vs straight |" if fps else " |"))
    print("|---|---|" + "---|" * len(cols) + ("---|---|" if fps else ""))
    for preset in args.presets:
        f = fps.get(preset, {})
        for fields in dict.fromkeys(fields_kinds + list(f)):
            cell = [mins.get((preset, fields, v), "") for v in cols]
            line = f"| {preset} | {fields} | " + " | ".join(cell) + " |"
            if fps:
                rate = f"{f[fields]:,.1f}" if fields in f else ""
                rel = f"{f[fields] / f['straight'] - 1.0:+.1%}" if fields in f else ""
                line += f" {rate} | {rel} |"
            print(line)
    return 0


if __name__ == "__main__":
    sys.exit(main())
