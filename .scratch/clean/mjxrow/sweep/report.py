"""The tables and the markdown report of a sweep, and its output files (figures: figures.py).

A summary table has one row per cell: the swept axes (dotted names, e.g. `field.d_rr`), `n`
(episodes), and per metric `m` its mean with the 95 % interval `m_lo`, `m_hi` and `m_n`, the
episodes the mean is taken over: an episode excluded from the trajectory metrics (no valid step,
flipped, simulation error: Metric.trajectory in rollout.metrics) and a failed episode's `time`
are NaN in results.csv and left out, so `m_n` < `n` says how many were left out. The metrics are
the registered ones (rollout.metrics.METRICS), with their labels and formats (figures.metric_info).

A `--smoke` run (`is_smoke`) says so: report.md opens with `SMOKE_NOTE` and its figures' titles
carry "(smoke)".
"""

from __future__ import annotations

import os
from concurrent.futures import Executor
from pathlib import Path
from typing import Any

import numpy as np
import pandas as pd
import yaml

from mjxrow.rollout import aggregate as rollout_aggregate
from mjxrow.rollout import metrics as rollout_metrics
from mjxrow.sweep import config
from mjxrow.sweep.figures import fmt_tick, metric_info, surfaces


def atomic_write_text(path: Path, text: str) -> None:
    """Write a text file atomically: temp file in the same folder, then os.replace."""
    tmp = path.with_name(f".{path.name}.{os.getpid()}.tmp")
    tmp.write_text(text)
    os.replace(tmp, path)


# ---------------------------------------------------------------------------------------------
# Summary


def summary_table(results: pd.DataFrame, axes: list[str], metric_names: list[str]) -> pd.DataFrame:
    """Per cell: axis values, n, and per metric its mean with the 95 % interval and the number
    of episodes it is taken over (`m`, `m_lo`, `m_hi`, `m_n`; Wilson for rates, Student t
    otherwise, via rollout.aggregate; NaN values left out), plus the share of episodes per
    ending reason (`reason_<name>`)."""
    out = []
    for cell, rows in results.groupby("cell", sort=True):
        row: dict[str, Any] = {"cell": cell, **{a: rows[a].iloc[0] for a in axes},
                               "n": len(rows)}
        table = {m: rows[m].to_numpy() for m in metric_names if m != "reason"}
        for m, agg in rollout_aggregate.aggregate(table).items():
            row.update({m: agg["mean"], f"{m}_lo": agg["lo"], f"{m}_hi": agg["hi"],
                        f"{m}_n": agg["n"]})
        if "reason" in rows:
            shares = rows["reason"].value_counts(normalize=True)
            row.update(
                {f"reason_{r}": float(shares.get(r, 0.0)) for r in rollout_metrics.REASONS[1:]}
            )
        out.append(row)
    return pd.DataFrame(out)


# ---------------------------------------------------------------------------------------------
# Report


def _md_table(df: pd.DataFrame) -> str:
    cols = list(df.columns)
    lines = ["| " + " | ".join(cols) + " |", "|" + "---|" * len(cols)]
    for row in df.itertuples(index=False):
        lines.append("| " + " | ".join(fmt_tick(v) if not isinstance(v, str) else v
                                       for v in row) + " |")
    return "\n".join(lines)


def _mean_ci(fmt: str, mean, lo, hi, n_used, n) -> str:
    """`mean [lo, hi]`, with `(n = k of N)` when only k of the cell's N episodes count."""
    if not np.isfinite(mean):
        text = "–"
    elif np.isfinite(lo) and np.isfinite(hi):
        text = f"{fmt.format(mean)} [{fmt.format(lo)}, {fmt.format(hi)}]"
    else:
        text = fmt.format(mean)
    return text if n_used >= n else f"{text} (n = {int(n_used)} of {int(n)})"


def summary_markdown(summary: pd.DataFrame, axes: list[str], metrics: list[str]) -> str:
    """Markdown table: axis values, n, and `mean [lo, hi]` per metric, with the count of the
    episodes it is taken over where some were left out."""
    out = summary[axes + ["n"]].copy() if axes else summary[["n"]].copy()
    for m in metrics:
        fmt = metric_info(m)[2]
        used = summary[f"{m}_n"] if f"{m}_n" in summary else summary["n"]
        out[m] = [_mean_ci(fmt, *v) for v in zip(
            summary[m], summary[f"{m}_lo"], summary[f"{m}_hi"], used, summary["n"], strict=True)]
    return _md_table(out)


def failures_markdown(summary: pd.DataFrame, axes: list[str], reasons: list[str],
                      threshold: float = 0.95) -> str:
    """Cells whose success rate is below `threshold`, with the share of each ending reason."""
    if "success" not in summary:
        return "No success metric in this sweep."
    bad = summary[summary["success"] < threshold]
    if bad.empty:
        return f"Every cell succeeds in at least {threshold:.0%} of its episodes."
    cols = axes + ["n", "success"] + [f"reason_{r}" for r in reasons if r != "goal" and
                                      f"reason_{r}" in bad and bad[f"reason_{r}"].gt(0).any()]
    table = bad[cols].copy()
    table["success"] = [f"{v:.2f}" for v in table["success"]]
    for c in cols[len(axes) + 2:]:
        table[c] = [f"{v:.0%}" for v in table[c]]
    return (f"{len(bad)} of {len(summary)} cells succeed in fewer than {threshold:.0%} of "
            f"their episodes (share of episodes by how they ended):\n\n" + _md_table(table))


SMOKE_NOTE = ("**Smoke run: a tiny configuration that checks the pipeline; its numbers are not "
              "results.**")


def is_smoke(info: dict[str, Any]) -> bool:
    """Whether the run facts describe a `--smoke` run: a `smoke` fact that is True, or
    `--smoke` (or an abbreviation argparse accepts, `--smo`) among the words of the command."""
    if info.get("smoke") is True:
        return True
    words = str(info.get("command", "")).split()
    return any(len(w) > 3 and "--smoke".startswith(w) for w in words)


def report(path: str | Path, title: str, info: dict[str, Any], config_yaml: str,
           summary: pd.DataFrame, axes: list[str], metrics: list[str], images: dict[str, Path],
           reasons: list[str], smoke: bool = False) -> Path:
    """Write `report.md` (atomically): run facts, failures, plots, summary, resolved config;
    with `smoke`, the title says "(smoke)" and the report opens with `SMOKE_NOTE`."""
    path = Path(path)
    parts = [f"# Sweep report: {title}" + (" (smoke)" if smoke else ""), ""]
    if smoke:
        parts += [SMOKE_NOTE, ""]
    parts += [f"- **{k}**: {v}" for k, v in info.items()]
    parts += ["", "## Where it fails", "", failures_markdown(summary, axes, reasons), ""]
    if images:
        parts += ["## Surfaces", ""]
        for m, p in images.items():
            parts += [f"### {metric_info(m)[0]}", "", f"![{m}]({Path(p).name})", ""]
    parts += ["## Summary (mean [95 % CI] per cell)", "",
              summary_markdown(summary, axes, metrics), "",
              "## Resolved configuration", "", "```yaml", config_yaml.rstrip(), "```", ""]
    atomic_write_text(path, "\n".join(parts))
    return path


# ---------------------------------------------------------------------------------------------
# Outputs of a sweep

ID_COLUMNS = ("cell", "episode", "cell_hash", "group", "lane")


def metric_columns(results: pd.DataFrame) -> list[str]:
    """The metric columns of a results table: all but identity and parameter columns
    (parameters are dotted, `field.d_rr`, or top-level config keys)."""
    params = {k for k, _ in config.leaf_keys()}
    return [c for c in results.columns
            if c not in params and c not in ID_COLUMNS and "." not in c]


def write_outputs(results: pd.DataFrame, cfg: config.SweepConfig, out: Path, info: dict[str, Any],
                  figures: bool = True, pool: Executor | None = None) -> dict[str, Path]:
    """summary.csv and config.yaml from a results table (one row per episode); with `figures`
    also one PNG per numeric metric (drawn in `pool`'s processes if given) and report.md.
    Every file written atomically. A smoke run (`is_smoke(info)`) says so in the figures'
    titles and atop report.md."""
    axes = list(cfg.axis_order)
    names = metric_columns(results)
    numeric = [m for m in names if m != "reason" and pd.api.types.is_numeric_dtype(results[m])]
    summary = summary_table(results, axes, names)
    atomic_write_text(out / "summary.csv", summary.to_csv(index=False))
    config_yaml = yaml.safe_dump(config.to_dict(cfg), sort_keys=False, allow_unicode=True)
    atomic_write_text(out / "config.yaml", config_yaml)
    files = {"summary": out / "summary.csv", "config": out / "config.yaml"}
    if not figures:
        return files
    smoke = is_smoke(info)
    images = surfaces(summary, axes, numeric, out, f"{cfg.name} (smoke)" if smoke else cfg.name,
                      pool)
    report(out / "report.md", cfg.name, info, config_yaml, summary, axes, numeric, images,
           list(rollout_metrics.REASONS[1:]), smoke)
    return {**files, "report": out / "report.md", **images}
