"""The figures of a sweep (matplotlib Agg): one PNG per metric, a heatmap over two swept axes or a
line with its 95 % interval over one, and the processes that draw them side by side
(`figure_pool`). Axis names; a metric's label, unit, format, better direction and bounds come
from its record in the metric registry (`rollout.metrics.METRICS`), for figures and tables
alike. Long titles and labels are wrapped to the figure (`_fit`): nothing is cut off."""

from __future__ import annotations

import contextlib
import math
import multiprocessing
import os
import signal
import textwrap
import threading
import time
from collections.abc import Iterator
from concurrent.futures import Executor, ProcessPoolExecutor
from concurrent.futures.process import BrokenProcessPool
from pathlib import Path
from typing import Any

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402
import numpy as np  # noqa: E402
import pandas as pd  # noqa: E402
from matplotlib.patches import Rectangle  # noqa: E402

from mjxrow.rollout import metrics as rollout_metrics  # noqa: E402

AXIS_LABELS = {"field.d_rr": "row spacing d_rr [m]", "field.d_RR": "group spacing d_RR [m]",
               "field.d_pp": "plant spacing d_pp [m]", "field.terrain_dh": "terrain |ΔH| [m]",
               "field.row_length": "row length [m]", "field.slope_x": "slope dz/dx [-]",
               "field.slope_y": "lateral slope dz/dy [-]", "preset": "crop preset",
               "field.terrain_scale": "terrain roughness scale [m]"}


def metric_info(m: str) -> tuple[str, str, str, str | None]:
    """(label, unit, format, better) of the registered metric `m`; a column that is no
    registered metric: its name, no unit, three significant digits, no better direction."""
    metric = rollout_metrics.METRICS.get(m)
    if metric is None:
        return m, "", "{:.3g}", None
    return metric.label, metric.unit, metric.fmt, metric.better


def axis_label(a: str) -> str:
    return AXIS_LABELS.get(a, a)


def fmt_tick(v: Any) -> str:
    return f"{v:g}" if isinstance(v, (int, float, np.number)) else str(v)


def _numeric(vals) -> bool:
    return all(isinstance(v, (int, float, np.number)) and not isinstance(v, bool) for v in vals)


def _wrap(text, inches: float) -> None:
    """Wrap a Text artist's string to lines of about `inches` at its font size (an average
    character is taken as 0.6 em, a little wider than DejaVu Sans's)."""
    chars = max(12, int(inches * 72 / (0.6 * text.get_fontsize())))
    text.set_text("\n".join(textwrap.fill(t, chars) for t in text.get_text().split("\n")))


def _fit(fig, texts: list, tries: int = 4) -> None:
    """Grow `fig` until every one of `texts` (titles, axis and colour-bar labels) lies inside
    it: a safety net behind `_wrap` (constrained layout makes room beside the axes, but cannot
    shrink a title wider than the figure or a colour-bar label taller than it)."""
    for _ in range(tries):
        fig.draw_without_rendering()
        renderer = fig.canvas.get_renderer()
        box = fig.bbox
        grow_w = grow_h = 1.0
        for t in texts:
            if t is None or not t.get_visible() or not t.get_text():
                continue
            e = t.get_window_extent(renderer)
            if e.x0 < box.x0 or e.x1 > box.x1:
                grow_w = max(grow_w, 1.05 * e.width / box.width, 1.1)
            if e.y0 < box.y0 or e.y1 > box.y1:
                grow_h = max(grow_h, 1.05 * e.height / box.height, 1.1)
        if grow_w == grow_h == 1.0:
            return
        w, h = fig.get_size_inches()
        fig.set_size_inches(w * grow_w, h * grow_h)


def _save(fig, path: Path) -> Path:
    """Atomic PNG write: temp file in the same folder, then os.replace."""
    tmp = path.with_name(f".{path.name}.{os.getpid()}.tmp")
    fig.savefig(tmp, format="png", dpi=110)
    plt.close(fig)
    os.replace(tmp, path)
    return path


def _cmap(better):
    """A diverging map, white at 0, for a signed metric (better 'zero'); else viridis with the
    better end bright."""
    if better == "zero":
        return "RdBu_r"
    return "viridis_r" if better == "lower" else "viridis"


HINTS = {"higher": " (higher is better)", "lower": " (lower is better)", "zero": " (0 is best)"}


def colour_range(values: np.ndarray, fmt: str,
                 bounds: tuple[float, float] = (-math.inf, math.inf),
                 signed: bool = False) -> tuple[float, float]:
    """(vmin, vmax) of a colour scale over finite `values`: their range, widened to at least
    ten steps of the printed precision (`{:.2f}`: 0.1), so that rounding noise (0.49975 to
    0.50000) does not fill the whole scale, then moved inside `bounds` (a metric's valid
    values, Metric.bounds: an MAE scale never runs below 0). `signed`: symmetric about 0,
    ±max |v| (a diverging map centred on 0)."""
    lo, hi = _widened(values, fmt)
    b_lo, b_hi = bounds
    if signed:
        a = max(abs(lo), abs(hi))
        lo, hi = max(-a, b_lo), min(a, b_hi)
    elif lo < b_lo:  # shifted up to the bound, keeping its width where the upper bound allows
        lo, hi = b_lo, min(b_hi, b_lo + (hi - lo))
    elif hi > b_hi:
        lo, hi = max(b_lo, b_hi - (hi - lo)), b_hi
    return (lo, hi) if lo < hi else _widened(values, fmt)


def _widened(values: np.ndarray, fmt: str) -> tuple[float, float]:
    if not values.size:
        return 0.0, 1.0
    lo, hi = float(values.min()), float(values.max())
    digits = fmt.split(".")[-1].rstrip("}") if "." in fmt else ""
    if digits.endswith("f") and digits[:-1].isdigit():
        step = 10.0 ** -int(digits[:-1])
    else:  # significant digits: a step relative to the magnitude
        step = max(abs(lo), abs(hi), 1e-12) * 1e-3
    if hi - lo < 10 * step:
        mid = (lo + hi) / 2
        lo, hi = mid - 5 * step, mid + 5 * step
    return lo, hi


def _panel(ax, grid: np.ndarray, xs, ys, fmt, cmap, vmin, vmax, xlabel, ylabel,
           failed: np.ndarray | None = None, counts: np.ndarray | None = None):
    """One heatmap panel; with `failed` (episodes that did not reach the goal per cell) and
    `counts` (episodes per cell), cells with failures are hatched and say `k/N failed`."""
    im = ax.imshow(grid, origin="lower", aspect="auto", cmap=cmap, vmin=vmin, vmax=vmax)
    ax.set_xticks(range(len(xs)), [fmt_tick(v) for v in xs], rotation=45 if len(xs) > 8 else 0)
    ax.set_yticks(range(len(ys)), [fmt_tick(v) for v in ys])
    ax.set_xlabel(xlabel)
    ax.set_ylabel(ylabel)
    norm = im.norm
    for (j, i), v in np.ndenumerate(grid):
        bad = failed is not None and np.isfinite(failed[j, i]) and failed[j, i] > 0
        if bad:
            ax.add_patch(Rectangle((i - 0.5, j - 0.5), 1, 1, fill=False, hatch="///",
                                   edgecolor="0.5", linewidth=0))
        if np.isfinite(v):
            light = np.asarray(im.cmap(norm(v)))[:3] @ [0.299, 0.587, 0.114] > 0.55
            text = fmt.format(v)
            if bad:
                text += f"\n{failed[j, i]:.0f}/{counts[j, i]:.0f} failed"
            ax.text(i, j, text, ha="center", va="center", fontsize=8 if not bad else 7,
                    color="black" if light or bad else "white",  # bad: on a light box
                    bbox=dict(boxstyle="round,pad=0.1", fc="white", ec="none", alpha=0.6)
                    if bad else None)
        else:
            ax.text(i, j, "–" if not bad else f"–\n{failed[j, i]:.0f}/{counts[j, i]:.0f} "
                    "failed", ha="center", va="center", fontsize=8, color="grey")
    return im


def heatmap(summary: pd.DataFrame, metric: str, x: str, y: str, path: str | Path,
            title: str = "", facet: str | None = None) -> Path:
    """One PNG of `heatmap_figure` (the same arguments)."""
    return _save(heatmap_figure(summary, metric, x, y, title, facet), Path(path))


def heatmap_figure(summary: pd.DataFrame, metric: str, x: str, y: str, title: str = "",
                   facet: str | None = None):
    """`metric`'s cell means over axes `x` (columns) and `y` (rows), values written in the
    cells; one panel per value of `facet` if given. Cells are averaged over other columns.
    Returns the matplotlib Figure.

    For a trajectory metric (Metric.trajectory) a cell in which some episodes did not reach the
    goal is hatched and says how many of its episodes failed: its value averages collided or
    stuck episodes and is not comparable with a clean cell's. The colour scale spans at least
    ten steps of the printed precision and stays within the metric's bounds (`colour_range`),
    0 to 1 for a rate (Metric.binary). A signed metric (better 'zero', CHA) gets a diverging
    map, white at 0, over ±max |v|, with 0 marked on the colour bar."""
    name, unit, fmt, better = metric_info(metric)
    record = rollout_metrics.METRICS.get(metric)  # None: a column that is no registered metric
    xs = list(dict.fromkeys(summary[x]))
    ys = list(dict.fromkeys(summary[y]))
    fs = list(dict.fromkeys(summary[facet])) if facet else [None]
    mark = record is not None and record.trajectory and "success" in summary
    grids, fails, counts = [], [], []
    for f in fs:
        sub = summary if facet is None else summary[summary[facet] == f]
        g = np.full((len(ys), len(xs)), np.nan)
        k, n = np.full_like(g, np.nan), np.full_like(g, np.nan)
        for (xv, yv), rows in sub.groupby([x, y], sort=False):
            at = ys.index(yv), xs.index(xv)
            g[at] = rows[metric].mean()
            if mark:
                k[at] = float(np.round((rows["n"] * (1 - rows["success"])).sum()))
                n[at] = float(rows["n"].sum())
        grids.append(g)
        fails.append(k if mark else None)
        counts.append(n)
    finite = np.concatenate([g[np.isfinite(g)] for g in grids] + [np.zeros(0)])
    vmin, vmax = colour_range(finite, fmt, record.bounds if record is not None
                              else (-math.inf, math.inf), signed=better == "zero")
    if record is not None and record.binary:
        vmin, vmax = 0.0, 1.0
    ncol = min(len(fs), 3)
    nrow = -(-len(fs) // ncol)
    w = max(4.5, 0.75 * len(xs) + 2.5)
    h = max(3.5, 0.5 * len(ys) + 2.0)
    fig, axs = plt.subplots(nrow, ncol, figsize=(w * ncol, h * nrow), squeeze=False,
                            layout="constrained")
    im, texts = None, []
    for k, (f, g) in enumerate(zip(fs, grids, strict=True)):
        ax = axs[k // ncol][k % ncol]
        im = _panel(ax, g, xs, ys, fmt, _cmap(better), vmin, vmax, axis_label(x),
                    axis_label(y) if k % ncol == 0 else "", fails[k], counts[k])
        if facet:
            ax.set_title(f"{axis_label(facet)} = {fmt_tick(f)}", fontsize=9)
        for t in (ax.title, ax.xaxis.label, ax.yaxis.label):
            _wrap(t, (w if t is not ax.yaxis.label else h) - 1.0)
            texts.append(t)
    for k in range(len(fs), nrow * ncol):
        axs[k // ncol][k % ncol].axis("off")
    hint = HINTS.get(better, "")
    cb = fig.colorbar(im, ax=axs.ravel().tolist(), shrink=0.9)
    if better == "zero":  # 0 marked: a tick and a line across the bar
        ticks = [t for t in cb.get_ticks() if vmin <= t <= vmax and abs(t) > 1e-9 * vmax]
        cb.set_ticks(sorted([*ticks, 0.0]))
        cb.ax.axhline(0.0, color="black", linewidth=1.0)
    cb.set_label(f"{name} [{unit}]{hint}" if unit else name + hint)
    _wrap(cb.ax.yaxis.label, 0.85 * h * nrow)
    sup = fig.suptitle(f"{title}: {name}" if title else name)
    _wrap(sup, w * ncol - 0.3)
    texts += [sup, cb.ax.yaxis.label]
    if mark and any(np.nansum(k) > 0 for k in fails):  # below the panels, in the layout
        note = fig.supxlabel("hatched: cells where some episodes did not reach the goal (k/N "
                             "failed); their value is not comparable", fontsize=7, color="0.3")
        _wrap(note, w * ncol - 0.3)
        texts.append(note)
    _fit(fig, texts)
    return fig


def line(summary: pd.DataFrame, metric: str, x: str, path: str | Path, title: str = "",
         hue: str | None = None) -> Path:
    """One PNG of `line_figure` (the same arguments)."""
    return _save(line_figure(summary, metric, x, title, hue), Path(path))


def line_figure(summary: pd.DataFrame, metric: str, x: str, title: str = "",
                hue: str | None = None):
    """`metric`'s mean over axis `x` with its 95 % interval as a band (numeric x) or error bars
    (categorical x); one line per value of `hue` if given. Returns the matplotlib Figure."""
    name, unit, _, better = metric_info(metric)
    fig, ax = plt.subplots(figsize=(6.0, 4.0), layout="constrained")
    hues = list(dict.fromkeys(summary[hue])) if hue else [None]
    for hv in hues:
        sub = summary if hue is None else summary[summary[hue] == hv]
        agg = sub.groupby(x, sort=False)[[metric, f"{metric}_lo", f"{metric}_hi"]].mean()
        xs = list(agg.index)
        label = None if hue is None else f"{axis_label(hue)} = {fmt_tick(hv)}"
        m, lo, hi = (agg[c].to_numpy(float) for c in (metric, f"{metric}_lo", f"{metric}_hi"))
        if _numeric(xs):
            xv = np.asarray(xs, float)
            order = np.argsort(xv)
            ax.plot(xv[order], m[order], "o-", label=label)
            ax.fill_between(xv[order], lo[order], hi[order], alpha=0.25)
        else:
            pos = np.arange(len(xs))
            ax.errorbar(pos, m, yerr=[m - lo, hi - m], fmt="o", capsize=4, label=label)
            ax.set_xticks(pos, [str(v) for v in xs])
    ax.set_xlabel(axis_label(x))
    hint = {"higher": " (↑ better)", "lower": " (↓ better)", "zero": " (0 best)"}.get(better, "")
    ax.set_ylabel(f"{name} [{unit}]{hint}" if unit else name + hint)
    if metric in ("success", "collision"):
        ax.set_ylim(-0.03, 1.03)
    if better == "zero":
        ax.axhline(0.0, color="0.4", linewidth=0.8)
    ax.grid(alpha=0.3)
    if hue:
        ax.legend(fontsize=8)
    ax.set_title(f"{title}: {name} (mean, 95 % CI)" if title else f"{name} (mean, 95 % CI)")
    _wrap(ax.title, 5.0)  # centred on the axes, not on the figure
    _wrap(ax.xaxis.label, 5.0)
    _wrap(ax.yaxis.label, 3.4)
    _fit(fig, [ax.title, ax.xaxis.label, ax.yaxis.label])
    return fig


def surface(summary: pd.DataFrame, axes: list[str], metric: str, path: Path,
            title: str = "") -> Path | None:
    """One metric's PNG: a heatmap over the first two axes (panels over the third; further
    axes averaged), or a line plot with CI bands when one axis is swept; None without axes."""
    if len(axes) >= 2:
        return heatmap(summary, metric, axes[0], axes[1], path, title,
                       facet=axes[2] if len(axes) > 2 else None)
    if len(axes) == 1:
        return line(summary, metric, axes[0], path, title)
    return None


def surfaces(summary: pd.DataFrame, axes: list[str], metrics: list[str], out_dir: str | Path,
             title: str = "", pool: Executor | None = None) -> dict[str, Path]:
    """metric → PNG path (`surface` of each metric), drawn side by side in `pool`'s
    processes when one is given (figure_pool), else one after another."""
    out_dir = Path(out_dir)
    paths = {m: out_dir / f"{m}.png" for m in metrics}
    if pool is not None:
        try:
            jobs = {m: pool.submit(surface, summary, axes, m, p, title) for m, p in paths.items()}
            done = {m: j.result() for m, j in jobs.items()}
            return {m: p for m, p in done.items() if p is not None}
        except BrokenProcessPool:  # a worker died (killed, out of memory): draw them here
            pass
    done = {m: surface(summary, axes, m, p, title) for m, p in paths.items()}
    return {m: p for m, p in done.items() if p is not None}


def figure_workers() -> int:
    """Processes the sweep's figure_pool starts: `$MJXROW_FIGURE_WORKERS` if set (0: draw in
    place), else up to 4, leaving two cores to the rest, and none on a host of fewer than 4
    cores, where drawing in place costs less than starting them."""
    env = os.environ.get("MJXROW_FIGURE_WORKERS")
    if env is not None:
        if not env.strip().isdigit():
            raise ValueError(f"MJXROW_FIGURE_WORKERS: expected a whole number ≥ 0, got {env!r}")
        return int(env)
    n = os.cpu_count() or 1
    return min(4, n - 2) if n >= 4 else 0


@contextlib.contextmanager
def figure_pool(enabled: bool = True, workers: int = 0) -> Iterator[Executor | None]:
    """`workers` processes that draw a sweep's PNGs side by side (`surfaces(..., pool=...)`),
    or None (disabled, or fewer than 2 workers). Entered at a sweep's start, they import
    matplotlib and this module (with the metric registry, hence JAX's modules; they never
    touch an accelerator) while the sweep compiles and runs. They are spawned: the caller's
    main module must be a package's `__main__` or guarded by `if __name__ == "__main__":`;
    they know the metrics registered on import (the built-in ones and those of the modules
    imported, the main module's top level included), and draw another metric with its column
    name as label and no unit. They ignore Ctrl-C (the sweep handles it) and end when the
    sweep's process does, however it ends."""
    n = workers
    if not enabled or n < 2:
        yield None
        return
    pool = ProcessPoolExecutor(n, mp_context=multiprocessing.get_context("spawn"),
                               initializer=_figure_worker, initargs=(os.getpid(),))
    try:
        for _ in range(n):  # start every process now, not at the first figure
            pool.submit(time.sleep, 0)
        yield pool
    finally:
        pool.shutdown(wait=True, cancel_futures=True)


def _figure_worker(parent: int) -> None:
    signal.signal(signal.SIGINT, signal.SIG_IGN)

    def orphaned() -> None:  # the sweep ended without closing the pool (os._exit, a kill)
        while os.getppid() == parent:
            time.sleep(0.5)
        os._exit(0)

    threading.Thread(target=orphaned, daemon=True).start()
