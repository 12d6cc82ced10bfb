"""Markdown tables from `benchmarks.jsonl` (the machine record of every benchmark run).

    python experiments/benchmarks_table.py            # latest row per device, stage, config
    python experiments/benchmarks_table.py --all      # every recorded row
"""

from __future__ import annotations

import argparse
import json
from pathlib import Path

import pandas as pd


def load(path: str | Path = "benchmarks.jsonl") -> pd.DataFrame:
    rows = [json.loads(line) for line in Path(path).read_text().splitlines() if line.strip()]
    return pd.DataFrame(rows)


def _num(v: float) -> str:
    return f"{v:,.0f}" if abs(v) >= 100 else f"{v:.3g}"


def table(df: pd.DataFrame, latest: bool = True) -> str:
    if latest:
        df = df.drop_duplicates(["device", "stage", "config", "batch"], keep="last")
    lines = ["| date | device | stage | config | batch | value | unit | compile [s] |",
             "|---|---|---|---|---|---|---|---|"]
    for r in df.itertuples():
        comp = getattr(r, "compile_s", float("nan"))
        comp = "" if pd.isna(comp) else f"{comp:.1f}"
        lines.append(f"| {r.date} | {r.device} | {r.stage} | {r.config} | {r.batch} | "
                     f"{_num(r.value)} | {r.unit} | {comp} |")
    return "\n".join(lines)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--file", default="benchmarks.jsonl")
    ap.add_argument("--all", action="store_true", help="every row, not only the latest")
    args = ap.parse_args()
    text = table(load(args.file), latest=not args.all)
    print(text)


if __name__ == "__main__":
    main()
