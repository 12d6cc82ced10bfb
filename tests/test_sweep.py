"""Sweep machinery with a fake evaluator: grid → groups → batches → cell files → results,
summary, PNGs, report; resume after a finished run and after an interrupt; CLI errors."""

import math
import os
import signal
from pathlib import Path

import jax
import numpy as np
import pandas as pd
import pytest
import yaml

from mjxrow.rollout import build as B
from mjxrow.sweep import config as C
from mjxrow.sweep import groups as SG
from mjxrow.sweep import run as S

BASE = {"name": "fake", "seeds": 3, "batch_size": 3,
        "perception": {"source": "ground_truth"},
        "field": {"d_rr": [1.6, 2.4], "terrain_dh": [0.1, 0.3]}}


def fake_metrics(cfg: C.SweepConfig, e: int) -> dict:
    """Hand-checkable numbers: success unless (odd episode and d_rr < 2); mae = dh + e/100."""
    d, dh = C.field_values(cfg)["d_rr"], C.field_values(cfg)["terrain_dh"]
    ok = e % 2 == 0 or d > 2.0
    mae = dh + 0.01 * e
    return dict(success=ok, collision=not ok, reason="goal" if ok else "collision", cha=0.0,
                mae=mae, mse=mae * mae, omega_std=0.1 * d, v_mean=0.5,
                time=10.0 + e if ok else math.nan, path_ratio=1.0, max_offset=2 * mae)


class Fake:
    """An evaluator that records its calls; can stop after `stop_after` batches with a
    KeyboardInterrupt or a SIGTERM to this process."""

    def __init__(self, stop_after=None, how="interrupt"):
        self.groups, self.batches, self.stop_after, self.how = [], [], stop_after, how

    def __call__(self, group, cfg, on_batch_done):
        self.groups.append(group)
        out = []
        for start in range(0, len(group.episodes), cfg.batch_size):
            if self.stop_after is not None and len(self.batches) == self.stop_after:
                if self.how == "sigterm":
                    os.kill(os.getpid(), signal.SIGTERM)
                raise KeyboardInterrupt
            eps = group.episodes[start:start + cfg.batch_size]
            rows = pd.DataFrame([{"cell": c, "episode": e,
                                  **fake_metrics(group.cell(c).cfg, e)} for c, e in eps])
            self.batches.append(eps)
            on_batch_done(rows)
            out.append(rows)
        return pd.concat(out)


def run(tmp_path, raw=BASE, fake=None, figures=False, **kw):
    fake = fake or Fake()
    res = S.run(C.from_dict(raw, **kw), tmp_path, evaluate=fake, progress=False,
                figures=figures)
    return res, fake


def test_two_by_two_sweep_writes_everything(tmp_path):
    res, fake = run(tmp_path, figures=True)
    assert len(fake.groups) == 1  # one static group: one compile
    assert len(fake.groups[0].episodes) == 4 * 3 and len(fake.batches) == 4
    results = pd.read_csv(tmp_path / "results.csv")
    assert len(results) == 4 * 3
    assert set(results.groupby("cell").size()) == {3}
    assert {"field.d_rr", "field.d_pp", "robot.v_max", "controller.omega_gain",
            "camera.width", "success", "mae", "reason", "cell_hash"} <= set(results.columns)
    assert results["field.d_pp"].eq(0.7).all()  # zucchini's preset value, resolved
    summary = pd.read_csv(tmp_path / "summary.csv")
    assert len(summary) == 4
    row = summary[(summary["field.d_rr"] == 1.6) & (summary["field.terrain_dh"] == 0.1)]
    assert row["mae"].item() == pytest.approx(0.11)  # (0.10 + 0.11 + 0.12) / 3
    assert row["success"].item() == pytest.approx(2 / 3)
    assert row["reason_collision"].item() == pytest.approx(1 / 3)
    assert row["time"].item() == pytest.approx(11.0)  # only successful episodes: 10 and 12
    assert row["mae_lo"].item() < 0.11 < row["mae_hi"].item()
    wide = summary[summary["field.d_rr"] == 2.4]
    assert wide["success"].eq(1.0).all()
    for m in ("success", "collision", "mae", "mse", "cha", "omega_std", "time"):
        assert (tmp_path / f"{m}.png").stat().st_size > 1000, m
    report = (tmp_path / "report.md").read_text()
    assert "![success](success.png)" in report and "![mae](mae.png)" in report
    assert "2 of 4 cells succeed in fewer than 95%" in report
    cfg_block = report.split("```yaml\n")[1].split("```")[0]
    assert yaml.safe_load(cfg_block)["field"]["d_rr"] == [1.6, 2.4]
    assert len(list((tmp_path / "cells").glob("*.csv"))) == 4
    assert not list(tmp_path.rglob("*.tmp"))
    assert res["ran"] == 12 and res["skipped"] == 0


def test_rerun_skips_finished_cells(tmp_path):
    run(tmp_path)
    before = pd.read_csv(tmp_path / "results.csv")
    res, fake = run(tmp_path)
    assert fake.groups == [] and res["ran"] == 0 and res["skipped"] == 4
    pd.testing.assert_frame_equal(pd.read_csv(tmp_path / "results.csv"), before)
    # a wider grid runs only its new cells
    raw = {**BASE, "field": {"d_rr": [1.6, 2.4], "terrain_dh": [0.1, 0.3, 0.5]}}
    res, fake = run(tmp_path, raw)
    assert res["skipped"] == 4 and res["ran"] == 2 * 3
    assert {C.field_values(fake.groups[0].cell(c).cfg)["terrain_dh"]
            for c, _ in fake.groups[0].episodes} == {0.5}
    assert len(pd.read_csv(tmp_path / "results.csv")) == 6 * 3


@pytest.mark.parametrize("how", ["interrupt", "sigterm"])
def test_interrupt_keeps_finished_cells_and_resumes(tmp_path, how):
    with pytest.raises(KeyboardInterrupt):
        run(tmp_path, fake=Fake(stop_after=1, how=how))
    assert len(list((tmp_path / "cells").glob("*.csv"))) == 1  # batch = one whole cell
    assert len(pd.read_csv(tmp_path / "results.csv")) == 3
    assert not list(tmp_path.rglob("*.tmp"))
    res, fake = run(tmp_path)
    assert res["skipped"] == 1 and res["ran"] == 3 * 3
    assert len(fake.groups[0].episodes) == 9
    full, _ = run(tmp_path / "fresh")
    pd.testing.assert_frame_equal(
        pd.read_csv(tmp_path / "results.csv").drop(columns="group"),
        pd.read_csv(tmp_path / "fresh" / "results.csv").drop(columns="group"))


def test_partial_cell_is_rerun_not_half_kept(tmp_path):
    # batches of 2 episodes: the interrupt lands inside cell 1 (episodes 0-2 of cell 0 and
    # 0 of cell 1 done)
    with pytest.raises(KeyboardInterrupt):
        run(tmp_path, {**BASE, "batch_size": 2}, fake=Fake(stop_after=2))
    assert len(list((tmp_path / "cells").glob("*.csv"))) == 1
    res, fake = run(tmp_path, {**BASE, "batch_size": 2})
    assert res["ran"] == 9 and fake.groups[0].episodes[0] == (1, 0)


def test_groups_by_static_values(tmp_path):
    raw = {**BASE, "camera": {"width": [16, 24]}, "field": {"d_rr": [1.6, 2.4]}}
    res, fake = run(tmp_path, raw)
    assert len(fake.groups) == 2
    assert [{fake.groups[i].cell(c).cfg.camera.width for c, _ in g.episodes}
            for i, g in enumerate(fake.groups)] == [{16}, {24}]
    assert len(pd.read_csv(tmp_path / "results.csv")) == 4 * 3
    # field axes share a group and its fitted shape holds every cell's field
    groups = SG.plan(C.from_dict({**BASE, "field": {"d_pp": [0.3, 0.7], "row_length": [20, 50]}}))
    assert len(groups) == 1
    assert groups[0].shape.max_plants_per_row >= 50 / 0.3 + 1
    # start-pose noise axes are traced: one group
    assert len(SG.plan(C.from_dict({**BASE, "episode": {"start_offset_std": [0.0, 0.1],
                                                        "start_yaw_std": [0.0, 3.0]}}))) == 1
    # presets differ in crop: one group each
    assert len(SG.plan(C.from_dict({**BASE, "field": {}, "preset": ["zucchini", "pear"]}))) == 2


def test_mix_controllers_puts_a_controller_axis_in_one_group():
    raw = {**BASE, "controller": {"name": ["oracle", "segzeros"]},
           "perception": {"source": ["ground_truth", "learned"]}}
    assert len(SG.plan(C.from_dict(raw))) == 4  # every (controller, source): its own group
    groups = SG.plan(C.from_dict({**raw, "mix_controllers": True}))
    assert [len(g.cells) for g in groups] == [16]  # 4 fields × 2 controllers × 2 sources
    built_variants = {g.cell(c).cfg.variant_key() for g in groups for c, _ in g.episodes}
    assert len(built_variants) == 3  # the oracle reads no mask: its source does not count
    # other static values still split the groups
    wide = {**raw, "mix_controllers": True, "camera": {"width": [16, 24]}}
    assert [len(g.cells) for g in SG.plan(C.from_dict(wide))] == [16, 16]
    with pytest.raises(C.ConfigError, match="mix_controllers: expected true or false"):
        C.from_dict({**BASE, "mix_controllers": 1})
    with pytest.raises(C.ConfigError, match="mix_controllers: controller 'policy' renders"):
        C.from_dict({"mix_controllers": True, "controller": {"name": ["oracle", "policy"]}})


def test_one_axis_gives_line_plots_and_categorical_axes_work(tmp_path):
    raw = {**BASE, "field": {"terrain_dh": [0.1, 0.2, 0.3]}}
    run(tmp_path / "line", raw, figures=True)
    assert (tmp_path / "line" / "mae.png").exists()
    raw = {**BASE, "field": {"d_rr": [1.6, 2.4]}, "controller": {"variant": ["paper", "public"]}}
    _, fake = run(tmp_path / "cat", raw, figures=True)
    assert len(fake.groups) == 2 and (tmp_path / "cat" / "success.png").exists()


def test_episode_keys_are_deterministic():
    def data(seed, eps):
        return np.asarray(jax.random.key_data(B.episode_keys(seed, eps)))

    a = data(0, [0, 1, 2])
    assert a.shape[0] == 3 and np.array_equal(a, data(0, [0, 1, 2]))
    assert len({tuple(r) for r in a}) == 3
    assert np.array_equal(data(0, [2]), a[2:])  # episode i's key does not depend on the batch
    assert not np.array_equal(a, data(5, [0, 1, 2]))


def test_cli_bad_yaml_exits_2_with_dotted_key(tmp_path, capsys):
    bad = tmp_path / "bad.yaml"
    bad.write_text("field:\n  d_rrr: [1.2, 1.8]\n")
    assert S.main([str(bad), "--out", str(tmp_path / "o")]) == 2
    err = capsys.readouterr().err
    assert err.strip() == "error: field.d_rrr: unknown key; did you mean d_rr?"
    assert not (tmp_path / "o").exists()  # validation before any work
    assert S.main([str(bad), "--set", "field.d_rrr=1"]) == 2


def test_cli_smoke_with_fake_evaluator(tmp_path, monkeypatch):
    fake = Fake()
    monkeypatch.setattr(SG, "evaluate_group", fake)
    path = tmp_path / "s.yaml"
    path.write_text(yaml.safe_dump({**BASE, "seeds": 8, "field": {
        "d_rr": [1.6, 1.8, 2.0, 2.4], "terrain_dh": [0.0, 0.1, 0.2]}}))
    assert S.main([str(path), "--smoke", "--out", str(tmp_path / "o"), "--no-progress"]) == 0
    results = pd.read_csv(tmp_path / "o" / "results.csv")
    assert len(results) == 4 * 2 and len(fake.groups) == 1
    assert sorted(set(results["field.d_rr"])) == [1.6, 2.4]


def test_smoke_keeps_the_camera_a_learned_policy_was_trained_on():
    """--smoke shrinks the images to 16 px, except where a cell runs the `policy` controller:
    its network takes the size it was trained on (sweeps/sun.yaml's policy at 64 px)."""
    sun = Path(__file__).resolve().parents[1] / "sweeps" / "sun.yaml"
    for names, px in (("policy", 64), ("segzeros", 16), ("[segzeros, policy]", 64)):
        cfg = C.shrink(C.load(sun, [f"controller.name={names}"]))
        assert (cfg.camera.width, cfg.camera.height) == (px, px), names
        assert cfg.seeds == 2 and dict(cfg.values)["sim.path_length"] == 1.5


# ---------------------------------------------------------------------------------------------
# The real evaluator (episode.rollout): small, oracle controller, one compile shared by the tests

REAL = {"name": "real", "seeds": 2, "batch_size": 4, "controller": {"name": "oracle"},
        "perception": {"source": "ground_truth"},
        "field": {"d_rr": [1.6, 2.4], "terrain_dh": 0.0, "row_length": 6.0,
                  "terrain_length": 10.0, "terrain_width": 10.0, "rows_per_group": 2},
        "sim": {"path_length": 1.5},
        "episode": {"max_time": 4.0, "start_offset_std": [0.0, 0.1]},
        "camera": {"width": 16, "height": 16}}


@pytest.fixture(scope="module")
def real_run(tmp_path_factory):
    from mjxrow.rollout import episode as E

    out = tmp_path_factory.mktemp("real")
    before = E.TRACES
    res = S.run(C.from_dict(REAL), out, progress=False)
    return out, res, E.TRACES - before


def test_real_sweep_compiles_once_and_writes_results(real_run):
    out, res, traces = real_run
    assert traces <= 1  # 8 episodes in 2 batches of 4: one trace (none when an earlier test kept
    # the same program, runtime.exported)
    results = pd.read_csv(out / "results.csv")
    assert len(results) == 4 * 2
    assert results["success"].all(), results[["cell", "reason"]]
    assert (results["mae"] < 0.1).all() and (results["time"] < 4.0).all()
    # start-pose noise per episode in the same batch: on flat ground the oracle stays on the
    # centre line from a centred start and deviates from a noisy one
    noisy = results["episode.start_offset_std"] == 0.1
    assert noisy.sum() == 4 and (results.loc[~noisy, "max_offset"] < 1e-3).all()
    assert (results.loc[noisy, "max_offset"] > 1e-3).all(), results["max_offset"]
    assert results["lane"].nunique() >= 1 and (out / "success.png").exists()
    assert "![mae](mae.png)" in (out / "report.md").read_text()


def test_real_sweep_is_deterministic_and_resumes(real_run, tmp_path):
    from mjxrow.rollout import episode as E

    out, _, _ = real_run
    before = E.TRACES
    res = S.run(C.from_dict(REAL), tmp_path, progress=False, figures=False)
    assert E.TRACES == before  # same static group: the compiled function is reused
    cols = ["cell", "episode", "success", "mae", "mse", "cha", "omega_std", "time"]
    pd.testing.assert_frame_equal(pd.read_csv(tmp_path / "results.csv")[cols],
                                  pd.read_csv(out / "results.csv")[cols])
    again = S.run(C.from_dict(REAL), tmp_path, progress=False, figures=False)
    assert res["ran"] == 8 and again["ran"] == 0 and again["skipped"] == 4


@pytest.mark.slow
def test_cli_smoke_segzeros_ground_truth(tmp_path):
    from pathlib import Path

    root = Path(__file__).parents[1]
    code = S.main([str(root / "sweeps.yaml"), "--smoke", "--out", str(tmp_path),
                   "--set", "perception.source=ground_truth", "--no-progress"])
    assert code == 0
    results = pd.read_csv(tmp_path / "results.csv")
    assert len(results) == 4 * 2 and set(results["controller.name"]) == {"segzeros"}
    assert (tmp_path / "report.md").exists()


def test_learned_weights_are_shared_params_of_one_policy(tmp_path):
    """A learned-mask group: the checkpoint is loaded once and its weights are the shared part
    of every cell's params; another checkpoint of the same architecture gets the same policy
    (so the same compiled rollout) with other weights."""
    from mjxrow.rollout import episode as E
    from mjxrow.seg import checkpoint as ckpt
    from mjxrow.seg import model as segmodel

    module, va = segmodel.create("small", 0.25, jax.random.key(0), 32)
    _, vb = segmodel.create("small", 0.25, jax.random.key(1), 32)
    ckpt.save(tmp_path / "a", module, va)
    ckpt.save(tmp_path / "b", module, vb)

    def group(checkpoint):
        raw = {**BASE, "field": {"d_rr": [1.6, 2.4]},
               "perception": {"source": "learned", "checkpoint": str(tmp_path / checkpoint),
                              "threshold": [0.5, 0.7]}}
        groups = SG.plan(C.from_dict(raw))
        assert len(groups) == 1  # threshold and geometry are traced: one group, one compile
        g = groups[0]
        return g, B.build([c.cfg for c in g.cells], g.shape)

    g, built = group("a")
    policy, axes = built.policy, built.axes
    params = [built.policy_params(c.cfg) for c in g.cells]
    batch = E.stack_params(params, axes)
    assert batch[0].variables is params[0][0].variables is params[-1][0].variables
    np.testing.assert_allclose(batch[0].threshold, [0.5, 0.5, 0.7, 0.7])  # first axis slowest
    assert batch[1].omega_gain.shape == (4,)
    E.check_params(batch, axes, 4)
    _, built_b = group("b")
    assert built_b.policy is policy
    wa = jax.tree.leaves(params[0][0].variables)
    wb = jax.tree.leaves(built_b.policy_params(g.cells[0].cfg)[0].variables)
    assert max(float(np.abs(a - b).max()) for a, b in zip(wa, wb, strict=True)) > 0


def test_the_shipped_throughput_is_that_of_benchmarks_jsonl():
    """The estimate reads its closed-loop rates from package data (an installed package has no
    benchmarks.jsonl); they are the rates `estimate.rates` reads from the repository's record."""
    import json
    from pathlib import Path

    from mjxrow.sweep import estimate

    record = Path(__file__).resolve().parents[1] / "benchmarks.jsonl"
    assert json.loads(estimate.THROUGHPUT.read_text()) == estimate.rates(
        record.read_text().splitlines())
    assert estimate._rate("cpu")[0] > 0 and estimate._rate("no such device") is None


def test_the_sun_azimuth_is_a_traced_key_that_turns_the_sun_about_the_rows():
    from mjxrow import render
    from mjxrow.rollout import episode as E
    from mjxrow.rollout.config import build_run

    raw = {**BASE, "field": {}, "perception": {"source": "ground_truth",
                                                "sun_azimuth": [35.0, -35.0, 215.0]}}
    groups = SG.plan(C.from_dict(raw))
    assert len(groups) == 1  # traced: one group, one compile
    g = groups[0]
    built = B.build([c.cfg for c in g.cells], g.shape)
    batch = E.stack_params([built.policy_params(c.cfg) for c in g.cells], built.axes)
    sun = np.asarray(batch[0].cond.sun_dir)
    np.testing.assert_allclose(sun[0], render.conditions("sunny").sun_dir, atol=1e-6)  # default
    np.testing.assert_allclose(sun[1], sun[0] * [1, -1, 1], atol=1e-6)  # mirrored about the row
    np.testing.assert_allclose(sun[2], sun[0] * [-1, -1, 1], atol=1e-6)  # from behind
    for bad in ("north", float("nan")):
        with pytest.raises(C.ConfigError, match="perception.sun_azimuth"):
            C.from_dict({**BASE, "perception": {"sun_azimuth": bad}})
    with pytest.raises(ValueError, match="perception.sun_azimuth"):  # the run's own check
        build_run({"preset": "zucchini", "perception.sun_azimuth": float("inf")})
