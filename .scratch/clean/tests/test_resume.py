"""What a sweep reuses and what survives a stop: damaged cell files are reported and recomputed,
temp files removed; a second sweep into the same folder refuses; a re-run with nothing to do
keeps the original run's facts; Ctrl-C during an XLA compilation exits 130 and keeps the
finished cells. A fake evaluator stands in for the rollout (tests/test_sweep.py runs the real
one); the interrupt test compiles a real, deliberately long XLA program in a fresh process."""

import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import pandas as pd
import pytest
import yaml

from mjxrow import files as FS
from mjxrow.sweep import cells as SC
from mjxrow.sweep import config as C
from mjxrow.sweep import run as S

ROOT = Path(__file__).parents[1]
RAW = {"name": "resume", "seeds": 3, "batch_size": 3, "controller": {"name": "oracle"},
       "perception": {"source": "ground_truth"},
       "field": {"d_rr": [1.6, 2.4], "terrain_dh": [0.1, 0.3]}}


class Fake:
    """Hand-checkable rows (mae = d_rr + terrain_dh + episode/100); records the episodes run."""

    def __init__(self):
        self.episodes = []

    def __call__(self, group, cfg, on_batch_done):
        out = []
        for start in range(0, len(group.episodes), cfg.batch_size):
            eps = group.episodes[start:start + cfg.batch_size]
            rows = []
            for c, e in eps:
                fv = C.field_values(group.cell(c).cfg)
                rows.append({"cell": c, "episode": e, "success": True, "reason": "goal",
                             "mae": fv["d_rr"] + fv["terrain_dh"] + e / 100, "time": 10.0})
            self.episodes += list(eps)
            on_batch_done(pd.DataFrame(rows))
            out.append(pd.DataFrame(rows))
        return pd.concat(out)


def sweep(out, fake=None, figures=False):
    fake = fake or Fake()
    return S.run(C.from_dict(RAW), out, evaluate=fake, progress=False, figures=figures), fake


def test_damaged_cell_files_are_reported_and_recomputed(tmp_path, capsys):
    sweep(tmp_path)
    first = pd.read_csv(tmp_path / "results.csv")
    # the render knobs left at None are written as the values used, not as NaN
    assert first[["render.tile", "render.deep_share", "render.kernel"]].notna().all().all()
    files = sorted((tmp_path / "cells").glob("*.csv"))
    assert len(files) == 4
    text = files[0].read_text()
    files[0].write_text(text[: len(text) * 2 // 3])  # cut inside a row
    files[1].write_text(files[1].read_text().splitlines()[0] + "\n")  # header only
    files[2].write_text("")  # empty
    lines = files[3].read_text().splitlines(keepends=True)
    (tmp_path / "cells" / ".x.csv.123.tmp").write_text("half a cell")  # a killed write
    capsys.readouterr()
    res, fake = sweep(tmp_path)
    err = capsys.readouterr().err
    for f, why in zip(files[:3], ("cut short", "header only", "empty"), strict=True):
        assert f"{f}: {why}" in err, err
    assert res["ran"] == 3 * 3 and res["skipped"] == 1
    assert len(fake.episodes) == 9  # the three damaged cells, every episode
    assert files[3].read_text().splitlines(keepends=True) == lines  # the good one untouched
    again = pd.read_csv(tmp_path / "results.csv")
    cols = ["cell", "episode", "mae", "success"]
    pd.testing.assert_frame_equal(again[cols], first[cols])
    assert not FS.temp_files(tmp_path / "cells") and not FS.temp_files(tmp_path)


def test_cell_file_with_missing_episodes_or_another_hash(tmp_path):
    sweep(tmp_path)
    files = sorted((tmp_path / "cells").glob("*.csv"))
    df = pd.read_csv(files[0])
    df.iloc[:2].to_csv(files[0], index=False)
    assert SC.cell_file_problem(files[0], 3) == "2 of 3 episodes"
    pd.read_csv(files[2]).to_csv(files[1], index=False)
    assert SC.cell_file_problem(files[1], 3) == "holds another cell's rows"
    assert SC.cell_file_problem(files[3], 3) is None


def test_second_sweep_into_the_same_folder_refuses(tmp_path, capsys):
    path = tmp_path / "s.yaml"
    path.write_text(yaml.safe_dump(RAW))
    out = tmp_path / "o"
    out.mkdir()
    with FS.OutLock(out):  # the first sweep, still running
        with pytest.raises(FS.OutputError, match="another run is writing"):
            sweep(out)
        assert S.main([str(path), "--out", str(out), "--no-progress"]) == 2
        assert "another run is writing this folder" in capsys.readouterr().err
    assert not (out / "results.csv").exists()
    sweep(out)  # the lock is free again
    assert (out / "results.csv").exists()


def test_rerun_with_nothing_to_do_keeps_the_run_facts(tmp_path):
    sweep(tmp_path, figures=True)
    report = (tmp_path / "report.md").read_text()
    wall = next(ln for ln in report.splitlines() if ln.startswith("- **wall time**"))
    assert wall != "- **wall time**: 0.0 s for 0 episodes" and "12 episodes" in wall
    res, fake = sweep(tmp_path, figures=True)
    assert res["ran"] == 0 and not fake.episodes
    again = (tmp_path / "report.md").read_text()
    assert wall in again.splitlines()
    assert "- **re-run**: " in again and "nothing run" in again


HEAVY = """
import sys
import jax, jax.numpy as jnp, pandas as pd
from mjxrow.sweep import groups as SG
from mjxrow.sweep import run as S

def heavy(x):
    for _ in range({ops}):
        x = jnp.sin(x) * 1.0001 + jnp.cos(x[::-1])
    return x

def evaluate(group, cfg, on_batch_done):
    if group.index == 1:  # the second group compiles a long program
        lowered = jax.jit(heavy).lower(jnp.ones(64))
        print("COMPILING", file=sys.stderr, flush=True)
        lowered.compile()
        print("COMPILED", file=sys.stderr, flush=True)
    rows = pd.DataFrame([dict(cell=c, episode=e, success=True, reason="goal", mae=0.1)
                         for c, e in group.episodes])
    on_batch_done(rows)
    return rows

SG.evaluate_group = evaluate
sys.exit(S.main(sys.argv[1:]))
"""


@pytest.mark.parametrize("sig, workers", [(signal.SIGINT, "0"), (signal.SIGTERM, "0"),
                                          (signal.SIGINT, "2")])
def test_interrupt_during_compilation_exits_130_and_keeps_cells(tmp_path, sig, workers):
    """Two groups (camera.width is static): the first group's cells are written, the signal
    arrives while XLA compiles the second group's program. Exit 130 before the compilation
    ends, no crash, the finished cells in cells/ and results.csv, no temp file, lock free.
    With figure processes (MJXROW_FIGURE_WORKERS=2) they end too, leaving nothing behind."""
    raw = {**RAW, "seeds": 2, "field": {"d_rr": [1.6, 2.4]}, "camera": {"width": [8, 12]}}
    path = tmp_path / "s.yaml"
    path.write_text(yaml.safe_dump(raw, sort_keys=False))
    out = tmp_path / "o"
    proc = subprocess.Popen(
        [sys.executable, "-c", HEAVY.format(ops=3000), str(path), "--out", str(out),
         "--no-progress"], stderr=subprocess.PIPE, stdout=subprocess.PIPE, text=True,
        env={**os.environ, "PYTHONPATH": str(ROOT), "MJXROW_FIGURE_WORKERS": workers},
        cwd=tmp_path)
    lines = []
    deadline = time.monotonic() + 240
    for line in proc.stderr:
        lines.append(line)
        if line.startswith("COMPILING") or time.monotonic() > deadline:
            break
    time.sleep(0.3)
    proc.send_signal(sig)
    t = time.monotonic()
    _, rest = proc.communicate(timeout=240)
    err = "".join(lines) + rest
    assert proc.returncode == 130, err
    assert "COMPILED" not in err, err  # it stopped inside the compilation
    assert time.monotonic() - t < 60
    assert "Traceback" not in err and "interrupted: 2 of 4 cells finished and kept" in err, err
    assert "leaked" not in err and "Error" not in err, err
    results = pd.read_csv(out / "results.csv")
    assert sorted(results["cell"].unique()) == [0, 2] and len(results) == 4  # camera.width 8
    assert len(list((out / "cells").glob("*.csv"))) == 2
    assert not FS.temp_files(out) and not FS.temp_files(out / "cells")
    res, fake = sweep_resume(out, raw)
    assert res["ran"] == 4 and sorted({c for c, _ in fake.episodes}) == [1, 3]


def sweep_resume(out, raw):
    fake = Fake()
    return S.run(C.from_dict(raw), out, evaluate=fake, progress=False, figures=False), fake



def test_a_sweep_leaves_the_users_files_in_cells_alone(tmp_path):
    """Only files named as cells and the temp files of our own atomic writes are read or
    removed in OUT/cells: a user's notes, a hidden .tmp of theirs and a CSV that is no cell
    stay as they were."""
    cells = tmp_path / "cells"
    cells.mkdir()
    mine = {"my_notes.csv": "a,b\n1,2\n", ".scratch.tmp": "keep", "notes.txt": "hello"}
    for name, text in mine.items():
        (cells / name).write_text(text)
    (cells / ".0123456789abcdef.csv.4242.tmp").write_text("half a cell")  # a killed write of ours
    sweep(tmp_path)
    for name, text in mine.items():
        assert (cells / name).read_text() == text, name
    assert not (cells / ".0123456789abcdef.csv.4242.tmp").exists()
    assert len(list(cells.glob("????????????????.csv"))) == 4


def test_a_linked_cells_folder_is_refused(tmp_path):
    elsewhere = tmp_path / "elsewhere"
    elsewhere.mkdir()
    (elsewhere / "precious.csv").write_text("x\n1\n")
    out = tmp_path / "run"
    out.mkdir()
    (out / "cells").symlink_to(elsewhere)
    with pytest.raises(FS.OutputError, match="cells/ is a link"):
        sweep(out)
    assert [p.name for p in elsewhere.iterdir()] == ["precious.csv"]


def test_an_empty_out_is_refused():
    with pytest.raises(C.ConfigError, match="out: must not be empty"):
        C.from_dict({**RAW, "out": ""})
