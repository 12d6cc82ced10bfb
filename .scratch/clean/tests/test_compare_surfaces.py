"""experiments/compare_surfaces.py: the policy goal's check per cell (SegZeros < 0.8 and the oracle
≥ 0.95: the policy needs SegZeros + 0.2) on hand-made summaries, the side-by-side figure, and bad
input as one line with exit 2."""

import sys
from pathlib import Path

import pandas as pd

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "experiments"))
import compare_surfaces as CS  # noqa: E402

CELLS = [(0.0, 0.7), (0.0, 3.5), (0.01, 0.7), (0.01, 3.5)]


def _summary(path, rates, controller=None):
    rows = []
    for i, ((a, b), r) in enumerate(zip(CELLS, rates, strict=True)):
        row = {"cell": i, "field.row_curvature": a, "field.gap_length": b}
        if controller is not None:
            row["controller.name"] = controller
        rows.append({**row, "n": 20, "success": r})
    pd.DataFrame(rows).to_csv(path, index=False)
    return path


def test_goal_check_per_cell_and_figure(tmp_path, capsys):
    mixed = pd.concat([pd.read_csv(_summary(tmp_path / "s.csv", [1.0, 0.4, 0.0, 0.7], "segzeros")),
                       pd.read_csv(_summary(tmp_path / "o.csv", [1.0, 1.0, 1.0, 0.9], "oracle"))])
    mixed.to_csv(tmp_path / "mixed.csv", index=False)
    pol = _summary(tmp_path / "p.csv", [1.0, 0.55, 0.2, 0.0])
    png = tmp_path / "fig.png"
    assert CS.main([str(tmp_path / "mixed.csv"), "--label", f"policy={pol}", "--png",
                    str(png)]) == 0
    out = capsys.readouterr().out
    # applies: (0, 3.5) 0.4 < 0.8 and oracle 1.0 (policy 0.55 < 0.6: not met), (0.01, 0.7)
    # (policy 0.2 ≥ 0.0 + 0.2: met); (0.01, 3.5) has the oracle at 0.9: the goal does not apply
    assert "goal applies (SegZeros < 0.8, oracle ≥ 0.95): 2; policy ≥ SegZeros + 0.2 in 1" in out
    assert "| 0 | 3.5 | 0.40 | 0.55 | 1.00 | not met |" in out
    assert "| 0.01 | 3.5 | 0.70 | 0.00 | 0.90 | — |" in out
    assert png.stat().st_size > 10_000


def test_bad_input_one_line_exit_2(tmp_path, capsys):
    one = _summary(tmp_path / "p.csv", [1.0, 1.0, 1.0, 1.0])
    assert CS.main([str(one)]) == 2  # no controller column and no --label
    assert "no controller.name column" in capsys.readouterr().err
    assert CS.main([str(tmp_path / "missing.csv")]) == 2
    assert "no such file" in capsys.readouterr().err
    assert CS.main(["--label", f"policy={one}"]) == 2  # no SegZeros or oracle rows
    assert "segzeros" in capsys.readouterr().err
