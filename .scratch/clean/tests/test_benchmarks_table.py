"""experiments/benchmarks_table.py: the headline figures of BENCHMARKS.md from benchmarks.jsonl."""

import importlib.util
import json
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
_spec = importlib.util.spec_from_file_location("benchmarks_table",
                                               ROOT / "experiments" / "benchmarks_table.py")
bt = importlib.util.module_from_spec(_spec)
sys.modules[_spec.name] = bt  # dataclasses look their module up
_spec.loader.exec_module(bt)

ROWS = [
    {"date": "2026-01-01", "device": "cpu", "stage": "sweep", "config": "smoke, warm cache",
     "batch": 8, "value": 30.0, "unit": "s wall", "run_s": 3.0, "note": "first round",
     "command": "python -m mjxrow.sweep sweeps.yaml --smoke"},
    {"date": "2026-01-02", "device": "cpu", "stage": "sweep", "config": "smoke, warm cache",
     "batch": 8, "value": 9.0, "unit": "s wall", "run_s": 1.0, "note": "second round",
     "command": "python -m mjxrow.sweep sweeps.yaml --smoke"},
    {"date": "2026-01-02", "device": "cpu", "stage": "sweep", "config": "smoke, warm cache",
     "batch": 8, "value": 11.0, "unit": "s wall", "run_s": 2.0, "note": "second round",
     "command": "python -m mjxrow.sweep sweeps.yaml --smoke"},
    {"date": "2026-01-02", "device": "GPU A", "stage": "render", "config": "64x64", "batch": 16,
     "value": 500.0, "unit": "frames/s", "compile_s": 4.0, "runs_s": [0.1, 0.3, 0.2],
     "command": "bash experiments/gpu_speed_round.sh --out x/rows.jsonl"},
    {"date": "2026-01-03", "device": "GPU A", "stage": "render", "config": "64x64", "batch": 16,
     "value": 600.0, "unit": "frames/s", "compile_s": 5.0, "command": "python -m mjxrow.bench"},
    {"date": "2026-01-03", "device": "GPU B", "stage": "render", "config": "64x64", "batch": 16,
     "value": 200.0, "unit": "frames/s", "compile_s": 2.0, "command": "python -m mjxrow.bench"},
]
FIGURES = [
    bt.Figure("smoke warm", "sweep", "warm", "^cpu$", pick="median", goal=("<=", 10)),
    bt.Figure("render A", "render", "64x64", "A", pick="latest", goal=(">=", 1000)),
    bt.Figure("A over B", "render", "64x64", "A", unit="×", fmt="{:.1f}",
              over=bt.Figure("", "render", "64x64", "B")),
]


def test_current_picks_the_latest_row_the_latest_rounds_median_and_ratios():
    lines = bt.current(ROWS, FIGURES).splitlines()
    assert lines[0].startswith("| figure | value | goal | device | date | batch |")
    smoke, render, ratio = (line.split(" | ") for line in lines[2:])
    # the median of the second round's two runs (9 and 11 s), not of all three
    assert smoke[1:6] == ["10 s wall (median of 2)", "≤ 10: met", "cpu", "2026-01-02", "8"]
    assert smoke[7] == "1.5"  # the median run time of those two runs
    assert render[1:3] == ["600 frames/s", "≥ 1,000: not met"] and render[6] == "5"
    assert ratio[1] == "3.0×" and ratio[3] == "GPU A / GPU B" and ratio[6] == "5 / 2"
    # the per-round script is named as its set of experiments/gpu.sh; --out of raw rows dropped
    first = bt.current(ROWS[3:4], [bt.Figure("r", "render")])
    assert "`bash experiments/gpu.sh speed_round` |" in first and "0.2 |" in first


@pytest.mark.parametrize("name", ["BENCHMARKS.md", "README.md"])
def test_repository_figures_are_up_to_date(name, capsys):
    assert bt.main(["--check", str(ROOT / name)]) == 0
    assert "up to date" in capsys.readouterr().out


def test_stale_or_unmarked_file_fails(tmp_path, capsys, monkeypatch):
    jsonl = tmp_path / "b.jsonl"
    jsonl.write_text("".join(json.dumps(r) + "\n" for r in ROWS))
    md = tmp_path / "B.md"
    md.write_text(f"# B\n\n{bt.BEGIN}\n\n| old | table |\n\n{bt.END}\n\nmore\n")
    args = ["--file", str(jsonl)]
    # the repository's headline figures do not all have rows in this file: exit 2, naming one
    with pytest.raises(SystemExit) as e:
        bt.main(args + ["--check", str(md)])
    assert e.value.code == 2 and "matches the headline figure" in capsys.readouterr().err
    monkeypatch.setattr(bt, "HEADLINES", FIGURES)
    assert bt.main(args + ["--check", str(md)]) == 1
    assert "stale" in capsys.readouterr().err
    assert bt.main(args + ["--write", str(md)]) == 0
    assert bt.main(args + ["--check", str(md)]) == 0
    text = md.read_text()
    assert text.startswith(f"# B\n\n{bt.BEGIN}\n\n| figure |") and text.endswith("\nmore\n")
    md.write_text("# B\n")
    with pytest.raises(SystemExit) as e:
        bt.main(args + ["--check", str(md)])
    assert e.value.code == 2 and "no marker line" in capsys.readouterr().err
