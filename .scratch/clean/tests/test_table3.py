"""paper.table3: configs of the blocks, statistics and the markdown table on
hand-made results, resumable runs with a fake evaluator, blocks left out without a
checkpoint, CLI errors; one tiny real run: the blocks of a preset share one program."""

import math

import pandas as pd
import pytest

from mjxrow.seg import checkpoint as ckpt
from paper import table3 as T3


def test_block_configs():
    cfg = T3.build_config("segzeros_gt", "lettuce", episodes=5, image=32)
    assert cfg.axis_order == () and cfg.preset == "lettuce" and cfg.seeds == 5
    assert cfg.batch_size == 5  # never more than the episodes
    assert (cfg.controller.name, cfg.controller.variant) == ("segzeros", "paper")
    assert cfg.perception.source == "ground_truth"
    assert (cfg.camera.width, cfg.camera.height) == (32, 32)
    assert cfg.sim.path_length == 20.0 and cfg.robot.omega_max == 1.0  # presets.yaml
    oracle = T3.build_config("oracle", "pear", episodes=100)
    assert oracle.controller.name == "oracle" and oracle.camera.width == 64
    assert oracle.batch_size == 100
    smoke = T3.build_config("oracle", "pear", episodes=100, smoke=True)
    assert (smoke.seeds, smoke.camera.width, smoke.sim.path_length) == (2, 16, 1.5)
    with pytest.raises(ValueError, match="controller: unknown 'segmin'"):
        T3.build_config("segmin", "pear", episodes=1)


def hand_results() -> pd.DataFrame:
    return pd.DataFrame({
        "success": [True, True, True, False],
        "reason": ["goal", "goal", "goal", "collision"],
        "mae": [0.1, 0.2, 0.3, 0.4], "mse": [0.01, 0.04, 0.09, 0.16],
        "cha": [0.0, 0.0, 0.0, 0.0], "omega_std": [0.1, 0.1, 0.1, 0.1],
        "time": [10.0, 12.0, 14.0, math.nan]})


def test_block_stats_and_table_by_hand():
    s = T3.block_stats(hand_results())
    # MAE 0.25; s = 0.129099, t(0.975, 3) = 3.182446: half width 0.205426
    assert s["mae"]["mean"] == pytest.approx(0.25)
    assert s["mae"]["lo"] == pytest.approx(0.25 - 0.205426, abs=1e-6)
    # Wilson, p = 3/4, n = 4, z = 1.959964: [0.300642, 0.954413]
    assert (s["success"]["lo"], s["success"]["hi"]) == pytest.approx((0.300642, 0.954413),
                                                                     abs=1e-6)
    assert s["time"]["mean"] == pytest.approx(12.0) and s["time"]["n"] == 3
    assert s["episodes"] == 4 and s["ends"] == {"goal": 3, "collision": 1}

    md = T3.table_markdown({("oracle", "pear"): s}, ["pear", "vineyard"], ["oracle"])
    ours = next(line for line in md.splitlines() if "ours: oracle" in line)
    assert "| pear | ours: oracle pure pursuit | 4 | 0.75 [0.30, 0.95] |" in ours
    assert "0.2500 [0.0446, 0.4554]" in ours and ours.endswith("| goal 3, collision 1 |")
    paper = [line for line in md.splitlines() if "paper:" in line]
    # the paper's Table 3 as printed (one SegZeros row per crop; no success rate or time)
    assert paper == ["| pear | paper: SegZeros | – | n/a | -0.0005 | 0.0058 | 3.8349 | 0.0028 | "
                     "n/a | – |",
                     "| vineyard | paper: SegZeros | – | n/a | 0.0053 | 0.033 | 0.0014 | 0.0255 | "
                     "n/a | – |"]
    assert "pear, oracle pure pursuit: success 0.75 (goal 3, collision 1)" in \
        T3.failures_markdown({("oracle", "pear"): s})


class Fake:
    """Evaluator for sweep.run: episode e ends at the goal with mae = 0.01 · (e + 1)."""

    def __init__(self):
        self.calls = 0

    def __call__(self, group, cfg, on_batch_done):
        self.calls += 1
        rows = pd.DataFrame([dict(cell=c, episode=e, success=True, collision=False,
                                  reason="goal", cha=0.0, mae=0.01 * (e + 1),
                                  mse=(0.01 * (e + 1)) ** 2, omega_std=0.05, v_mean=0.5,
                                  time=40.0, path_ratio=1.0, max_offset=0.1)
                             for c, e in group.episodes])
        on_batch_done(rows)
        return rows


def test_run_table_resumes_and_leaves_out_missing_checkpoints(tmp_path, monkeypatch):
    monkeypatch.setattr(ckpt, "CHECKPOINT_DIR", tmp_path / "no_checkpoints")
    fake = Fake()
    args = (["lettuce", "chard"], ["oracle", "segzeros_gt", "segzeros_learned"], 3,
            tmp_path / "runs")
    md, stats = T3.run_table(*args, evaluate=fake, progress=False)
    assert fake.calls == 4 and set(stats) == {(c, p) for c in ("oracle", "segzeros_gt")
                                              for p in ("lettuce", "chard")}
    results = pd.read_csv(tmp_path / "runs" / "segzeros_gt" / "chard" / "results.csv")
    assert len(results) == 3 and set(results["perception.source"]) == {"ground_truth"}
    assert stats[("oracle", "lettuce")]["mae"]["mean"] == pytest.approx(0.02)  # (1 + 2 + 3) / 3
    assert "0.0200 [" in md
    assert "learned segmenter on lettuce: no segmenter checkpoint" in md
    assert "| chard | ours: SegZeros, learned segmenter" not in md
    again, _ = T3.run_table(*args, evaluate=fake, progress=False)
    assert fake.calls == 4  # every cell finished: nothing runs again
    assert "- chard, oracle pure pursuit: 3 episodes in " in md
    assert "- chard, oracle pure pursuit: 3 episodes in " in again and "reused now" in again
    table = [line for line in md.splitlines() if line.startswith("| ")]
    assert [line for line in again.splitlines() if line.startswith("| ")] == table


# -m slow (.ci/slow): 48 s of CPU compilation and episodes
@pytest.mark.slow
def test_the_blocks_of_a_preset_share_one_program(tmp_path):
    from mjxrow.rollout import build as B

    n0 = B.program_count()
    args = (["lettuce"], ["oracle", "segzeros_gt"], 2, tmp_path / "runs")
    md, stats = T3.run_table(*args, smoke=True, progress=False)
    assert B.program_count() - n0 == 1
    assert set(stats) == {("oracle", "lettuce"), ("segzeros_gt", "lettuce")}
    for c, name in (("oracle", "oracle"), ("segzeros_gt", "segzeros")):
        res = pd.read_csv(tmp_path / "runs" / c / "lettuce" / "results.csv")
        assert len(res) == 2 and set(res["controller.name"]) == {name}
    assert "- lettuce, oracle pure pursuit: 4 episodes in " in md
    assert "(one program with oracle pure pursuit, SegZeros, ground-truth mask)" in md
    again, _ = T3.run_table(*args, smoke=True, progress=False)
    assert B.program_count() - n0 == 1 and "reused now" in again


def test_cli_bad_base_yaml_exits_2(tmp_path, capsys):
    bad = tmp_path / "bad.yaml"
    bad.write_text("episode:\n  path_lenght: 20\n")
    code = T3.main(["--base", str(bad), "--presets", "lettuce", "--controllers", "oracle",
                    "--out", str(tmp_path / "runs"), "--no-progress"])
    assert code == 2
    assert "episode.path_lenght: unknown key; did you mean sim.path_length?" in \
        capsys.readouterr().err


def test_compare_pages_counts_disjoint_intervals(tmp_path, capsys):
    import importlib.util
    from pathlib import Path

    root = Path(__file__).resolve().parents[1]
    spec = importlib.util.spec_from_file_location("compare_table3",
                                                  root / "experiments" / "compare_table3.py")
    cmp = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(cmp)
    page = (root / "docs" / "table3.md").read_text()
    n, bad = cmp.compare(page, page)
    rows = [line for line in page.splitlines() if "| ours:" in line]
    assert n == 6 * len(rows) and not bad  # success, CHA, MAE, MSE, ω std, time per row
    row = next(line for line in rows if line.startswith("| lettuce | ours: oracle"))
    cells = row.split(" | ")
    cells[5] = "9.0000 [8.9000, 9.1000]"  # the MAE moved far away
    moved = page.replace(row, " | ".join(cells))
    n2, bad = cmp.compare(page, moved)
    assert n2 == n and len(bad) == 1 and bad[0].startswith("lettuce, oracle pure pursuit, MAE")
    (tmp_path / "a.md").write_text(page)
    (tmp_path / "b.md").write_text(moved)
    assert cmp.main([str(tmp_path / "a.md"), str(tmp_path / "b.md")]) == 1
    assert cmp.main([str(tmp_path / "a.md"), str(tmp_path / "a.md")]) == 0
    assert f"{n} of {n} intervals overlap" in capsys.readouterr().out
