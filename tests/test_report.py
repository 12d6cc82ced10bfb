"""Honest figures and tables: failed cells are marked on quality heatmaps, colour scales are not
stretched over rounding noise, counts of the episodes a mean is taken over are shown."""

import numpy as np
import pandas as pd
import pytest
from PIL import Image

from mjxrow.sweep import figures as R
from mjxrow.sweep import report


def summary(success):
    """A 2 × 2 grid; MAE lowest where every episode collided (as at d_rr = 1.5 m)."""
    rows = []
    for i, d in enumerate((1.5, 2.5)):
        for j, dh in enumerate((0.0, 0.2)):
            s = success[i][j]
            rows.append({"cell": 2 * i + j, "field.d_rr": d, "field.terrain_dh": dh, "n": 8,
                         "success": s, "mae": 0.01 if d == 1.5 else 0.05 + dh,
                         "mae_lo": 0.0, "mae_hi": 0.1, "mae_n": 8,
                         "v_mean": 0.5 - 0.00025 * j, "v_mean_lo": 0.49, "v_mean_hi": 0.51,
                         "v_mean_n": 8})
    return pd.DataFrame(rows)


def pixels(path):
    return np.asarray(Image.open(path).convert("L"), np.float32)


def test_failed_cells_are_hatched_on_quality_maps(tmp_path):
    clean = R.heatmap(summary([[1.0, 1.0], [1.0, 1.0]]), "mae", "field.d_rr",
                      "field.terrain_dh", tmp_path / "clean.png")
    failed = R.heatmap(summary([[0.0, 0.0], [1.0, 1.0]]), "mae", "field.d_rr",
                       "field.terrain_dh", tmp_path / "failed.png")
    a, b = pixels(clean), pixels(failed)
    assert a.shape == b.shape
    diff = np.abs(a - b) > 40
    # the marks fall in the left column (d_rr = 1.5), not in the right one
    cols = np.nonzero(diff.any(0))[0]
    assert diff.sum() > 500 and cols.min() < a.shape[1] / 2
    # success itself is never hatched: the same map with or without failures in the title
    s1 = R.heatmap(summary([[0.0, 0.0], [1.0, 1.0]]), "success", "field.d_rr",
                   "field.terrain_dh", tmp_path / "s.png")
    assert s1.exists()


def test_colour_range_ignores_rounding_noise():
    assert R.colour_range(np.array([0.49975, 0.5]), "{:.2f}") == pytest.approx((0.449875, 0.549875))
    assert R.colour_range(np.array([0.1, 0.9]), "{:.2f}") == (0.1, 0.9)
    lo, hi = R.colour_range(np.array([3.0, 3.0]), "{:.3g}")
    assert lo < 3.0 < hi


def test_summary_markdown_counts_left_out_episodes():
    s = summary([[1.0, 1.0], [1.0, 1.0]])
    s.loc[0, "mae_n"] = 5
    text = report.summary_markdown(s, ["field.d_rr", "field.terrain_dh"], ["mae"])
    assert "(n = 5 of 8)" in text and text.count("(n = ") == 1


def test_every_metric_has_a_unit_in_the_docs():
    from pathlib import Path

    from mjxrow.rollout import metrics as M

    doc = (Path(__file__).parents[1] / "docs" / "guarantees.md").read_text()
    table = doc.split("## Units of results.csv")[1].split("\n## ")[0]
    for m in M.METRICS:
        assert f"`{m}`" in table, m


def test_summary_gives_n_per_metric_and_leaves_excluded_out():
    """One cell, four episodes: one excluded (NaN trajectory metrics), one collided."""
    results = pd.DataFrame({
        "cell": 0, "field.d_rr": 1.5, "episode": range(4),
        "success": [True, True, False, False], "excluded": [False, False, False, True],
        "reason": ["goal", "goal", "collision", "flipped"],
        "mae": [0.1, 0.2, 0.3, np.nan], "time": [10.0, 12.0, np.nan, np.nan]})
    s = report.summary_table(results, ["field.d_rr"], ["success", "excluded", "reason", "mae",
                                                  "time"])
    row = s.iloc[0]
    assert row["n"] == 4 and row["mae_n"] == 3 and row["time_n"] == 2 and row["success_n"] == 4
    assert row["mae"] == pytest.approx(0.2) and row["excluded"] == pytest.approx(0.25)
    assert row["mae_lo"] >= 0.0


def test_figures_drawn_in_worker_processes_equal_those_drawn_in_place(tmp_path):
    """figure_pool's processes draw the same PNGs, pixel for pixel, as drawing in place."""
    s = summary([[0.0, 1.0], [1.0, 1.0]])
    axes, metrics = ["field.d_rr", "field.terrain_dh"], ["mae", "success", "v_mean"]
    (tmp_path / "pool").mkdir()
    (tmp_path / "here").mkdir()
    with R.figure_pool(workers=2) as pool:
        assert pool is not None
        drawn = R.surfaces(s, axes, metrics, tmp_path / "pool", "t", pool=pool)
    here = R.surfaces(s, axes, metrics, tmp_path / "here", "t")
    assert list(drawn) == metrics == list(here)
    for m in metrics:
        assert drawn[m].parent == tmp_path / "pool"
        assert np.array_equal(pixels(drawn[m]), pixels(here[m])), m
    with R.figure_pool(enabled=False, workers=2) as pool:
        assert pool is None
