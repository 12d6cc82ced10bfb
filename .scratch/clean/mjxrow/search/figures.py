"""The figures of a search (matplotlib Agg, written atomically): convergence (best margin and
distinct failures against episodes spent, each method), the pair plot of the searched keys
coloured by outcome, and one panel per top failure (first camera frame, its mask, the top-down
trajectory over the plants)."""

from __future__ import annotations

from pathlib import Path
from typing import Any

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402
import numpy as np  # noqa: E402
import pandas as pd  # noqa: E402
from matplotlib.patches import Ellipse  # noqa: E402

from mjxrow import files as mjxrow_files  # noqa: E402
from mjxrow import runtime  # noqa: E402
from mjxrow.rollout import metrics as rollout_metrics  # noqa: E402
from mjxrow.search import objective  # noqa: E402
from mjxrow.search.config import SearchConfig  # noqa: E402

OUTCOME_STYLE = {"pass": dict(c="0.6", alpha=0.35, s=8), "fail": dict(c="tab:red", alpha=0.9, s=14),
                 "invalid": dict(c="tab:blue", alpha=0.3, s=8, marker="x")}
METHOD_MARKER = {"cma_es": "o", "random": "^", "sobol": "s"}


def _save(fig, path: Path) -> Path:
    mjxrow_files.atomic_save(path, lambda tmp: fig.savefig(tmp, format="png", dpi=110))
    plt.close(fig)
    return path


def curves(rows: pd.DataFrame, cfg: SearchConfig, method: str) -> pd.DataFrame:
    """Per generation of `method`: episodes spent, best margin so far, distinct failures so
    far (objective.count_distinct over its failing candidates in the order found)."""
    df = rows[rows["method"] == method]
    if df.empty:
        return pd.DataFrame(columns=["episodes", "best_margin", "mean_margin", "distinct"])
    ucols = [f"u_{j}" for j in range(len(cfg.box))]
    fails = df[df["outcome"] == "fail"]
    counts = objective.count_distinct(fails[ucols].to_numpy(float), cfg.merge_radius)
    by_gen = pd.Series(counts, index=fails["generation"].to_numpy()).groupby(level=0).max()
    g = df.groupby("generation").agg(episodes=("episodes_spent", "max"),
                                     best=("margin", "min"), mean_margin=("margin", "mean"))
    g["best_margin"] = g["best"].cummin()
    g["distinct"] = by_gen.reindex(g.index).ffill().fillna(0).astype(int)
    return g[["episodes", "best_margin", "mean_margin", "distinct"]].reset_index()


def convergence(rows: pd.DataFrame, cfg: SearchConfig, path: Path) -> Path:
    fig, (a, b) = plt.subplots(1, 2, figsize=(10, 3.8), constrained_layout=True)
    for method in rows["method"].unique():
        c = curves(rows, cfg, method)
        style = dict(marker=METHOD_MARKER.get(method, "o"), ms=3, label=method)
        line = a.plot(c["episodes"], c["best_margin"], **style)[0]
        a.plot(c["episodes"], c["mean_margin"], ls="--", lw=0.8, color=line.get_color(),
               label=f"{method}: generation mean")
        b.step(np.r_[0, c["episodes"]], np.r_[0, c["distinct"]], where="post", **style)
    a.axhline(0.0, color="k", lw=0.6, ls=":")
    a.set(xlabel="episodes spent", ylabel="margin (−1: failed)",
          title="best margin so far, and each generation's mean")
    b.set(xlabel="episodes spent", ylabel="distinct failures",
          title=f"distinct failures (merged within {cfg.merge_radius:g})")
    for ax in (a, b):
        ax.grid(alpha=0.3)
        ax.legend()
    fig.suptitle(f"{cfg.name}: {cfg.scenario.controller.name}, {cfg.method} vs {cfg.baseline}")
    return _save(fig, path)


def _axis_values(rows: pd.DataFrame, cfg: SearchConfig, j: int) -> np.ndarray:
    d = cfg.box[j]
    if d.choices:
        return rows[d.key].map({n: i for i, n in enumerate(d.choices)}).to_numpy(float)
    return rows[d.key].to_numpy(float)


def pairs(rows: pd.DataFrame, cfg: SearchConfig, path: Path, most: int = 8) -> Path:
    """Scatter of every pair of searched keys (the first `most`), candidates coloured by
    outcome, marker by method; the diagonal: histograms of failing and passing ones."""
    n = min(len(cfg.box), most)
    size = max(2.0, 11.0 / max(n, 1))
    fig, axes = plt.subplots(n, n, figsize=(size * n + 1, size * n + 0.5), squeeze=False,
                             constrained_layout=True)
    vals = [_axis_values(rows, cfg, j) for j in range(n)]
    for i in range(n):
        for j in range(n):
            ax = axes[i][j]
            if i == j:
                for outcome, colour in (("pass", "0.6"), ("fail", "tab:red")):
                    sel = rows["outcome"].to_numpy() == outcome
                    if sel.any():
                        ax.hist(vals[j][sel], bins=20, color=colour, alpha=0.6)
            else:
                for (method, outcome), grp in rows.groupby(["method", "outcome"]):
                    sel = grp.index.to_numpy()
                    style = dict(OUTCOME_STYLE[outcome])
                    style.setdefault("marker", METHOD_MARKER.get(method, "o"))
                    ax.scatter(vals[j][rows.index.get_indexer(sel)],
                               vals[i][rows.index.get_indexer(sel)], linewidths=0.5, **style)
            if i == n - 1:
                ax.set_xlabel(cfg.box[j].key, fontsize=8)
            if j == 0:
                ax.set_ylabel(cfg.box[i].key, fontsize=8)
            ax.tick_params(labelsize=7)
            if cfg.box[j].choices:
                ax.set_xticks(range(len(cfg.box[j].choices)), cfg.box[j].choices, rotation=30)
    fig.suptitle(f"{cfg.name}: candidates (grey pass, red fail, blue × invalid; "
                 + ", ".join(f"{m} {METHOD_MARKER.get(m, 'o')}" for m in rows["method"].unique())
                 + ")", fontsize=9)
    return _save(fig, path)


def failure(f: pd.Series, cfg: SearchConfig, batch: Any, log: Any, k: int,
            frame: tuple[np.ndarray, np.ndarray], path: Path) -> Path:
    """One failure: the camera's first frame, the mask the controller saw, and the top-down
    view of the episode `first_failing` (its plants, lane, trajectory, start and goal)."""
    rgb, mask = frame
    field = runtime.to_host(batch.fields)
    fig, (a, b, c) = plt.subplots(1, 3, figsize=(13, 4.2), constrained_layout=True,
                                  gridspec_kw=dict(width_ratios=[1, 1, 2.2]))
    a.imshow(rgb)
    a.set_title("first camera frame")
    b.imshow(mask, cmap="gray")
    b.set_title("mask the controller saw" if cfg.scenario.perception.source == "learned"
                else "plant mask (ground truth)")
    for ax in (a, b):
        ax.set_xticks([])
        ax.set_yticks([])
    pose = np.asarray(log.pose[k])
    alive = np.asarray(log.alive[k])
    xy = pose[alive, :2]
    start, goal = np.asarray(log.start[k]), np.asarray(log.goal[k])
    act = np.asarray(field.plant_active[k])
    pts = np.asarray(field.plant_pos[k])[act]
    size = np.asarray(field.plant_size[k])[act]
    lo = np.minimum(start[:2], goal) - 2.5
    hi = np.maximum(start[:2], goal) + 2.5
    if len(xy):
        lo, hi = np.minimum(lo, xy.min(0) - 1.0), np.maximum(hi, xy.max(0) + 1.0)
    sel = np.all((pts[:, :2] > lo) & (pts[:, :2] < hi), axis=1)
    for p, s in zip(pts[sel], size[sel], strict=True):
        c.add_patch(Ellipse(p[:2], s[0], s[1], color="tab:green", alpha=0.5))
    if getattr(field, "weed_active", None) is not None and np.asarray(field.weed_active).ndim:
        wa = np.asarray(field.weed_active[k])
        w = np.asarray(field.weed_pos[k])[wa]
        c.scatter(w[:, 0], w[:, 1], s=4, c="olive", alpha=0.6, label="weeds")
    c.plot(xy[:, 0], xy[:, 1], "-", color="tab:red", lw=1.5, label="trajectory")
    c.plot(*start[:2], "ko", ms=5, label="start")
    c.plot(*goal, "k*", ms=10, label="goal")
    c.set_xlim(lo[0], hi[0])
    c.set_ylim(lo[1], hi[1])
    c.set_aspect("equal")
    c.set(xlabel="x [m]", ylabel="y [m]")
    c.legend(fontsize=7, loc="upper left")
    reason = rollout_metrics.REASONS[int(np.asarray(log.reason[k]))]
    c.set_title(f"episode {int(f['first_failing'])}: {reason}")
    vals = ", ".join(f"{d.key.split('.', 1)[1]}={_short(f[d.key])}" for d in cfg.box)
    fig.suptitle(f"failure {int(f['rank'])} ({f['method']}, fails {f['fail_rate']:.0%} of "
                 f"{cfg.repeats}): {vals}", fontsize=9)
    return _save(fig, path)


def _short(v: Any) -> str:
    return f"{v:.3g}" if isinstance(v, (float, np.floating)) else str(v)
