"""The outputs of a search: the ranked distinct failures (`failures.csv`), the confirmation of
the top ones with new seeds (`confirm.csv`), the per-method summary (printed last, in
`report.md`, and as rows of `benchmarks.jsonl` with `--record`), the figures and `report.md`."""

from __future__ import annotations

import dataclasses
import datetime
import json
from pathlib import Path
from typing import Any

import numpy as np
import pandas as pd

from mjxrow import files as mjxrow_files
from mjxrow.rollout import metrics as rollout_metrics
from mjxrow.search import box as search_box
from mjxrow.search import figures as search_figures
from mjxrow.search import objective
from mjxrow.search.config import SearchConfig

FAILURES, CONFIRM, REPORT = "failures.csv", "confirm.csv", "report.md"
CONFIRM_SEED = 1  # confirmation episodes: run seed = seed + this, episodes 0 … N − 1
CONFIRMED = 0.5  # a failure is confirmed when it fails again in at least this share of them


def reason_names(codes) -> list[str]:
    return [rollout_metrics.REASONS[int(c)] for c in np.asarray(codes).reshape(-1)]


def u_columns(cfg: SearchConfig) -> list[str]:
    return [f"u_{j}" for j in range(len(cfg.box))]


def rank_failures(cfg: SearchConfig, rows: pd.DataFrame) -> pd.DataFrame:
    """The distinct failures of every method, ranked (objective.cluster): the leader's row
    (its values, episodes, the first failing episode) with rank (1 = worst), members (failing
    candidates merged into it) and methods (the methods that found one of them)."""
    if rows.empty:
        return pd.DataFrame(columns=["rank", "members", "methods"])
    fails = rows[rows["outcome"] == "fail"].reset_index(drop=True)
    if fails.empty:
        return pd.DataFrame(columns=["rank", "members", "methods", *rows.columns])
    label, leaders = objective.cluster(fails[u_columns(cfg)].to_numpy(float),
                                       fails["fail_rate"].to_numpy(float),
                                       fails["margin"].to_numpy(float), cfg.merge_radius)
    out = fails.iloc[leaders].reset_index(drop=True)
    out.insert(0, "rank", np.arange(1, len(out) + 1))
    out.insert(1, "members", [int((label == k).sum()) for k in range(len(leaders))])
    out.insert(2, "methods", [";".join(sorted(set(fails["method"][label == k])))
                              for k in range(len(leaders))])
    return out


def confirm_failures(cfg: SearchConfig, failures: pd.DataFrame, evaluator, n: int, top: int
                     ) -> pd.DataFrame:
    """The top `top` failures the search method found (alone or with the baseline), each run
    again at its values with `n` new seeds (run seed seed + CONFIRM_SEED, episodes
    0 … n − 1): rank, episodes, fails, rate, confirmed (rate ≥ CONFIRMED), reasons
    (name: count)."""
    own = failures["methods"].astype(str).str.split(";").map(lambda m: cfg.method in m)
    picked = failures[own].head(top)
    seed = (cfg.seed + CONFIRM_SEED) % 2**32
    runs = [dataclasses.replace(search_box.run_of(cfg.scenario, cfg.box, u), seed=seed)
            for u in picked[u_columns(cfg)].to_numpy(float)]
    items = [(r, e) for r in runs for e in range(n)]
    res = evaluator.episodes(items)
    rows = []
    for k, rank in enumerate(picked["rank"]):
        reason = res["reason"][k * n:(k + 1) * n]
        fail = objective.failed(reason)
        names, counts = np.unique(reason_names(reason), return_counts=True)
        rows.append({"rank": int(rank), "seed": seed, "episodes": n, "fails": int(fail.sum()),
                     "rate": float(fail.mean()), "confirmed": bool(fail.mean() >= CONFIRMED),
                     "reasons": ";".join(f"{a}: {b}" for a, b in zip(names, counts,
                                                                       strict=True))})
    return pd.DataFrame(rows)


def summary(cfg: SearchConfig, rows: pd.DataFrame, state: dict[str, Any]) -> pd.DataFrame:
    """One row per method: episodes, failing episodes (and per 1,000), failing candidates,
    distinct failures, best margin, episodes spent when the first failure was found, time."""
    out = []
    for name, st in state.get("streams", {}).items():
        df = rows[rows["method"] == name] if not rows.empty else rows
        valid = df[df["outcome"] != "invalid"] if len(df) else df
        n_eps = int(st["episodes"])
        failing_eps = int(round((valid["fail_rate"] * cfg.repeats).sum())) if len(valid) else 0
        fails = df[df["outcome"] == "fail"] if len(df) else df
        out.append({"method": name, "generations": int(st["generation"]), "episodes": n_eps,
                    "failing_episodes": failing_eps,
                    "failing_per_1000": 1000.0 * failing_eps / n_eps if n_eps else np.nan,
                    "candidates": len(df), "invalid": int((df["outcome"] == "invalid").sum())
                    if len(df) else 0,
                    "failing_candidates": len(fails), "distinct_failures": int(st["distinct"]),
                    "best_margin": float(valid["margin"].min()) if len(valid) else np.nan,
                    "first_failure_at": int(fails["episodes_spent"].iloc[0]) if len(fails)
                    else np.nan,
                    "time_s": round(float(st["elapsed_s"]), 1),
                    "stopped_by": st.get("stopped_by", "")})
    return pd.DataFrame(out)


def _md(df: pd.DataFrame) -> str:
    cols = list(df.columns)
    lines = ["| " + " | ".join(cols) + " |", "|" + "---|" * len(cols)]
    for _, r in df.iterrows():
        lines.append("| " + " | ".join(_fmt(r[c]) for c in cols) + " |")
    return "\n".join(lines)


def _fmt(v: Any) -> str:
    if isinstance(v, (float, np.floating)):
        return "" if np.isnan(v) else f"{v:.4g}"
    return str(v)


def summary_text(cfg: SearchConfig, res: dict[str, Any]) -> str:
    """The table printed last: per method, and the confirmation's count."""
    cols = ["method", "episodes", "failing_episodes", "failing_per_1000", "distinct_failures",
            "best_margin", "first_failure_at", "time_s"]
    text = _md(res["summary"][cols]) if len(res["summary"]) else "(nothing run)"
    conf = res.get("confirm")
    if conf is not None and len(conf):
        text += (f"\nconfirmed: {int(conf['confirmed'].sum())} of {len(conf)} distinct failures "
                 f"fail again in ≥ {CONFIRMED:.0%} of {int(conf['episodes'].iloc[0])} new seeds")
    return text


def write_outputs(cfg: SearchConfig, out: Path, rows: pd.DataFrame, state: dict[str, Any],
                  info: dict[str, Any], search, figures: bool, confirm: int, confirm_top: int
                  ) -> dict[str, Any]:
    """failures.csv, confirm.csv (confirm > 0), the figures, report.md; every file atomic.
    `search` (run._Search) gives the evaluator, built on first need."""
    failures = rank_failures(cfg, rows)
    files: dict[str, Path] = {}
    conf = None
    if confirm and len(failures) and failures["methods"].str.contains(cfg.method).any():
        conf = confirm_failures(cfg, failures, search.get_evaluator(), confirm, confirm_top)
        mjxrow_files.atomic_write_text(out / CONFIRM, conf.to_csv(index=False))
        files["confirm"] = out / CONFIRM
        failures = failures.merge(conf[["rank", "rate", "confirmed"]].rename(
            columns={"rate": "confirm_rate"}), on="rank", how="left")
    mjxrow_files.atomic_write_text(out / FAILURES, failures.to_csv(index=False))
    files["failures"] = out / FAILURES
    table = summary(cfg, rows, state)
    if figures and len(rows):
        files["convergence"] = search_figures.convergence(rows, cfg, out / "convergence.png")
        files["pairs"] = search_figures.pairs(rows, cfg, out / "pairs.png")
        top = failures.head(cfg.top)
        if len(top):
            ev = search.get_evaluator()
            runs = [search_box.run_of(cfg.scenario, cfg.box, u)
                    for u in top[u_columns(cfg)].to_numpy(float)]
            eps = [int(e) for e in top["first_failing"]]
            batch, log = ev.replay(list(zip(runs, eps, strict=True)))
            frames = ev.first_frames(batch, runs)
            for k, (_, f) in enumerate(top.iterrows()):
                p = out / f"failure_{int(f['rank'])}.png"
                files[p.stem] = search_figures.failure(f, cfg, batch, log, k, frames[k], p)
        files["report"] = report(out / REPORT, cfg, info, table, failures, conf, files)
    return {"candidates": rows, "failures": failures, "summary": table, "confirm": conf,
            "files": files}


def report(path: Path, cfg: SearchConfig, info: dict[str, Any], table: pd.DataFrame,
           failures: pd.DataFrame, conf: pd.DataFrame | None, files: dict[str, Path]) -> Path:
    keys = list(cfg.keys)
    parts = [f"# Failure search: {cfg.name}", ""]
    parts += [f"- **{k}**: {v}" for k, v in info.items()]
    parts += [f"- **controller**: {cfg.scenario.controller.name} (perception "
              f"{cfg.scenario.perception.source}), preset {cfg.scenario.preset}",
              f"- **method**: {cfg.method} (baseline: {cfg.baseline}), population "
              f"{cfg.population} × {cfg.repeats} repeats = {cfg.generation} episodes per call",
              "- **box**: " + ", ".join(f"{d.key} {d.bounds()}" for d in cfg.box),
              f"- **valid share of the box**: {cfg.valid_share:.0%} (invalid candidates are "
              "scored as invalid and not run)", "",
              "## Summary", "", _md(table), ""]
    if conf is not None and len(conf):
        parts += [f"Confirmed: {int(conf['confirmed'].sum())} of {len(conf)} failures fail "
                  f"again in ≥ {CONFIRMED:.0%} of {int(conf['episodes'].iloc[0])} new seeds.", ""]
    if "convergence" in files:
        parts += ["## Convergence", "", "![convergence](convergence.png)", "",
                  "## Candidates by outcome", "", "![pairs](pairs.png)", ""]
    parts += ["## Distinct failures (ranked)", ""]
    if len(failures):
        cols = ["rank", "method", "members", "fail_rate", "margin", *keys, "first_failing",
                "reasons"] + (["confirm_rate"] if "confirm_rate" in failures else [])
        parts += [_md(failures[cols].head(20)), "",
                  "Replay one: `python -m mjxrow.worlds --from-search RUN --rank K`.", ""]
        for k in range(1, cfg.top + 1):
            if f"failure_{k}" in files:
                parts += [f"### Failure {k}", "", f"![failure {k}](failure_{k}.png)", ""]
    else:
        parts += ["No failure found.", ""]
    mjxrow_files.atomic_write_text(path, "\n".join(parts))
    return path


def record(path: str | Path, cfg: SearchConfig, res: dict[str, Any], command: str,
           wall_s: float, device: str) -> list[dict[str, Any]]:
    """Append the search's figures to benchmarks.jsonl (stage `search`): the distinct failing
    fields the search method found (those confirmed, when --confirm ran), and each method's
    failing episodes per 1,000. Returns the rows."""
    table = res["summary"].set_index("method")
    conf = res.get("confirm")
    base = {"date": datetime.date.today().isoformat(), "device": device, "stage": "search",
            "batch": cfg.generation, "command": command, "compile_s": round(res["compile_s"], 1),
            "run_s": round(float(table["time_s"].sum()) - res["compile_s"], 1),
            "wall_s": round(wall_s, 1), "budget_episodes": cfg.episodes,
            "budget_minutes": cfg.minutes}
    own = table.loc[cfg.method] if cfg.method in table.index else None
    rows = []
    if own is not None:
        if conf is not None and len(conf):
            value, what = int(conf["confirmed"].sum()), (
                f"distinct failing fields confirmed (≥ {CONFIRMED:.0%} of "
                f"{int(conf['episodes'].iloc[0])} new seeds; {len(conf)} tried)")
        else:
            value, what = int(own["distinct_failures"]), "distinct failing fields"
        rows.append({**base, "config": f"{cfg.name}: {what}, {cfg.method}", "value": value,
                     "unit": "fields", "episodes": int(own["episodes"]),
                     "search_s": float(own["time_s"])})
    for name, r in table.iterrows():
        rows.append({**base, "config": f"{cfg.name}: failing episodes per 1,000, {name}",
                     "value": round(float(r["failing_per_1000"]), 2), "unit": "per 1,000 episodes",
                     "episodes": int(r["episodes"])})
    with open(path, "a") as f:
        for row in rows:
            f.write(json.dumps(row) + "\n")
    return rows
