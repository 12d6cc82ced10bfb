"""Hostile inputs, table-driven: every case ends with exit code 2, a one-line error that names the
key, option or file at fault, and no output folder (an existing one left as it was): YAML
files, checkpoints (segmenter and policy), run and search folders handed back to a command,
names too long, a full disk. All of them fail in validation, before any field, model or
compiled program exists, so each takes well under a second (but the damaged weights, which
need a saved checkpoint, and the SIGTERM of train_policy.py, which waits for its start)."""

import json
import re
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
    ("out_climbs", _with(out="../../x"), [], "out: '../../x' climbs out of the working"),
    ("out_climbs_inside", _with(out="runs/../../x"), [], "out: 'runs/../../x' climbs out"),
    ("wheel_radius_tiny", _with(robot={"wheel_radius": 1e-300}), [],
     "robot.wheel_radius: 1e-300 m is outside the sane range"),
    ("robot_mass_huge", _with(robot={"mass": 1e30}), [], "robot.mass: 1e+30 kg is outside"),
    ("robot_friction_nan", _with(robot={"friction": float("nan")}), [], "robot.friction"),
    ("robot_torque_tiny", _with(), ["--set", "robot.wheel_torque=1.0e-200"],
     "robot.wheel_torque"),
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


def test_sweep_refuses_a_linked_cells_folder_before_reading_it(tmp_path, capsys):
    """OUT/cells a link to another folder: exit 2 in one line before any of its files is
    read, removed or written; the other folder is as it was."""
    elsewhere = tmp_path / "elsewhere"
    elsewhere.mkdir()
    (elsewhere / "0123456789abcdef.csv").write_text("not a cell\n")
    (elsewhere / ".x.123.tmp").write_text("theirs")
    out = tmp_path / "o"
    out.mkdir()
    (out / "cells").symlink_to(elsewhere)
    path = tmp_path / "s.yaml"
    path.write_text(yaml.safe_dump(BASE))
    assert S.main([str(path), "--out", str(out), "--no-progress"]) == 2
    err = capsys.readouterr().err.strip()
    assert "cells/ is a link" in err and "\n" not in err, err
    assert sorted(p.name for p in elsewhere.iterdir()) == [".x.123.tmp", "0123456789abcdef.csv"]
    assert sorted(p.name for p in out.iterdir()) == ["cells"]


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
    # the sweep restores the weights while it checks its config: no output folder yet
    raw = {**BASE, "controller": {"name": "segzeros"},
           "perception": {"source": "learned", "checkpoint": str(ck)}}
    (tmp_path / "s.yaml").write_text(yaml.safe_dump(raw))
    assert S.main([str(tmp_path / "s.yaml"), "--out", str(tmp_path / "o"), "--no-progress"]) == 2
    err = capsys.readouterr().err.strip()
    assert err.startswith("error: perception.checkpoint: ") and "cannot be restored" in err, err
    assert "\n" not in err and not (tmp_path / "o").exists()


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


@pytest.mark.parametrize("data", ["missing", "not_a_dataset", "init_missing", "dot_out",
                                  "dot_out_init_missing"])
def test_seg_train_restart_deletes_nothing_it_did_not_write(tmp_path, capsys, monkeypatch, data):
    """`--restart` with a bad `--data` or `--init`, or into a folder that holds no seg.train
    run (`--out .` included: the working directory), exits 2 and leaves the folder as it was."""
    from mjxrow.seg import train

    out = tmp_path / "mine"
    out.mkdir()
    (out / "thesis.tex").write_text("years of work")
    folder = tmp_path / ("not_a_dataset" if data == "not_a_dataset" else "missing")
    if data == "not_a_dataset":
        folder.mkdir()
        (folder / "index.csv").write_text("path,mask,crop,condition,split\n")
    args = ["--crop", "zucchini", "--steps", "1", "--restart", "--out", str(out)]
    if data.startswith("dot_out"):
        monkeypatch.chdir(out)
        args[-1] = "."
    if data.endswith("init_missing"):
        args += ["--init", str(tmp_path / "no_checkpoint"), "--on-the-fly"]
    else:
        args += ["--data", str(folder)]
    assert train.cli(args) == 2
    err = capsys.readouterr().err
    assert len(err.strip().splitlines()) == 1, err
    assert [p.name for p in out.iterdir()] == ["thesis.tex"]
    assert (out / "thesis.tex").read_text() == "years of work"


def test_seg_train_restart_keeps_the_users_files(tmp_path):
    """`--restart` in a folder that holds a seg.train run beside the user's own files deletes
    the run's entries (state/, best/, train_log.jsonl) and nothing else."""
    from mjxrow.seg import training

    out = tmp_path / "run"
    for d in ("state/1", "best"):
        (out / d).mkdir(parents=True)
    (out / "state/1/x").write_text("0")
    (out / "train_log.jsonl").write_text('{"step": 1}\n')
    (out / "thesis.tex").write_text("years of work")
    (out / "notes").mkdir()
    training.restart(out)
    assert sorted(p.name for p in out.iterdir()) == ["notes", "thesis.tex"]


def test_seg_train_log_with_a_cut_short_line_resumes(tmp_path):
    from mjxrow.seg import training

    log = tmp_path / "train_log.jsonl"
    log.write_text('{"step": 50, "loss": 0.5}\n{"step": 100, "loss": 0.4}\n{"step": 150, "lo')
    training._truncate_log(log, 100)
    assert log.read_text() == '{"step": 50, "loss": 0.5}\n{"step": 100, "loss": 0.4}\n'


def _dataset(root, rgb="a.png", png=b""):
    root.mkdir()
    (root / "index.csv").write_text("rgb,mask,crop,condition,split\n"
                                    + "".join(f"{rgb},m.png,zucchini,sunny,{s}\n"
                                              for s in ("train", "train", "test")))
    from PIL import Image
    Image.new("L", (16, 16)).save(root / "m.png")
    if png is not None:
        (root / "a.png").write_bytes(png)


@pytest.mark.parametrize("case,needle", [
    ("outside", "lies outside the dataset folder"),
    ("absolute", "lies outside the dataset folder"),
    ("truncated", "a.png: unreadable image"),
    ("not_png", "a.png: unreadable image"),
])
def test_seg_train_rejects_a_hostile_dataset(tmp_path, capsys, case, needle):
    """An index.csv path that leaves the folder is never opened; a truncated or foreign image is
    one line naming it; --out is not made."""
    import io

    from PIL import Image

    from mjxrow.seg import train

    buf = io.BytesIO()
    Image.new("RGB", (16, 16), (40, 160, 50)).save(buf, "PNG")
    rgb = {"outside": "../../../etc/hostname", "absolute": "/etc/hostname"}.get(case, "a.png")
    png = {"truncated": buf.getvalue()[:40], "not_png": b"#!/bin/sh\necho hi\n"}.get(
        case, buf.getvalue())
    _dataset(tmp_path / "d", rgb, png)
    out = tmp_path / "out"
    assert train.cli(["--crop", "zucchini", "--data", str(tmp_path / "d"), "--size", "16",
                      "--steps", "1", "--batch", "1", "--out", str(out), "--no-progress"]) == 2
    err = capsys.readouterr().err
    assert len(err.strip().splitlines()) == 1 and needle in err, err
    assert not out.exists()


def _nan_speed(d):
    d["action"]["v_max"] = float("nan")


# (id, change to the shipped policy.json (a function of the parsed dict, or the file's text),
# text the message must hold)
POLICY_CASES = [
    ("top_list", "[1, 2]", "expected a mapping, got list"),
    ("damaged", '{"observation": ', "is not a policy spec"),
    ("observation_list", lambda d: d.update(observation=[1, 2]), "observation: expected a mapping"),
    ("action_list", lambda d: d.update(action=[1]), "action: expected a mapping"),
    ("meta_text", lambda d: d.update(meta="x"), "meta: expected a mapping"),
    ("weights_int4", lambda d: d.update(weights_dtype="int4"), "weights_dtype: one of"),
    ("v_max_nan", _nan_speed, "action.v_max: expected a finite number, got nan"),
    ("v_max_text", lambda d: d["action"].update(v_max="fast"), "action.v_max"),
    ("omega_max_zero", lambda d: d["action"].update(omega_max=0.0), "action.omega_max"),
    ("height_text", lambda d: d["observation"].update(height="64"), "observation.height"),
    ("proprio_text", lambda d: d["observation"].update(proprio="yes"), "observation.proprio"),
    ("channels_text", lambda d: d["network"].update(channels="abc"), "network.channels"),
    ("hidden_huge", lambda d: d["network"].update(hidden=10**9), "network.hidden"),
    ("image_shape", lambda d: d["meta"].update(image_shape="x"), "meta.image_shape"),
]


def _policy_checkpoint(folder: Path, change) -> Path:
    """A policy checkpoint folder whose policy.json is the shipped one changed by `change`
    (a function of the parsed dict, or the file's whole text); params/ empty (never read)."""
    from mjxrow.policies import checkpoint as PC

    (folder / "params").mkdir(parents=True)
    if isinstance(change, str):
        text = change
    else:
        doc = json.loads((PC.SHIPPED / "policy.json").read_text())
        change(doc)
        text = json.dumps(doc)
    (folder / "policy.json").write_text(text)
    return folder


@pytest.mark.parametrize("change, needle", [c[1:] for c in POLICY_CASES],
                         ids=[c[0] for c in POLICY_CASES])
def test_sweep_checks_a_policy_checkpoint_past_its_json_shape(tmp_path, capsys, change, needle):
    """A policy.json of the wrong types or ranges (a NaN speed would run every episode into
    sim_error; int4 weights would be accepted): exit 2, one line naming controller.checkpoint
    and the field, before any weight is read or folder made."""
    ck = _policy_checkpoint(tmp_path / "ck", change)
    raw = {"name": "h", "seeds": 2, "controller": {"name": "policy", "checkpoint": str(ck)}}
    path = tmp_path / "s.yaml"
    path.write_text(yaml.safe_dump(raw))
    _rejected(capsys, S.main, [str(path), "--no-progress"], [], tmp_path / "o",
              f"controller.checkpoint: {ck / 'policy.json'} is not a policy spec")
    from mjxrow.policies import checkpoint as PC

    with pytest.raises(ValueError, match=re.escape(needle)):
        PC.read_spec(ck)
    PC.read_spec(PC.SHIPPED)  # the shipped one passes


# (id, the run folder's config.yaml (a mapping, or text), its results.csv or None, message)
FROM_RUN_CASES = [
    ("emptied_config", "", None, "config.yaml: empty file"),
    ("comments_config", "# cleared\n", None, "config.yaml: empty file"),
    ("invalid_config", "name: [1, 2\n", None, "config.yaml:2: invalid YAML"),
    ("list_config", "- 1\n- 2\n", None, "expected a mapping of keys"),
    ("unknown_key", "nope: 1\n", None, "config.yaml: nope: unknown key"),
    ("alias_bomb", ALIAS_BOMB, None, "f: more than 100,000 values"),
    ("no_cell_column", BASE, "episode,cell_hash,lane\n0,abc,1\n", "has no column 'cell'"),
    ("nan_lane", BASE, "cell,episode,cell_hash,lane\n0,0,abc,\n",
     "column 'lane' holds values that are not non-negative integers"),
    ("text_episode", BASE, "cell,episode,cell_hash\n0,first,abc\n", "column 'episode'"),
    ("binary_results", BASE, "\x00\xff\x00", "results.csv"),
]


@pytest.mark.parametrize("config, results, needle", [c[1:] for c in FROM_RUN_CASES],
                         ids=[c[0] for c in FROM_RUN_CASES])
def test_worlds_from_run_trusts_nothing_in_the_run_folder(tmp_path, capsys, config, results,
                                                         needle):
    """`worlds --from-run` over a run folder whose files were emptied, damaged or hand-edited:
    exit 2, one line naming --from-run and the file (an emptied config.yaml is no run, not
    the default sweep's), nothing exported."""
    from mjxrow.worlds import run as W

    run = tmp_path / "run"
    run.mkdir()
    (run / "config.yaml").write_text(config if isinstance(config, str) else
                                     yaml.safe_dump(config))
    if results is not None:
        (run / "results.csv").write_text(results)
    _rejected(capsys, W.main, ["--from-run", str(run), "--cell", "0", "--episode", "0"], [],
              tmp_path / "o", needle)


def test_worlds_from_run_without_a_config(tmp_path, capsys):
    from mjxrow.worlds import run as W

    _rejected(capsys, W.main, ["--from-run", str(tmp_path), "--cell", "0", "--episode", "0"],
              [], tmp_path / "o", "--from-run: no config.yaml in")


TRAIN_POLICY = ROOT / "experiments" / "train_policy.py"


def _train_policy():
    import importlib.util

    spec = importlib.util.spec_from_file_location("train_policy_hostile", TRAIN_POLICY)
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


@pytest.mark.parametrize("extra, needle", [
    (["--num-envs", "0"], "--num-envs: must be ≥ 1"),
    (["--unroll", "-1"], "--unroll"),
    (["--episodes", "0"], "--episodes"),
    (["--budget-minutes", "nan"], "--budget-minutes"),
    (["--deadline-minutes", "-1"], "--deadline-minutes"),
    (["--seed", "-1"], "--seed"),
    (["--eval-seed", str(2**32)], "--eval-seed"),
], ids=["num_envs", "unroll", "episodes", "budget_nan", "deadline", "seed", "eval_seed"])
def test_train_policy_checks_its_arguments_before_making_out(tmp_path, capsys, extra, needle):
    _rejected(capsys, _train_policy().main, ["--smoke"], extra, tmp_path / "o", needle)


def test_train_policy_out_a_file(tmp_path, capsys):
    (tmp_path / "o").write_text("mine")
    assert _train_policy().main(["--smoke", "--out", str(tmp_path / "o")]) == 2
    err = capsys.readouterr().err.strip()
    assert err == f"error: --out {tmp_path / 'o'}: exists and is not a folder", err
    assert (tmp_path / "o").read_text() == "mine"


def test_a_truncated_training_state_is_one_line_naming_the_step(tmp_path):
    """A training state whose step folder was cut short (a full disk, a killed copy): the
    resume fails in one line naming that step folder, not with orbax's traceback."""
    import numpy as np

    from mjxrow.train import state as TS

    tree = {"w": np.arange(64, dtype=np.float32), "b": np.ones(3, np.float32)}
    TS.save_state(tmp_path / "state", 7, tree, {"network": "tiny"})
    for f in (tmp_path / "state" / "7").rglob("*"):
        if f.is_file() and f.stat().st_size > 0:
            f.write_bytes(f.read_bytes()[: f.stat().st_size // 3])
    with pytest.raises(ValueError) as e:
        TS.restore_state(tmp_path / "state", tree, {"network": "tiny"}, key="--out")
    msg = str(e.value)
    assert msg.startswith(f"--out: the training state {tmp_path / 'state' / '7'} cannot be "
                          "restored") and "\n" not in msg, msg
    (tmp_path / "state" / "train.json").write_text('{"network": ')
    with pytest.raises(ValueError, match="train.json is damaged"):
        TS.restore_state(tmp_path / "state", tree, {"network": "tiny"}, key="--out")


def test_the_last_save_on_a_save_every_iteration_is_no_error(tmp_path):
    """The loop saves every `save_every` iterations and once more at its end: when the end
    falls on a saved iteration (75 of 75 with save_every 25, on an H100), the second save of
    that step is skipped, not orbax's "Checkpoint for step 75 already exists" (exit 2, no
    policy written)."""
    import numpy as np

    from mjxrow.train import state as TS

    tree = {"w": np.arange(8, dtype=np.float32)}
    TS.save_state(tmp_path / "state", 75, tree, {"network": "tiny"})
    TS.save_state(tmp_path / "state", 75, tree, {"network": "tiny"})
    step, got = TS.restore_state(tmp_path / "state", tree, {"network": "tiny"})
    assert step == 75 and np.array_equal(got["w"], tree["w"])


def test_train_policy_sigterm_says_how_to_resume(tmp_path):
    """SIGTERM (a batch system's kill) while the run starts: exit 130 and one line saying
    that the saved state is kept and the same command resumes."""
    import os
    import signal
    import time

    out = tmp_path / "o"
    proc = subprocess.Popen([sys.executable, str(TRAIN_POLICY), "--smoke", "--no-eval",
                             "--no-progress", "--cache-dir", "none", "--out", str(out)],
                            stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True,
                            cwd=tmp_path, env={**os.environ, "PYTHONPATH": str(ROOT)})
    t0 = time.time()
    while not out.exists() and proc.poll() is None and time.time() - t0 < 120:
        time.sleep(0.05)
    proc.send_signal(signal.SIGTERM)
    _, err = proc.communicate(timeout=120)
    assert proc.returncode == 130, err
    assert f"the last saved training state in {out / 'state'} is kept; run the same command " \
           "again to resume" in err, err


def _long(tmp_path: Path) -> str:
    return str(tmp_path / ("x" * 300))  # one name past NAME_MAX (255): ENAMETOOLONG


@pytest.mark.parametrize("command", ["sweep", "episode", "worlds", "search", "seg.export",
                                     "seg.eval", "seg.synth"])
def test_a_name_too_long_is_one_line(tmp_path, capsys, command):
    """A 300-character --out (or --csv): exit 2 with one line naming the option, not an
    ENAMETOOLONG traceback; the message elides the name."""
    from mjxrow.search import run as search_run
    from mjxrow.seg import synth
    from mjxrow.worlds import run as W

    path = tmp_path / "s.yaml"
    path.write_text(yaml.safe_dump(BASE if command != "search" else SEARCH))
    long = _long(tmp_path)
    main, args = {
        "sweep": (S.main, [str(path), "--no-progress", "--out", long]),
        "episode": (EP.main, ["--n", "2", "--no-progress", "--out", long]),
        "worlds": (W.main, ["--preset", "zucchini", "--out", long]),
        "search": (search_run.main, [str(path), "--no-progress", "--out", long]),
        "seg.export": (SX.cli, ["--crop", "zucchini", "--out", long + "/m.onnx"]),
        "seg.eval": (SE.cli, ["--crop", "zucchini", "--csv", long + "/t.csv"]),
        "seg.synth": (synth.main, ["--crop", "zucchini", "--n", "2", "--out", long]),
    }[command]
    assert main(args) == 2
    err = capsys.readouterr().err.strip()
    assert err.startswith("error: --") and "File name too long" in err and "\n" not in err, err
    assert len(err) < 250, err


def test_a_full_disk_leaves_no_temp_file(tmp_path, monkeypatch):
    """ENOSPC in the middle of an atomic write: an OutputError (one line, naming the file and
    the full disk), the file as it was before, no temp file left."""
    import errno

    from mjxrow import files

    target = tmp_path / "results.csv"
    target.write_text("the earlier results\n")
    real = Path.write_bytes

    def full(self, data):
        real(self, data[: len(data) // 2])  # half of it reached the disk
        raise OSError(errno.ENOSPC, "No space left on device")

    monkeypatch.setattr(Path, "write_bytes", full)
    with pytest.raises(files.OutputError) as e:
        files.atomic_write_text(target, "a,b\n" * 1000)
    assert str(e.value).startswith(f"{target}: cannot be written (No space left on device)")
    assert "\n" not in str(e.value)

    def save(tmp):
        Path(tmp).write_bytes(b"png" * 100)

    with pytest.raises(files.OutputError, match="No space left"):
        files.atomic_save(tmp_path / "figure.png", save)
    monkeypatch.undo()
    assert sorted(p.name for p in tmp_path.iterdir()) == ["results.csv"]
    assert target.read_text() == "the earlier results\n"


@pytest.mark.parametrize("extra, needle", [(["--size", "0"], "--size: 0 px"),
                                           (["--size", "-16"], "--size"),
                                           (["--size", "100000"], "--size: 100000 px"),
                                           (["--check", "-1"], "--check")],
                         ids=["size_0", "size_negative", "size_huge", "check_negative"])
def test_seg_export_checks_its_numbers(tmp_path, capsys, extra, needle):
    """`--size 0` would write an ONNX graph for 0×0 images: refused before any file."""
    out = tmp_path / "o"
    assert SX.cli(["--crop", "zucchini", "--out", str(out / "m.onnx"), *extra]) == 2
    err = capsys.readouterr().err.strip()
    assert err.startswith(f"error: {needle}") and "\n" not in err, err
    assert not out.exists()


SEARCH = {"name": "hostile", "preset": "zucchini", "controller": {"name": "oracle"},
          "perception": {"source": "ground_truth"}, "population": 4, "repeats": 1,
          "budget": {"episodes": 8}, "box": {"field.d_rr": [1.8, 2.4]}}
SEARCH_CASES = [
    ("out_climbs", {**SEARCH, "out": "../../x"}, "out: '../../x' climbs out"),
    ("out_empty", {**SEARCH, "out": " "}, "out: must not be empty"),
    ("box_nan", {**SEARCH, "box": {"field.d_rr": [float("nan"), 2.4]}}, "box.field.d_rr[0]"),
    ("box_inf", {**SEARCH, "box": {"field.d_rr": [1.8, float("inf")]}}, "box.field.d_rr[1]"),
    ("box_text", {**SEARCH, "box": {"field.d_rr": "wide"}}, "box.field.d_rr: expected"),
    ("minutes_nan", {**SEARCH, "budget": {"minutes": float("nan")}}, "budget.minutes"),
    ("population", {**SEARCH, "population": 10**9}, "population"),
    ("alias_bomb", ALIAS_BOMB, "f: more than 100,000 values"),
    ("name_a_date", "name: 2024-01-01\n", "name: a date or time"),
    ("robot", {**SEARCH, "robot": {"wheel_radius": 1e-300}}, "robot.wheel_radius"),
]


@pytest.mark.parametrize("content, needle", [c[1:] for c in SEARCH_CASES],
                         ids=[c[0] for c in SEARCH_CASES])
def test_search_rejects(tmp_path, capsys, content, needle):
    from mjxrow.search import run as search_run

    path = tmp_path / "s.yaml"
    path.write_text(content if isinstance(content, str) else yaml.safe_dump(content))
    _rejected(capsys, search_run.main, [str(path), "--no-progress"], [], tmp_path / "o", needle)


def _search_shape(tmp_path) -> str:
    from mjxrow.search import config as search_config

    path = tmp_path / "s.yaml"
    path.write_text(yaml.safe_dump(SEARCH))
    return repr(search_config.load(path).shape)


# (id, files in the --out folder ({name: text}; SHAPE: the search's own shape), message)
SEARCH_FOLDER_CASES = [
    ("state_damaged", {"state.json": "{not json"}, "state.json is unreadable"),
    ("state_a_list", {"state.json": "[1]"}, "state.json is not a mapping (a list)"),
    ("state_rows", {"state.json": '{"shape": SHAPE, "rows": "many"}'}, "counts 'many' rows"),
    ("state_rows_no_csv", {"state.json": '{"shape": SHAPE, "rows": 4}'},
     "counts 4 candidates but candidates.csv is missing"),
    ("another_shape", {"state.json": '{"shape": "x"}'}, "another field shape"),
    ("config_bomb", {"state.json": '{"shape": SHAPE}', "config.yaml": ALIAS_BOMB},
     "config.yaml cannot be read (f: more than 100,000 values"),
    ("config_empty", {"state.json": '{"shape": SHAPE}', "config.yaml": ""},
     "config.yaml cannot be read"),
    ("candidates_alone", {"candidates.csv": "x\n1\n"}, "holds candidates.csv but no state.json"),
]


@pytest.mark.parametrize("folder, needle", [c[1:] for c in SEARCH_FOLDER_CASES],
                         ids=[c[0] for c in SEARCH_FOLDER_CASES])
def test_search_checks_its_folder_before_writing_it(tmp_path, capsys, folder, needle):
    """A --out folder with a damaged or foreign search in it: exit 2, one line naming --out,
    and the folder exactly as it was (no .lock, no config.yaml rewritten)."""
    from mjxrow.search import run as search_run

    out = tmp_path / "o"
    out.mkdir()
    shape = json.dumps(_search_shape(tmp_path))
    for name, text in folder.items():
        (out / name).write_text(text.replace("SHAPE", shape))
    before = {p.name: p.read_text() for p in out.iterdir()}
    assert search_run.main([str(tmp_path / "s.yaml"), "--out", str(out), "--no-progress"]) == 2
    err = capsys.readouterr().err.strip()
    assert err.startswith(f"error: --out {out}: ") and needle in err and "\n" not in err, err
    assert {p.name: p.read_text() for p in out.iterdir()} == before
