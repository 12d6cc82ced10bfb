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


# ---------------------------------------------------------------------------------------------
# Titles and labels fit; signed and bounded colour scales; smoke runs say so

LONG = ("a deliberately long label of a toy metric that no figure of the default size can hold "
        "on one line")


def texts_outside(fig):
    """The titles, axis and colour-bar labels and texts of `fig` whose drawn extent leaves the
    figure, and "ticks of <axes>" where an axes' drawn tick labels do."""
    fig.draw_without_rendering()
    renderer, box = fig.canvas.get_renderer(), fig.bbox

    def out(e):
        return e.x0 < box.x0 - 0.5 or e.x1 > box.x1 + 0.5 or e.y0 < box.y0 - 0.5 or \
            e.y1 > box.y1 + 0.5

    texts = [fig._suptitle, fig._supxlabel, *fig.texts]
    for ax in fig.axes:
        texts += [ax.title, ax.xaxis.label, ax.yaxis.label, *ax.texts]
    bad = [t.get_text() for t in dict.fromkeys(texts) if t is not None and t.get_visible() and
           t.get_text().strip() and out(t.get_window_extent(renderer))]
    return bad + [f"ticks of {ax.get_label()}" for ax in fig.axes
                  if out(ax.get_tightbbox(renderer))]


def colourbar_label(fig):
    return fig.axes[0].images[0].colorbar.ax.yaxis.label


def test_titles_and_colour_bar_labels_fit_in_the_figure():
    import matplotlib.pyplot as plt

    from mjxrow.rollout import metrics as M

    s = summary([[0.0, 1.0], [1.0, 1.0]])
    s["toy"], s["toy_lo"], s["toy_hi"] = s["mae"], s["mae"] - 0.01, s["mae"] + 0.01
    s["excluded"], s["excluded_lo"], s["excluded_hi"] = 0.1, 0.0, 0.3
    s["cha"], s["cha_lo"], s["cha_hi"] = s["mae"] - 0.05, s["mae"] - 0.1, s["mae"]
    s["preset"] = ["zucchini", "pear", "zucchini", "pear"]
    M.register(M.Metric("toy", lambda log, dt: log.steps * dt, LONG, "m", "{:.3f}",
                        better="lower", bounds=(0.0, np.inf), env=False))
    try:
        title = "a sweep with a rather long name (smoke)"
        figs = [R.heatmap_figure(s, m, "field.d_rr", "field.terrain_dh", title)
                for m in ("excluded", "mae", "cha", "toy")]
        figs.append(R.heatmap_figure(s, "toy", "field.d_rr", "field.terrain_dh", title,
                                     facet="preset"))
        figs += [R.line_figure(s, m, "field.d_rr", title) for m in ("excluded", "toy")]
        for fig in figs:
            head = fig.get_suptitle() or fig.axes[0].get_title()
            assert "(smoke)" in head and "\n" in head  # wrapped, not cut
            assert texts_outside(fig) == [], head
        # the note under a map with hatched cells lies below the x label, not across it
        renderer = figs[1].canvas.get_renderer()
        note = figs[1]._supxlabel
        assert note is not None and note.get_text().startswith("hatched")
        assert note.get_window_extent(renderer).y1 <= \
            figs[1].axes[0].xaxis.label.get_window_extent(renderer).y0
        plt.close("all")
        fig = R.heatmap_figure(s, "toy", "field.d_rr", "field.terrain_dh", title)
        assert "\n" in colourbar_label(fig).get_text()
        assert " ".join(colourbar_label(fig).get_text().split()).startswith(LONG)
        plt.close(fig)
    finally:
        M.unregister("toy")


def test_signed_metric_has_a_diverging_scale_centred_on_zero():
    import matplotlib.pyplot as plt

    s = summary([[1.0, 1.0], [1.0, 1.0]])
    s["cha"] = [-0.05, -0.01, 0.02, 0.03]
    fig = R.heatmap_figure(s, "cha", "field.d_rr", "field.terrain_dh")
    im = fig.axes[0].images[0]
    assert im.norm.vmin == pytest.approx(-0.05) and im.norm.vmax == pytest.approx(0.05)
    assert im.cmap.name == "RdBu_r"
    assert np.all(np.asarray(im.cmap(im.norm(0.0)))[:3] > 0.9)  # white at 0
    assert 0.0 in list(im.colorbar.get_ticks())
    assert any(np.allclose(ln.get_ydata(), 0.0) for ln in im.colorbar.ax.lines)  # a line at 0
    plt.close(fig)
    # rounding noise about 0 still gets a scale symmetric about 0 of ten printed steps
    assert R.colour_range(np.array([0.0001, 0.0002]), "{:.3f}", signed=True) == \
        pytest.approx((-0.00515, 0.00515))
    # a metric without a zero best keeps its sequential map
    fig = R.heatmap_figure(s, "mae", "field.d_rr", "field.terrain_dh")
    assert fig.axes[0].images[0].cmap.name == "viridis_r"
    plt.close(fig)


def test_colour_scale_stays_within_the_metric_bounds():
    import matplotlib.pyplot as plt

    s = summary([[1.0, 1.0], [1.0, 1.0]])
    s["mae"] = [0.001, 0.0012, 0.0014, 0.0011]  # narrower than ten steps of {:.3f}
    fig = R.heatmap_figure(s, "mae", "field.d_rr", "field.terrain_dh")
    im = fig.axes[0].images[0]
    assert (im.norm.vmin, im.norm.vmax) == pytest.approx((0.0, 0.01))  # not -0.0038 .. 0.0062
    assert min(im.colorbar.ax.get_ylim()) >= 0.0
    plt.close(fig)
    inf = np.inf
    assert R.colour_range(np.array([1.0, 1.002]), "{:.3f}", (1.0, inf)) == pytest.approx((1.0,
                                                                                           1.01))
    assert R.colour_range(np.array([0.999, 1.0]), "{:.2f}", (0.0, 1.0)) == pytest.approx((0.9,
                                                                                          1.0))
    assert R.colour_range(np.array([0.2, 0.4]), "{:.2f}", (0.0, inf)) == (0.2, 0.4)


def smoke_results():
    rows = []
    for c, (d, dh) in enumerate([(1.5, 0.0), (1.5, 0.2), (2.5, 0.0), (2.5, 0.2)]):
        for e in range(2):
            rows.append({"cell": c, "episode": e, "field.d_rr": d, "field.terrain_dh": dh,
                         "success": True, "reason": "goal", "mae": 0.01 * (c + e),
                         "cha": 0.01 * (c - e - 1)})
    return pd.DataFrame(rows)


@pytest.mark.parametrize("command, smoke", [
    ("python -m mjxrow.sweep s.yaml --smoke --out o", True),
    ("python -m mjxrow.sweep s.yaml --smo", True),
    ("python -m mjxrow.sweep s.yaml --out o_smoke", False),
    ("(API call)", False)])
def test_smoke_report_says_its_numbers_are_not_results(tmp_path, monkeypatch, command, smoke):
    from mjxrow.sweep import config as C

    titles = []

    def surfaces(summary, axes, metrics, out, title="", pool=None):
        titles.append(title)
        return R.surfaces(summary, axes, metrics[:1], out, title, pool)

    monkeypatch.setattr(report, "surfaces", surfaces)
    cfg = C.from_dict({"name": "fake", "perception": {"source": "ground_truth"},
                       "field": {"d_rr": [1.5, 2.5], "terrain_dh": [0.0, 0.2]}})
    files = report.write_outputs(smoke_results(), cfg, tmp_path, {"command": command})
    lines = files["report"].read_text().splitlines()
    note = "Smoke run: a tiny configuration that checks the pipeline; its numbers are not results."
    assert (note in lines[2]) == smoke and (note in "\n".join(lines)) == smoke
    assert lines[0] == "# Sweep report: fake" + (" (smoke)" if smoke else "")
    assert titles == ["fake (smoke)" if smoke else "fake"]
    assert report.is_smoke({"smoke": True, "command": "(API call)"})


def test_cli_smoke_report(tmp_path, monkeypatch):
    """`python -m mjxrow.sweep ... --smoke`, with a fake evaluator: report.md says so."""
    import yaml

    from mjxrow.sweep import groups as SG
    from mjxrow.sweep import run as S

    def fake(group, cfg, on_batch_done):
        rows = pd.DataFrame([{"cell": c, "episode": e, "success": True, "reason": "goal",
                              "mae": 0.01 * e, "cha": 0.0} for c, e in group.episodes])
        on_batch_done(rows)
        return rows

    monkeypatch.setattr(SG, "evaluate_group", fake)
    monkeypatch.setenv("MJXROW_FIGURE_WORKERS", "0")
    path = tmp_path / "s.yaml"
    path.write_text(yaml.safe_dump({"name": "fake", "perception": {"source": "ground_truth"},
                                    "field": {"d_rr": [1.6, 2.4], "terrain_dh": [0.0, 0.2]}}))
    assert S.main([str(path), "--smoke", "--out", str(tmp_path / "o"), "--no-progress"]) == 0
    text = (tmp_path / "o" / "report.md").read_text()
    assert text.startswith("# Sweep report: fake (smoke)\n\n**Smoke run: a tiny configuration")
