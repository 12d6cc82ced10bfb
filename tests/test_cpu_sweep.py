"""A sweep on a CPU keeps its results as it goes: `batch_size: auto` runs whole cells of about
32 episodes per call there, an interrupt after the first batch keeps that batch's cells (a real
rollout, not a fake), and the estimate before the run says what it assumes."""

import time

import pandas as pd
import pytest

from mjxrow.sweep import cells as sweep_cells
from mjxrow.sweep import config as sweep_config
from mjxrow.sweep import estimate as sweep_estimate
from mjxrow.sweep import groups as sweep_groups
from mjxrow.sweep import run as sweep_run
from mjxrow.sweep import writer as sweep_writer

TINY = {"name": "cpu", "seeds": 2, "batch_size": 2, "controller": {"name": "oracle"},
        "perception": {"source": "ground_truth"}, "preset": "vineyard",
        "field": {"d_rr": [2.4, 2.6, 2.8], "terrain_length": 14.0, "row_length": 10.0,
                  "terrain_width": 8.0, "stone_density": 0.0, "branch_density": 0.0},
        "camera": {"width": 16, "height": 16}, "render": {"shadows": False},
        "sim": {"path_length": 1.5}, "episode": {"max_time": 1.0}}


@pytest.mark.parametrize(("setting", "seeds", "episodes", "platform", "devices", "want"), [
    ("auto", 6, 216, "cpu", 1, 36),  # sweeps.yaml on a CPU: six cells a call
    ("auto", 100, 500, "cpu", 1, 100),  # never part of a cell
    ("auto", 2, 8, "cpu", 1, 8),  # never more than the group's episodes
    ("auto", 6, 216, "gpu", 1, 216),  # a GPU takes the whole group
    ("auto", 6, 40_000, "gpu", 2, 8192),  # up to GPU_BATCH per device
    (72, 6, 216, "cpu", 1, 72),  # a number is a number
    (500, 6, 216, "gpu", 1, 216),
])
def test_batch_size(setting, seeds, episodes, platform, devices, want):
    assert sweep_groups.batch_size(setting, seeds, episodes, platform, devices) == want


def test_auto_is_the_default_and_a_bad_value_is_named():
    assert sweep_config.from_dict({}).batch_size == "auto"
    assert sweep_config.from_dict({"batch_size": 7}).batch_size == 7
    with pytest.raises(sweep_config.ConfigError, match="batch_size"):
        sweep_config.from_dict({"batch_size": "many"})
    with pytest.raises(sweep_config.ConfigError, match="batch_size"):
        sweep_config.from_dict({"batch_size": 0})


def test_an_interrupt_after_the_first_batch_keeps_its_cells(tmp_path):
    cfg = sweep_config.from_dict(TINY)
    batches = []

    def evaluate(group, cfg, on_batch_done):
        def after(rows):
            on_batch_done(rows)
            batches.append(rows)
            raise KeyboardInterrupt  # Ctrl-C right after the first batch

        return sweep_groups.evaluate_group(group, cfg, after)

    with pytest.raises(KeyboardInterrupt):
        sweep_run.run(cfg, tmp_path, evaluate=evaluate, progress=False, figures=False)
    assert len(batches) == 1 and len(batches[0]) == 2  # one batch: one cell of two episodes
    kept = sweep_cells.finished_cells(tmp_path / "cells", cfg.seeds)
    assert len(kept) == 1
    results = pd.read_csv(tmp_path / "results.csv")
    assert sorted(results["episode"]) == [0, 1] and results["cell"].nunique() == 1
    res = sweep_run.run(cfg, tmp_path, progress=False, figures=False)  # the rest, resumed
    assert res["skipped"] == 1 and res["ran"] == 4


def test_the_estimate_says_what_it_assumes():
    cfg = sweep_config.from_dict(TINY)
    groups = sweep_groups.plan(cfg)
    est = sweep_estimate.estimate(groups, cfg.seeds, "auto", "cpu", "cpu")
    assert est.batch == 6  # all three cells: fewer episodes than a CPU batch
    assert "control steps/s" in est.text() and "on cpu" in est.text()
    none = sweep_estimate.estimate(groups, cfg.seeds, 2, "a device never measured", "gpu")
    assert none.seconds is None and "no time estimate" in none.text()
    assert "no closed-loop measurement on a device never measured" in none.text()


def test_the_eta_after_the_first_batch_is_within_30_percent(tmp_path):
    """Four batches of equal work (every episode runs to its timeout): the time left that the
    bar shows after the first batch, against the time the other three took. The suite's other
    worker shares the two cores and its load changes from second to second, so a run is
    repeated (up to three times, the program compiled once) until one is within 30 %; an ETA
    that counted compilation, the group's one-time build or the wrong episodes misses every
    time."""
    raw = {**TINY, "field": {**TINY["field"], "d_rr": [2.4, 2.5, 2.6, 2.7]},
           "episode": {"max_time": 120.0}, "sim": {"path_length": 8.0},
           "robot": {"v_max": 0.05}}  # 1,800 steps, every episode to its timeout
    cfg = sweep_config.from_dict(raw)
    tries = []
    for attempt in range(3):
        marks = []

        def evaluate(group, cfg, on_batch_done, marks=marks):
            def after(rows):
                on_batch_done(rows)
                marks.append((time.perf_counter(), on_batch_done.eta_seconds()))

            return sweep_groups.evaluate_group(group, cfg, after)

        sweep_run.run(cfg, tmp_path / str(attempt), evaluate=evaluate, progress=False,
                      figures=False)
        assert len(marks) == 4
        (t1, eta), (t_end, _) = marks[0], marks[-1]
        assert eta is not None
        tries.append((eta, t_end - t1))
        if abs(eta - (t_end - t1)) <= 0.3 * (t_end - t1):
            break
    print("eta, took [s]:", tries)
    eta, took = tries[-1]
    assert abs(eta - took) <= 0.3 * took, tries


class _Bar:
    def __init__(self):
        self.n, self.postfix = 0, ""

    def update(self, k):
        self.n += k

    def set_postfix_str(self, s, refresh=True):
        self.postfix = s


def test_the_bar_moves_inside_a_batch(tmp_path):
    """On a CPU a shown bar counts the episodes of a running batch as they end (between its
    chunks of control steps, `groups.evaluate_episodes`' in_batch) and says the control step;
    the batch's rows then add only the rest."""
    cfg = sweep_config.from_dict(TINY)
    group = sweep_groups.plan(cfg)[0]
    bar = _Bar()
    quiet = sweep_writer.CellWriter(group, 100, tmp_path, bar)
    assert quiet.in_batch is None  # no bar, or a GPU: one program per batch
    w = sweep_writer.CellWriter(group, 100, tmp_path, bar, in_batch=True)
    w.in_batch(50, 0, 6)
    assert bar.n == 0 and "control step 50" in bar.postfix and "0 of 6" in bar.postfix
    w.in_batch(100, 4, 6)
    assert bar.n == 4 and "4 of 6 episodes ended" in bar.postfix
    w(pd.DataFrame({"cell": [group.cells[0].index] * 6, "episode": range(6)}))
    assert bar.n == 6 and w.episodes == 6
