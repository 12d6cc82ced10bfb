"""Aggregation of the navigation metrics over episodes, on the host (numpy): every metric's
mean with its confidence interval (Student t, or Wilson for binary metrics, clipped to the
metric's bounds from the registry of `rollout.metrics`), the episodes per termination reason,
and both as a text table."""

from __future__ import annotations

import math
from typing import Any

import numpy as np

from mjxrow.rollout.metrics import METRICS, REASONS, RUNNING


def _t_quantile(p: float, dof: int) -> float:
    from scipy.stats import t as student_t  # scipy ships with jax

    return float(student_t.ppf(p, dof))


def aggregate(table: dict[str, Any], confidence: float = 0.95) -> dict[str, dict[str, float]]:
    """Mean and confidence interval of every numeric metric over episodes (host, numpy).

    table: name → [B] values (as `summarise` returns). Non-finite values (e.g. `time` of failed
    episodes) are left out and `n` says how many values were used. Continuous metrics get a
    Student-t interval, mean ± t_{(1+c)/2, n−1} · s / √n (s with ddof = 1); binary ones
    (`success`, `collision`, any bool array) a Wilson score interval for the proportion.
    `reason` is not averaged: see `reason_counts`.

    Intervals are clipped to the metric's bounds (Metric.bounds: an MSE interval stays ≥ 0).
    Returns name → {mean, lo, hi, n, method}; with n < 2 a t interval is (nan, nan)."""
    if not 0 < confidence < 1:
        raise ValueError(f"confidence: must lie in (0, 1), got {confidence}")
    out: dict[str, dict[str, float]] = {}
    for name, values in table.items():
        if name == "reason":
            continue
        x = np.asarray(values)
        if x.dtype.kind not in "biuf":
            continue
        metric = METRICS.get(name)
        binary = x.dtype == bool or (metric is not None and metric.binary)
        x = x.astype(np.float64).reshape(-1)
        x = x[np.isfinite(x)]
        n = int(x.size)
        if n == 0:
            out[name] = dict(mean=math.nan, lo=math.nan, hi=math.nan, n=0,
                             method="wilson" if binary else "t")
            continue
        mean = float(x.mean())
        if binary:
            z = _normal_quantile(0.5 + confidence / 2)
            centre = (mean + z * z / (2 * n)) / (1 + z * z / n)
            half = z / (1 + z * z / n) * math.sqrt(mean * (1 - mean) / n + z * z / (4 * n * n))
            lo, hi, method = max(centre - half, 0.0), min(centre + half, 1.0), "wilson"
        elif n < 2:
            lo, hi, method = math.nan, math.nan, "t"
        else:
            half = _t_quantile(0.5 + confidence / 2, n - 1) * float(x.std(ddof=1)) / math.sqrt(n)
            lo, hi, method = mean - half, mean + half, "t"
        r_lo, r_hi = metric.bounds if metric is not None else (-math.inf, math.inf)
        lo, hi = min(max(lo, r_lo), r_hi), max(min(hi, r_hi), r_lo)
        out[name] = dict(mean=mean, lo=float(lo), hi=float(hi), n=n, method=method)
    return out


def _normal_quantile(p: float) -> float:
    from statistics import NormalDist

    return NormalDist().inv_cdf(p)


def reason_counts(reason: Any) -> dict[str, int]:
    """Episodes per termination reason: REASONS name → count (host). reason: int codes [B]."""
    r = np.asarray(reason).reshape(-1)
    return {name: int(np.sum(r == code)) for code, name in enumerate(REASONS) if code != RUNNING}


def format_table(table: dict[str, Any], confidence: float = 0.95) -> str:
    """`aggregate` as a text table (CHA also in degrees) with the episodes per reason."""
    lines = [f"{'metric':<12} {'mean':>10}  {f'{confidence:.0%} CI':>24}  {'n':>4}  method",
             "-" * 64]

    def row(name, a, f=1.0):
        lines.append(f"{name:<12} {a['mean'] * f:>10.4g}  [{a['lo'] * f:>10.4g}, "
                     f"{a['hi'] * f:>10.4g}]  {a['n']:>4}  {a['method']}")

    for name, a in aggregate(table, confidence).items():
        row(name, a)
        if name == "cha":
            row("cha [deg]", a, 180.0 / math.pi)
    if "reason" in table:
        counts = reason_counts(table["reason"])
        lines.append("reasons: " + ", ".join(f"{k} {v}" for k, v in counts.items() if v))
    return "\n".join(lines)
