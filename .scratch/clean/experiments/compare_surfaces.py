"""Sweep surfaces of several controllers side by side, and the policy goal's check, from the
`summary.csv` files of sweeps over the same cells (e.g. SegZeros and the oracle in one mixed
run, the learned policy in another):

    python experiments/compare_surfaces.py A/summary.csv B/summary.csv
        [--controllers segzeros policy oracle] [--metric success] [--png FIG.png]
        [--label NAME=CSV ...]

A summary without a `controller.name` column is one controller's: `--label policy=B/summary.csv`
names it. The figure is `mjxrow.sweep.figures.heatmap` with one panel per controller, in
`--controllers` order. The check (printed as a markdown table): in every cell where SegZeros
succeeds in fewer than `--below` (0.80) of its episodes and the oracle in at least `--drivable`
(0.95), the policy must succeed in at least `--margin` (0.20) more than SegZeros.

Exit codes: 0 (the check is printed, met or not), 2 bad input (the file or column named).
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))  # run from a checkout, uninstalled

CONTROLLER = "controller.name"


def parser() -> argparse.ArgumentParser:
    p = argparse.ArgumentParser(prog="python experiments/compare_surfaces.py",
                                description=__doc__.split("\n")[0],
                                formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("summaries", nargs="*", type=Path, help="sweep summary.csv files")
    p.add_argument("--label", action="append", default=[], metavar="NAME=CSV",
                   help="a summary of one controller, without a controller.name column")
    p.add_argument("--controllers", nargs="+", default=["segzeros", "policy", "oracle"])
    p.add_argument("--metric", default="success")
    p.add_argument("--png", type=Path, default=None, help="write the side-by-side figure here")
    p.add_argument("--title", default="")
    p.add_argument("--below", type=float, default=0.80)
    p.add_argument("--drivable", type=float, default=0.95)
    p.add_argument("--margin", type=float, default=0.20)
    return p


def load(summaries: list[Path], labels: list[str]):
    """One frame of every summary's rows (a labelled one gets its controller.name)."""
    import pandas as pd

    frames = []
    pairs = [(None, p) for p in summaries]
    for item in labels:
        name, sep, path = item.partition("=")
        if not sep or not name or not path:
            raise ValueError(f"--label {item!r}: expected NAME=CSV")
        pairs.append((name, Path(path)))
    if not pairs:
        raise ValueError("no summary.csv given")
    for name, path in pairs:
        if not path.is_file():
            raise ValueError(f"{path}: no such file")
        df = pd.read_csv(path)
        if name is not None:
            df[CONTROLLER] = name
        elif CONTROLLER not in df:
            raise ValueError(f"{path}: no {CONTROLLER} column (name it with --label NAME=CSV)")
        frames.append(df)
    return pd.concat(frames, ignore_index=True)


def axes_of(df, metric: str) -> list[str]:
    """The swept axes: the columns between `cell` and `n` other than the controller."""
    cols = list(df.columns)
    if "cell" not in cols or "n" not in cols or metric not in cols:
        raise ValueError(f"the summaries lack cell, n or {metric} columns")
    return [c for c in cols[cols.index("cell") + 1:cols.index("n")] if c != CONTROLLER]


def check(df, axes: list[str], metric: str, below: float, drivable: float, margin: float):
    """Per cell: SegZeros', the policy's and the oracle's metric, whether the goal applies
    (SegZeros < below, oracle ≥ drivable) and whether it is met (policy ≥ SegZeros + margin)."""
    wide = df.pivot_table(index=axes, columns=CONTROLLER, values=metric, aggfunc="mean")
    for c in ("segzeros", "policy", "oracle"):
        if c not in wide:
            raise ValueError(f"no rows of controller {c!r} in the summaries")
    wide = wide[["segzeros", "policy", "oracle"]].copy()
    wide["applies"] = (wide["segzeros"] < below) & (wide["oracle"] >= drivable)
    wide["met"] = ~wide["applies"] | (wide["policy"] >= wide["segzeros"] + margin - 1e-9)
    return wide


def main(argv: list[str] | None = None) -> int:
    args = parser().parse_args(argv)
    try:
        df = load(args.summaries, args.label)
        axes = axes_of(df, args.metric)
        if len(axes) != 2:
            raise ValueError(f"expected two swept axes, found {axes}")
        missing = [c for c in args.controllers if c not in set(df[CONTROLLER])]
        if missing:
            raise ValueError(f"--controllers: no rows of {', '.join(missing)}")
        table = check(df, axes, args.metric, args.below, args.drivable, args.margin)
    except ValueError as e:
        print(f"error: {e}", file=sys.stderr)
        return 2
    from mjxrow.sweep import figures

    if args.png is not None:
        order = {c: i for i, c in enumerate(args.controllers)}
        sub = df[df[CONTROLLER].isin(order)].copy()
        sub = sub.sort_values(CONTROLLER, key=lambda s: s.map(order), kind="stable")
        args.png.parent.mkdir(parents=True, exist_ok=True)
        figures.heatmap(sub, args.metric, axes[0], axes[1], args.png, args.title,
                        facet=CONTROLLER)
        print(f"wrote {args.png}")
    applies = table[table["applies"]]
    print(f"| {' | '.join(axes)} | SegZeros | policy | oracle | goal |")
    print("|" + "---|" * (len(axes) + 4))
    for idx, r in table.iterrows():
        goal = ("met" if r["met"] else "not met") if r["applies"] else "—"
        print(f"| {' | '.join(f'{v:g}' for v in idx)} | {r['segzeros']:.2f} | "
              f"{r['policy']:.2f} | {r['oracle']:.2f} | {goal} |")
    print(f"\ncells where the goal applies (SegZeros < {args.below:g}, oracle ≥ "
          f"{args.drivable:g}): {len(applies)}; policy ≥ SegZeros + {args.margin:g} in "
          f"{int(applies['met'].sum())}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
