"""The paper's Table 1 beside the same quantities measured from generated fields.

    python experiments/table1.py [--seeds 5] [--out FILE]   # --out docs/table1.md: the page

For every preset, fields are generated for seeds 0..N-1 (one jit(vmap(generate)) call) and
measured as a user would measure a real field, from plant positions and primitives only:
terrain size (extent of the height grid), max |ΔH| (peak-to-peak of the terrain after removing
its least-squares plane), plant L×W×H (mean bounding box of the primitives of active plants:
L along the row, W across it, H from the plant's base), d_rr / d_RR (median gaps between
row centre lines, rows located by the median y of their plants, the gaps split into the small
in-group and the large between-group cluster), d_pp (median spacing of consecutive plants along
a row) and rows per group (rows between two large gaps; one uniform spacing reads as 1).
"""

from __future__ import annotations

import sys
from pathlib import Path

import jax
import numpy as np
from tqdm import tqdm

from mjxrow import crops
from mjxrow import field as mjxrow_field
from mjxrow.crops import prims as crops_prims
from mjxrow.files import atomic_write_text, check_out_file
from paper import cli

SAME_GAP = 0.05  # m: gaps closer than this form one cluster (a uniform row spacing)


def _half_extents(rot: np.ndarray, size: np.ndarray, kind: np.ndarray) -> np.ndarray:
    """Half extents along the frame axes of primitives [..., K, 3] (ellipsoid: semi-axes along
    rot's columns; capsule: radius + half length along rot[:, 2])."""
    ell = np.sqrt(np.sum((rot * size[..., None, :]) ** 2, -1))
    cap = size[..., :1] + np.abs(rot[..., :, 2]) * size[..., 2:3]
    return np.where((kind == crops_prims.CAPSULE)[:, None], cap, ell)


def plant_boxes(field: mjxrow_field.Field, prims: crops_prims.Prims) -> np.ndarray:
    """(L, W, H) [m] of the bounding box of each active plant's primitives: L along the row (x),
    W across it (y), H from the plant's base up: [n_active, 3]. One field, numpy arrays."""
    centre = prims.centre - field.plant_pos[:, :, None]
    half = _half_extents(prims.rot, prims.size, prims.kind)
    lo, hi = (centre - half).min(-2), (centre + half).max(-2)
    box = np.concatenate([(hi - lo)[..., :2], hi[..., 2:]], -1)
    return box[field.plant_active]


def detrended_ptp(field: mjxrow_field.Field) -> float:
    """Peak-to-peak [m] of the terrain after removing its least-squares plane."""
    x, y = (
        np.asarray(a) for a in mjxrow_field.terrain_axes(field.terrain_size, field.terrain.shape)
    )
    xx, yy = np.meshgrid(x, y)
    a = np.stack([xx.ravel(), yy.ravel(), np.ones(xx.size)], 1)
    h = field.terrain.ravel().astype(np.float64)
    coef, *_ = np.linalg.lstsq(a, h, rcond=None)
    return float(np.ptp(h - a @ coef))


def spacings(field: mjxrow_field.Field) -> dict[str, float]:
    """d_rr, d_RR, d_pp [m], rows per group, rows and groups, from plant positions only."""
    act = field.plant_active
    rows = [r for r in range(act.shape[0]) if act[r].any()]
    pos = field.plant_pos
    row_y = np.array([np.median(pos[r, act[r], 1]) for r in rows])
    order = np.argsort(row_y)
    gaps = np.diff(row_y[order])
    if np.ptp(gaps) < SAME_GAP:  # one uniform spacing: every row its own group
        small = large = gaps
        per_group = np.ones(len(rows))
    else:
        cut = 0.5 * (gaps.min() + gaps.max())
        small, large = gaps[gaps < cut], gaps[gaps >= cut]
        per_group = np.diff(np.r_[-1, np.flatnonzero(gaps >= cut), len(rows) - 1])
    steps = []
    for r in rows:
        i = np.flatnonzero(act[r])
        steps.append(np.diff(pos[r, i, 0]) / np.diff(i))
    return {"d_rr": float(np.median(small)), "d_RR": float(np.median(large)),
            "d_pp": float(np.median(np.concatenate(steps))),
            "rows_per_group": float(np.median(per_group)), "rows": len(rows),
            "groups": len(per_group)}


def measure(preset: str, seeds: int) -> dict[str, float | tuple]:
    """Means over `seeds` generated fields of `preset` (seed 0..seeds-1)."""
    shape = mjxrow_field.preset_shape(preset)
    gen = jax.jit(
        jax.vmap(mjxrow_field.generate, in_axes=(None, None, 0)), static_argnums=1
    )  # one preset
    prims_fn = jax.jit(jax.vmap(crops_prims.plant_prims, in_axes=(0, None)), static_argnums=1)
    keys = jax.vmap(jax.random.key)(np.arange(seeds))
    fields = gen(mjxrow_field.make_params(preset), shape, keys)
    prims = jax.tree.map(np.asarray, prims_fn(fields, shape))
    fields = jax.tree.map(np.asarray, fields)
    rows = []
    for b in range(seeds):
        f = jax.tree.map(lambda a, b=b: a[b], fields)
        p = jax.tree.map(lambda a, b=b: a[b], prims)
        x, y = (np.asarray(a) for a in mjxrow_field.terrain_axes(f.terrain_size, f.terrain.shape))
        rows.append({"terrain": (np.ptp(x), np.ptp(y)), "dh": detrended_ptp(f),
                     "plant": tuple(plant_boxes(f, p).mean(0)), **spacings(f)})
    out = {}
    for k in rows[0]:
        vals = np.array([r[k] for r in rows], np.float64)
        out[k] = tuple(vals.mean(0)) if vals.ndim > 1 else float(vals.mean())
        if vals.ndim == 1:
            out[k + "_std"] = float(vals.std())
    return out


def _x(vals, nd=2) -> str:
    return "×".join(f"{v:.{nd}f}".rstrip("0").rstrip(".") for v in vals)


def table(seeds: int, tol: float = 0.05) -> tuple[str, list[str]]:
    """The markdown table, and one line per measured number more than `tol` (relative) away
    from its reference."""
    head = ("| crop | source | terrain L×W [m] | max \\|ΔH\\| [m] | plant L×W×H [m] | d_rr [m] | "
            "d_RR [m] | d_pp [m] | rows per group | rows (groups) |")
    lines, off = [head, "|" + "---|" * 10], []
    for preset in tqdm(crops.names(), desc="presets", file=sys.stderr):
        crop = crops.get(preset)  # Martini et al., Table 1 where the paper has the crop
        q = crop.paper.get("table1", crop.preset)
        src = "paper" if "table1" in crop.paper else "typical (not in the paper)"
        tl, tw, dh = q["terrain_length"], q["terrain_width"], q["terrain_dh"]
        plant = (q["plant_length"], q["plant_width"], q["plant_height"])
        d_rr, d_RR, d_pp, rpg = q["d_rr"], q["d_RR"], q["d_pp"], int(q["rows_per_group"])
        lines.append(f"| {preset} | {src} | {_x((tl, tw))} | {dh:g} | {_x(plant)} | {d_rr:g} | "
                     f"{d_RR:g} | {d_pp:g} | {rpg} | |")
        m = measure(preset, seeds)
        lines.append(
            f"| | measured ({seeds} seeds) | {_x(m['terrain'])} | {m['dh']:.3f} | "
            f"{_x(m['plant'])} | {m['d_rr']:.3f} | {m['d_RR']:.3f} | {m['d_pp']:.3f} | "
            f"{m['rows_per_group']:g} | {m['rows']:g} ({m['groups']:g}) |")
        pairs = [("terrain L", tl, m["terrain"][0]), ("terrain W", tw, m["terrain"][1]),
                 ("|ΔH|", dh, m["dh"]), ("d_rr", d_rr, m["d_rr"]), ("d_RR", d_RR, m["d_RR"]),
                 ("d_pp", d_pp, m["d_pp"]), ("rows per group", rpg, m["rows_per_group"])]
        pairs += [(f"plant {n}", ref, v) for n, ref, v in zip("LWH", plant, m["plant"],
                                                                strict=True)]
        off += [f"- {preset} {n}: measured {v:.3g} vs {ref:g} ({100 * (v / ref - 1):+.0f} %)"
                for n, ref, v in pairs if abs(v / ref - 1) > tol]
    return "\n".join(lines), off


def main(argv: list[str] | None = None) -> int:
    """`python experiments/table1.py ARGS`: the table printed, and written to `--out` if given."""
    args = cli.table1().parse_args(argv)
    if args.seeds < 1:
        print("error: --seeds must be at least 1", file=sys.stderr)
        return 2
    if args.out:  # before minutes of work
        try:
            check_out_file(args.out, "--out")
        except ValueError as e:
            print(f"error: {e}", file=sys.stderr)
            return 2
    text, off = table(args.seeds)
    notes = "\n".join(off) if off else "- none"
    text += f"\n\nMeasured numbers more than 5 % away from their reference:\n{notes}\n"
    print(text)
    if args.out:
        doc = (f"# Table 1: the paper's field presets beside generated fields\n\n"
               f"Written by `python experiments/table1.py --seeds {args.seeds} --out "
               f"{args.out}`. {__doc__.split(chr(10), 3)[3].strip()}\n\n{text}")
        Path(args.out).parent.mkdir(parents=True, exist_ok=True)
        atomic_write_text(args.out, doc)
    return 0

if __name__ == "__main__":
    sys.exit(main())
