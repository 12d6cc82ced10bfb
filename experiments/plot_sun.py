"""Pear's success and CHA as the sun turns about the rows, one line per controller, from the
`summary.csv` of `sweeps/sun.yaml` runs:

    python experiments/plot_sun.py [--add LABEL=SUMMARY.csv ...] [--device NAME]
        [--data docs/data/sun_pear.csv] [--out docs/sun_pear.png]

`--add` copies a sweep's cells (azimuth, episodes, success with its 95 % Wilson interval, CHA
and MAE with theirs) into `--data` under LABEL, replacing that label's earlier rows; the figure
is then drawn from every label there. The dashed line is Table 3's azimuth (35°). An existing
--out is replaced only when this script wrote it (the PNG's `Software` entry names it).

Exit codes: 0 done, 2 bad input (the file, label or column named).
"""

from __future__ import annotations

import argparse
import csv
import datetime
import io
import sys
from pathlib import Path

import plot_one_command  # experiments/, the folder of this script

ROOT = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(ROOT))  # run from a checkout, uninstalled
TAG = "mjxrow experiments/plot_sun.py"  # the PNG's Software entry
AXIS = "perception.sun_azimuth"
COLUMNS = ("label", "device", "date", "azimuth", "n", "success", "success_lo", "success_hi",
           "cha", "cha_lo", "cha_hi", "mae")
TABLE3_AZIMUTH = 35.0  # degrees, render.SUN_AZIMUTH_DEG


def parser() -> argparse.ArgumentParser:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--add", nargs="*", default=[], metavar="LABEL=SUMMARY.csv",
                   help="a sun sweep's summary.csv to copy into --data under LABEL")
    p.add_argument("--device", default="", help="the device the added sweeps ran on")
    p.add_argument("--data", default=str(ROOT / "docs/data/sun_pear.csv"))
    p.add_argument("--out", default=str(ROOT / "docs/sun_pear.png"))
    return p


def _rows(path: str) -> list[dict]:
    with open(path, newline="") as f:
        return list(csv.DictReader(f))


def added(label: str, summary: str, device: str) -> list[dict]:
    """The data rows of one sweep's summary.csv under `label`."""
    try:
        cells = _rows(summary)
    except OSError as e:
        raise ValueError(f"--add {label}: cannot read {summary} ({e.strerror})") from None
    need = (AXIS, "n", "success", "success_lo", "success_hi", "cha", "cha_lo", "cha_hi", "mae")
    missing = [c for c in need if cells and c not in cells[0]]
    if not cells or missing:
        raise ValueError(f"--add {label}: {summary} is not a sun sweep's summary (no "
                         f"{(missing or [AXIS])[0]!r} column or no rows)")
    today = datetime.date.today().isoformat()
    return [{"label": label, "device": device, "date": today, "azimuth": c[AXIS],
             **{k: c[k] for k in need[1:]}} for c in cells]


def plot(rows: list[dict], out: Path) -> Path:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    labels = list(dict.fromkeys(r["label"] for r in rows))
    lines = -(-len(labels) // 2)  # the legend's rows, two labels a row
    fig, (ax, bx) = plt.subplots(1, 2, figsize=(12, 3.9 + 0.22 * lines))
    for i, label in enumerate(labels):
        mine = sorted((r for r in rows if r["label"] == label), key=lambda r: float(r["azimuth"]))
        x = [float(r["azimuth"]) for r in mine]
        for a, key in ((ax, "success"), (bx, "cha")):
            y = [float(r[key]) for r in mine]
            lo = [v - float(r[f"{key}_lo"] or v) for v, r in zip(y, mine, strict=True)]
            hi = [float(r[f"{key}_hi"] or v) - v for v, r in zip(y, mine, strict=True)]
            a.errorbar([v + 2.0 * (i - len(labels) / 2) for v in x], y, yerr=[lo, hi],
                       marker="os^dv"[i % 5], capsize=3,
                       label=f"{label} ({mine[0]['n']} episodes a point)")
    for a in (ax, bx):
        a.axvline(TABLE3_AZIMUTH, color="k", ls="--", lw=0.8)
        a.set_xlabel("sun azimuth [°] from the rows' direction toward +y (35°: Table 3)")
        a.set_xticks(range(0, 361, 45))
    ax.set_ylabel("success (95 % CI)")
    ax.set_ylim(0, 1.05)
    bx.set_ylabel("CHA [rad] (95 % CI)")
    bx.axhline(0.0, color="k", lw=0.6, ls=":")
    fig.suptitle("pear at its default geometry, sunny, the sun turned about the rows "
                 "(sweeps/sun.yaml)", fontsize=10)
    fig.tight_layout(rect=(0, 0.05 * lines, 1, 1))  # room below for the legend
    handles, names = ax.get_legend_handles_labels()
    fig.legend(handles, names, fontsize=8, loc="lower center", ncol=min(2, len(names)))
    out.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(out, dpi=110, metadata={"Software": TAG})
    plt.close(fig)
    return out


def main(argv: list[str] | None = None) -> int:
    args = parser().parse_args(argv)
    out, data = Path(args.out), Path(args.data)
    try:
        if out.exists() and not plot_one_command.written_by(out, TAG):
            raise ValueError(f"--out: {out} exists and was not written by this script; "
                             "choose another path")
        rows = _rows(str(data)) if data.exists() else []
        if rows and tuple(rows[0]) != COLUMNS:
            raise ValueError(f"--data: {data} does not have the columns {', '.join(COLUMNS)}")
        for item in args.add:
            label, sep, summary = item.partition("=")
            if not sep or not label:
                raise ValueError(f"--add: expected LABEL=SUMMARY.csv, got {item!r}")
            rows = [r for r in rows if r["label"] != label] + added(label, summary, args.device)
        if not rows:
            raise ValueError(f"--data: {data} has no rows; --add a sweep's summary.csv")
    except ValueError as e:
        print(f"error: {e}", file=sys.stderr)
        return 2
    if args.add:
        from mjxrow import files

        text = io.StringIO()
        w = csv.DictWriter(text, COLUMNS, lineterminator="\n")
        w.writeheader()
        w.writerows(rows)
        data.parent.mkdir(parents=True, exist_ok=True)
        files.atomic_write_text(data, text.getvalue())
    print(plot(rows, out))
    return 0


if __name__ == "__main__":
    sys.exit(main())
