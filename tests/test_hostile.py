"""Hostile inputs, table-driven: every case ends with exit code 2, a one-line error that names the
key (or option) at fault, and no output folder. All of them fail in validation, before any
field, model or compiled program exists, so each takes well under a second (but the damaged
weights, which need a saved checkpoint)."""

import json
import subprocess
import sys
from pathlib import Path

import pytest
import yaml

from mjxrow import episode as EP
from mjxrow.seg import eval as SE
from mjxrow.seg import export as SX
from mjxrow.sweep import run as S

ROOT = Path(__file__).parents[1]
BASE = {"name": "hostile", "seeds": 2, "perception": {"source": "ground_truth"},
        "controller": {"name": "oracle"}}


def _with(**sections):
    raw = json.loads(json.dumps(BASE))
    for k, v in sections.items():
        if isinstance(v, dict):
            raw.setdefault(k, {}).update(v)
        else:
            raw[k] = v
    return raw


# each list ten aliases of the one before: 10^6 values once expanded
ALIAS_BOMB = "a: &a [1, 1, 1, 1, 1, 1, 1, 1, 1, 1]\n" + "".join(
    f"{c}: &{c} [{', '.join(['*' + prev] * 10)}]\n"
    for prev, c in zip("abcde", "bcdef", strict=True))
# (id, YAML content: a mapping or raw text, extra CLI arguments, text the message must hold)
SWEEP_CASES = [
    ("alias_bomb", ALIAS_BOMB, [], "f: more than 100,000 values once its aliases"),
    ("name_a_date", "name: 2024-01-01\nseeds: 2\n", [], "name: a date or time is not a value"),
    ("name_binary", "name: !!binary aGVsbG8=\n", [], "name: binary data is not a value"),
    ("name_a_set", "name: !!set {a, b}\n", [], "name: a set is not a value"),
    ("nested_lists", "field:\n  d_rr: " + "[" * 50 + "1.5" + "]" * 50 + "\n", [],
     "field: nested more than 32 levels deep"),
    ("out_empty", _with(out=""), [], "out: must not be empty"),
    ("seeds", _with(seeds=10**9), [], "seeds"),
    ("seed", _with(seed=2**40), [], "seed"),
    ("seed_negative", _with(seed=-1), [], "seed"),
    ("cells", _with(field={"d_rr": {"start": 1.5, "stop": 3.0, "num": 1000},
                           "terrain_dh": {"start": 0.0, "stop": 0.3, "num": 1000}}), [],
     "field.d_rr: the grid has 1,000,000 cells"),
    ("range_num", _with(field={"d_rr": {"start": 1.5, "stop": 3.0, "num": 10**9}}), [],
     "field.d_rr.num"),
    ("control_hz", _with(sim={"control_hz": 1e6}), [], "sim.control_hz"),
    ("max_time", _with(episode={"max_time": 1e7}), [], "episode.max_time"),
    ("steps", _with(episode={"max_time": 3000.0}, sim={"control_hz": 100.0}), [],
     "episode.max_time: gives 300,000 control steps"),
    ("substeps", _with(), ["--set", "sim.dt=1e-9"], "sim.dt"),
    ("terrain_width", _with(field={"terrain_width": 1e6}), [], "field.terrain_width"),
    ("d_rr_huge", _with(field={"d_rr": 1e9}), [], "field.d_rr"),
    ("d_rr_wide", _with(field={"d_rr": 50.0}), [], "field.d_rr: fewer than two rows"),
    ("d_pp_tiny", _with(field={"d_pp": 1e-5}), [], "field.d_pp"),
    ("camera_width", _with(camera={"width": 100000}), [], "camera.width"),
    ("memory", _with(camera={"width": 2000, "height": 2000}, batch_size=256, seeds=256), [],
     "batch_size: estimated peak memory"),
    ("empty_yaml", "", [], "empty file"),
    ("comments_only_yaml", "# nothing here\n", [], "empty file"),
    ("duplicate_key", "name: dup\nfield:\n  d_rr: 1.5\n  terrain_dh: 0.1\n  d_rr: 2.0\n", [],
     "field.d_rr: duplicate key"),
    ("duplicate_top", "seeds: 2\nname: a\nseeds: 3\n", [], "seeds: duplicate key"),
    ("fraction_seeds", _with(seeds=2.5), [], "seeds: expected an integer"),
    ("fraction_width", _with(camera={"width": 16.5}), [], "camera.width: expected an integer"),
    ("fraction_rows", _with(field={"rows_per_group": 2.5}), [],
     "field.rows_per_group: expected an integer"),
    ("fraction_set", _with(), ["--set", "episode.stuck_window=4.5"], "episode.stuck_window"),
    ("out_proc", _with(), ["--out", "/proc/mjxrow_x"], "--out /proc/mjxrow_x"),
]


@pytest.mark.parametrize("content, extra, needle",
                         [c[1:] for c in SWEEP_CASES], ids=[c[0] for c in SWEEP_CASES])
def test_sweep_rejects(tmp_path, capsys, content, extra, needle):
    path = tmp_path / "s.yaml"
    path.write_text(content if isinstance(content, str) else yaml.safe_dump(content))
    _rejected(capsys, S.main, [str(path), "--no-progress"], extra, tmp_path / "o", needle)


def _rejected(capsys, main, args, extra, out, needle):
    """`main(args + extra)` (with `--out out` unless extra names one) exits 2 with one line
    naming `needle`, and creates no `out`."""
    assert main(args + (extra if "--out" in extra else ["--out", str(out), *extra])) == 2
    err = capsys.readouterr().err.strip()
    assert err.startswith("error: ") and "\n" not in err, err
    assert needle in err, err
    assert not out.exists()


def test_sweep_out_is_a_file(tmp_path, capsys):
    path = tmp_path / "s.yaml"
    path.write_text(yaml.safe_dump(BASE))
    (tmp_path / "o").write_text("not a folder")
    assert S.main([str(path), "--out", str(tmp_path / "o"), "--no-progress"]) == 2
    assert "--out" in capsys.readouterr().err
    assert (tmp_path / "o").read_text() == "not a folder"


def _checkpoint(tmp_path, kind: str) -> Path:
    ck = tmp_path / f"ck_{kind}"
    ck.mkdir()
    if kind == "damaged_config":
        (ck / "config.json").write_text('{"model": {"arch": ')
        (ck / "weights").mkdir()
        (ck / "weights" / "x").write_bytes(b"1")
    if kind == "no_weights":
        (ck / "config.json").write_text(json.dumps({"model": {}, "meta": {}}))
        (ck / "weights").mkdir()
    return ck


@pytest.mark.parametrize("kind, needle", [("empty", "no config.json"),
                                          ("damaged_config", "config.json is damaged"),
                                          ("no_weights", "weights/ holds no data")])
def test_sweep_rejects_a_bad_checkpoint(tmp_path, capsys, kind, needle):
    raw = {**BASE, "controller": {"name": "segzeros"},
           "perception": {"source": "learned", "checkpoint": str(_checkpoint(tmp_path, kind))}}
    path = tmp_path / "s.yaml"
    path.write_text(yaml.safe_dump(raw))
    assert S.main([str(path), "--out", str(tmp_path / "o"), "--no-progress"]) == 2
    err = capsys.readouterr().err.strip()
    assert "perception.checkpoint" in err and needle in err and "\n" not in err, err
    assert not (tmp_path / "o").exists()


EPISODE_CASES = [
    ("out_proc", ["--out", "/proc/mjxrow_x"], "--out /proc/mjxrow_x"),
    ("n_huge", ["--n", str(10**9)], "--n"),
    ("n_zero", ["--n", "0"], "--n"),
    ("n_memory", ["--n", "100000", "--set", "camera.width=2048", "--set", "camera.height=2048"],
     "--n: estimated peak memory"),
    ("seed", ["--seed", "-3"], "seed"),
    ("seed_huge", ["--seed", str(2**64)], "seed"),
    ("camera", ["--set", "camera.width=100000"], "camera.width"),
    ("fraction", ["--set", "camera.height=31.5"], "camera.height"),
    ("d_rr", ["--set", "field.d_rr=1e9"], "field.d_rr"),
    ("axis", ["--set", "field.d_rr=[2.5, 3.0]"], "field.d_rr"),
    ("preset", ["--preset", "nope"], "preset"),
    ("controller", ["--controller", "nope"], "controller.name"),
]


@pytest.mark.parametrize("extra, needle", [c[1:] for c in EPISODE_CASES],
                         ids=[c[0] for c in EPISODE_CASES])
def test_episode_rejects(tmp_path, capsys, extra, needle):
    _rejected(capsys, EP.main, ["--n", "2", "--no-progress"], extra, tmp_path / "o", needle)


def test_episode_keeps_an_earlier_csv(tmp_path, capsys):
    """An episodes.csv already in --out (an earlier run's) is refused before any work, in one
    line naming --out and the file; nothing in the folder changes. --overwrite allows it."""
    out = tmp_path / "o"
    out.mkdir()
    (out / "episodes.csv").write_text("earlier run\n")
    assert EP.main(["--n", "2", "--no-progress", "--out", str(out)]) == 2
    err = capsys.readouterr().err.strip()
    assert err.startswith("error: --out ") and "\n" not in err, err
    assert str(out / "episodes.csv") in err and "--overwrite" in err, err
    assert [p.name for p in out.iterdir()] == ["episodes.csv"]
    assert (out / "episodes.csv").read_text() == "earlier run\n"


@pytest.mark.parametrize("kind, needle", [("missing", "no such folder"),
                                          ("empty", "no config.json"),
                                          ("damaged_config", "config.json is damaged"),
                                          ("no_weights", "weights/ holds no data")])
def test_seg_eval_rejects_a_bad_checkpoint(tmp_path, capsys, kind, needle):
    ck = tmp_path / "nothing" if kind == "missing" else _checkpoint(tmp_path, kind)
    csv = tmp_path / "o" / "t.csv"
    assert SE.cli(["--ckpt", str(ck), "--csv", str(csv)]) == 2
    err = capsys.readouterr().err.strip()
    assert needle in err and "\n" not in err, err
    assert not csv.parent.exists()


def test_damaged_weights_give_one_line(tmp_path, capsys):
    """A saved checkpoint whose weight files were cut to nothing: restoring fails inside orbax;
    the error is one line naming the folder (not orbax's traceback)."""
    import jax

    from mjxrow.seg import checkpoint as ckpt
    from mjxrow.seg import model as segmodel

    module, variables = segmodel.create("small", 0.25, jax.random.key(0), 32)
    ck = ckpt.save(tmp_path / "ck", module, variables)
    files = [f for f in (ck / "weights").rglob("*") if f.is_file() and f.stat().st_size > 0]
    for f in files:
        f.write_bytes(f.read_bytes()[: len(f.read_bytes()) // 3])
    with pytest.raises(ckpt.CheckpointError, match="weights/ cannot be restored") as e:
        ckpt.load(ck)
    assert "\n" not in str(e.value)
    assert SE.cli(["--ckpt", str(ck), "--n", "1"]) == 2
    err = capsys.readouterr().err.strip()
    assert str(ck) in err and "\n" not in err


def test_seg_export_names_the_extra_without_onnx(tmp_path, capsys, monkeypatch):
    import importlib.util

    real = importlib.util.find_spec
    monkeypatch.setattr(importlib.util, "find_spec",
                        lambda name, *a: None if name == "onnx" else real(name, *a))
    assert SX.cli(["--crop", "zucchini", "--out", str(tmp_path / "o" / "m.onnx")]) == 2
    err = capsys.readouterr().err.strip()
    assert "[export]" in err and "\n" not in err
    assert not (tmp_path / "o").exists()


def test_command_line_error_is_one_line_without_noise(tmp_path):
    """The real command in a fresh process: exit 2, stderr one line (no MJX warp noise)."""
    res = subprocess.run([sys.executable, "-m", "mjxrow.episode", "--out", "/proc/mjxrow_x"],
                         capture_output=True, text=True, cwd=tmp_path, timeout=120,
                         env={**__import__("os").environ, "PYTHONPATH": str(ROOT)})
    assert res.returncode == 2, res.stderr
    assert res.stderr.strip() == ("error: --out /proc/mjxrow_x: cannot write in /proc (No such "
                                  "file or directory)"), res.stderr
    assert "warp" not in res.stdout


def test_seg_train_checks_its_output_folder_first(capsys):
    from mjxrow.seg import train

    assert train.cli(["--crop", "zucchini", "--on-the-fly", "--steps", "1", "--out",
                      "/proc/x"]) == 2
    err = capsys.readouterr().err
    assert "--out" in err and len(err.strip().splitlines()) == 1, err


def test_bench_checks_its_record_file_first(capsys):
    from mjxrow.bench.__main__ import main as bench_main

    with pytest.raises(SystemExit) as exit_info:
        bench_main(["fields", "--out", "/proc/x/bench.jsonl"])
    assert exit_info.value.code == 2 and "--out" in capsys.readouterr().err


@pytest.mark.parametrize("data", ["missing", "not_a_dataset"])
def test_seg_train_restart_deletes_nothing_it_did_not_write(tmp_path, capsys, data):
    """`--restart` with a bad `--data`, or into a folder that holds no seg.train run, exits 2
    and leaves the folder as it was."""
    from mjxrow.seg import train

    out = tmp_path / "mine"
    out.mkdir()
    (out / "thesis.tex").write_text("years of work")
    folder = tmp_path / data
    if data == "not_a_dataset":
        folder.mkdir()
        (folder / "index.csv").write_text("path,mask,crop,condition,split\n")
    assert train.cli(["--crop", "zucchini", "--data", str(folder), "--steps", "1", "--restart",
                      "--out", str(out)]) == 2
    err = capsys.readouterr().err
    assert len(err.strip().splitlines()) == 1, err
    assert (out / "thesis.tex").read_text() == "years of work"
