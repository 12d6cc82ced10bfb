"""Sweep config: YAML parsing, one-line errors with dotted keys, grid expansion, hashes."""

import shutil
from pathlib import Path

import jax
import pytest
import yaml

from mjxrow.seg import checkpoint as seg_checkpoint
from mjxrow.seg import model as seg_model
from mjxrow.sweep import config as C
from mjxrow.sweep import grid as G
from mjxrow.sweep import reference as SD

GT = {"perception": {"source": "ground_truth"}}


def cfg_of(raw, **kw):
    return C.from_dict({**GT, **raw}, **kw)


def error_of(raw, **kw) -> str:
    with pytest.raises(C.ConfigError) as e:
        C.from_dict(raw, **kw)
    msg = str(e.value)
    assert "\n" not in msg
    return msg


def test_defaults_are_the_papers():
    cfg = cfg_of({})
    assert cfg.preset == "zucchini" and cfg.controller.name == "segzeros"
    assert cfg.controller.variant == "paper" and cfg.controller.omega_gain == 3.0
    assert cfg.robot.v_max == 0.5 and cfg.robot.omega_max == 1.0
    assert cfg.controller.v_limit == 0.5 and cfg.controller.omega_limit == 1.0
    assert cfg.sim.control_hz == 15.0 and cfg.sim.path_length == 20.0
    assert C.field_values(cfg)["d_rr"] == 1.8 and G.expand(cfg)[0].point == ()
    run = G.expand(cfg)[0].cfg  # every section is the domain config itself
    assert run.episode.n_steps == 900 and run.camera.width == 64 and run.sim.substeps == 7


def test_unknown_keys_name_their_dotted_path():
    assert error_of({"field": {"d_rrr": 1.5}}) == "field.d_rrr: unknown key; did you mean d_rr?"
    assert error_of({"controler": {}}) == "controler: unknown key; did you mean controller?"
    assert error_of({"camera": {"fov": 40}}).startswith("camera.fov: unknown key")
    assert error_of({"field": {"d_rr": {"start": 1, "stop": 2, "nm": 3}}}).startswith(
        "field.d_rr.nm: unknown key; did you mean num?")


def test_wrong_types():
    assert error_of({"seeds": "many"}) == "seeds: expected an integer, got str 'many'"
    assert error_of({"camera": {"width": 1.5}}).startswith("camera.width: expected an integer")
    assert error_of({**GT, "field": {"d_rr": [1.8, "wide"]}}).startswith(
        "field.d_rr[1]: expected a number")
    assert error_of({"robot": {"v_max": True}}).startswith("robot.v_max: expected")
    assert error_of({"render": {"shadows": 1}}).startswith("render.shadows: expected true")
    assert error_of({"robot": {"cam_fovy": 40}}) == (
        "robot.cam_fovy: cannot be set here: the camera's vertical field of view is camera.fovy")
    # a key of another controller is that controller's only (one YAML can switch controllers)
    oracle = G.expand(C.from_dict({"controller": {"name": "oracle", "omega_gain": 2}}))[0].cfg
    assert not hasattr(oracle.controller_params(), "omega_gain")
    assert error_of({"controller": {"omega_gian": 2}}).startswith(
        "controller.omega_gian: unknown key; did you mean omega_gain?")
    assert error_of({"episode": {"path_length": 20}}) == (
        "episode.path_length: unknown key; did you mean sim.path_length?")
    assert error_of({"controller": {"name": "pid"}}).startswith(
        "controller.name: 'pid' is not one of oracle, segzeros, segmin")
    assert error_of({"seeds": [1, 2]}) == "seeds: cannot be a grid axis; give one value"
    assert error_of({"field": [1]}).startswith("field: expected a mapping")


def test_impossible_values():
    assert error_of({"robot": {"v_max": -0.5}}) == "robot.v_max: must be positive, got -0.5"
    assert error_of({"robot": {"cam_pitch_deg": -95}}).startswith(
        "robot.cam_pitch_deg: must lie in (-90, 90)")
    assert error_of({"sim": {"dt": [0.01, -1]}}) == (
        "sim.dt: must be positive, got -1.0 (cell sim.dt=-1.0)")
    assert error_of({"render": {"kernel": "cuda"}}).startswith("render.kernel: 'cuda' is not")
    # negative spacing is caught by field.checks, naming the cell
    msg = error_of({**GT, "field": {"d_pp": [0.7, -0.1]}})
    assert msg == "field.d_pp: must be positive (cell field.d_pp=-0.1)"
    # plants wider than the row spacing of one cell of a 2-axis grid: the key given (d_rr) is
    # named, not the preset's plant width
    msg = error_of({**GT, "field": {"d_rr": [1.8, 0.5], "terrain_dh": [0.1, 0.2]}})
    assert msg.startswith("field.d_rr: plants are wider than their row spacing")
    assert "field.d_rr=0.5, field.terrain_dh=0.1" in msg
    msg = error_of({**GT, "field": {"d_rr": 1.8, "plant_width": 2.0}})
    assert msg.startswith("field.plant_width: plants are wider than their row spacing")
    assert error_of({**GT, "sim": {"path_length": 60}}).startswith(
        "sim.path_length: 60.0 m is longer than the rows (50 m)")
    assert error_of({**GT, "controller": {"name": "segmin", "smooth": 4}}).startswith(
        "controller.smooth: must be a positive odd width")
    assert error_of({**GT, "controller": {"heading_alpha": 0}}) == (
        "controller.heading_alpha: must lie in (0, 1], got 0.0")


def test_heading_alpha_reaches_the_controller():
    cell = G.expand(cfg_of({"controller": {"heading_alpha": 0.02}}))[0]
    assert float(cell.cfg.controller_params().heading_alpha) == pytest.approx(0.02)
    default = G.expand(cfg_of({}))[0].cfg
    assert float(default.controller_params().heading_alpha) == pytest.approx(0.005)


def test_missing_checkpoint(tmp_path):
    msg = error_of({"perception": {"source": "learned", "checkpoint": str(tmp_path / "nope")}})
    assert msg.startswith("perception.checkpoint: segmenter checkpoint ") and "nope" in msg
    ck = tmp_path / "ck"
    ck.mkdir()
    assert "no config.json" in error_of({"perception": {"checkpoint": str(ck)}})
    (ck / "config.json").write_text("{}")
    (ck / "weights").mkdir()
    assert "no 'model' mapping" in error_of({"perception": {"checkpoint": str(ck)}})
    (ck / "config.json").write_text('{"model": {}}')
    assert "weights/ holds no data" in error_of({"perception": {"checkpoint": str(ck)}})
    (ck / "weights" / "data").write_bytes(b"w")
    assert "weights/ cannot be restored" in error_of({"perception": {"checkpoint": str(ck)}})
    shutil.rmtree(ck)  # the config check restores the weights (no program compiled): real ones pass
    seg_checkpoint.save(ck, *seg_model.create("tiny", 0.25, jax.random.key(0), 32))
    cfg = C.from_dict({"perception": {"checkpoint": "ck"}}, base_dir=tmp_path)  # YAML-relative
    r = G.resolved(G.expand(cfg)[0].cfg)
    assert r["perception.checkpoint"] == str(ck.resolve())
    assert len(r["perception.checkpoint_id"]) == 16
    # a copy elsewhere is the same checkpoint; retrained weights are another one
    shutil.copytree(ck, tmp_path / "copy")
    h = G.cell_hash(G.expand(cfg)[0])
    copy = C.from_dict({"perception": {"checkpoint": str(tmp_path / "copy")}})
    assert G.cell_hash(G.expand(copy)[0]) == h
    (ck / "config.json").write_text('{"retrained": 1}')
    G.checkpoint_id.cache_clear()
    assert G.resolved(G.expand(cfg)[0].cfg)["perception.checkpoint_id"] != \
        r["perception.checkpoint_id"]
    assert G.cell_hash(G.expand(cfg)[0]) != h
    # the oracle needs no checkpoint; ground truth neither
    C.from_dict({"controller": {"name": "oracle"}, "perception": {"checkpoint": "nope"}})
    C.from_dict({"perception": {"source": "ground_truth", "checkpoint": "nope"}})


def test_ranges_lists_and_grid_order():
    cfg = cfg_of({"field": {"terrain_dh": {"start": 0.0, "stop": 0.3, "num": 4},
                            "d_rr": [1.6, 2.0, 2.4]}})
    assert cfg.field.terrain_dh == (0.0, 0.1, 0.2, 0.3)
    assert cfg.axis_order == ("field.terrain_dh", "field.d_rr")
    cells = G.expand(cfg)
    assert len(cells) == 12
    # first axis slowest
    assert [c.point for c in cells[:4]] == [
        (("field.terrain_dh", 0.0), ("field.d_rr", d)) for d in (1.6, 2.0, 2.4)
    ] + [(("field.terrain_dh", 0.1), ("field.d_rr", 1.6))]
    assert cells[4].cfg.field.d_rr == 2.0 and cells[4].cfg.field.terrain_dh == 0.1
    assert G.resolved(cells[4].cfg)["field.d_rr"] == 2.0
    assert G.resolved(cells[4].cfg)["field.d_pp"] == 0.7  # zucchini's preset value


def test_axes_on_any_section_and_preset():
    cfg = cfg_of({"preset": ["zucchini", "vineyard"], "controller": {"omega_gain": [2, 3, 4]},
                  "camera": {"width": [32, 64]}})
    assert len(G.expand(cfg)) == 12
    vine = [c for c in G.expand(cfg) if c.cfg.preset == "vineyard"][0]
    assert C.field_values(vine.cfg)["d_rr"] == 2.7


def test_set_overrides():
    cfg = cfg_of({"field": {"terrain_dh": [0.1, 0.2]}},
                 sets=["field.d_rr=[1.6, 1.8]", "seeds=3", "controller.variant=public"])
    assert cfg.field.d_rr == (1.6, 1.8) and cfg.seeds == 3
    assert cfg.controller.variant == "public"
    assert cfg.axis_order == ("field.terrain_dh", "field.d_rr")  # --set axes come last
    assert len(G.expand(cfg)) == 4
    assert error_of({}, sets=["field.d_rr2=1"]).startswith("field.d_rr2: unknown key")
    assert error_of({}, sets=["seeds"]).startswith("--set 'seeds': expected key=value")


def test_load_file_errors(tmp_path):
    bad = tmp_path / "bad.yaml"
    bad.write_text("name: x\nfield:\n  d_rr: [1.2, 1.8\n")
    with pytest.raises(C.ConfigError, match=r"bad\.yaml:\d+: invalid YAML"):
        C.load(bad)
    unsafe = tmp_path / "unsafe.yaml"
    unsafe.write_text("name: !!python/object/apply:os.system ['true']\n")
    with pytest.raises(C.ConfigError, match="name: a value tagged tag:yaml.org,2002:python/"):
        C.load(unsafe)
    with pytest.raises(C.ConfigError, match="cannot read"):
        C.load(tmp_path / "missing.yaml")


def test_smoke_shrinks_to_two_by_two():
    cfg = cfg_of({"field": {"d_rr": [1.6, 1.8, 2.0, 2.4], "terrain_dh": [0.0, 0.1, 0.3],
                            "d_pp": [0.6, 0.7]}, "seeds": 10}, smoke=True)
    cells = G.expand(cfg)
    assert [c.point for c in cells] == [
        (("field.d_rr", a), ("field.terrain_dh", b)) for a in (1.6, 2.4) for b in (0.0, 0.3)]
    assert cfg.field.d_pp == 0.6 and cfg.seeds == 2 and cfg.camera.width == 16
    assert cfg.sim.path_length <= C.field_values(cells[0].cfg)["row_length"]


def test_hashes_and_static_keys():
    a = G.expand(cfg_of({"field": {"d_rr": [1.6, 2.0]}}))
    b = G.expand(cfg_of({"field": {"d_rr": [1.6, 2.0]}, "name": "other", "batch_size": 3}))
    assert [G.cell_hash(c) for c in a] == [G.cell_hash(c) for c in b]  # name/batch don't count
    assert G.cell_hash(a[0]) != G.cell_hash(a[1])
    assert G.cell_hash(a[0], "shape A") != G.cell_hash(a[0], "shape B")
    c = G.expand(cfg_of({"field": {"d_rr": 1.6}, "seed": 1}))
    assert G.cell_hash(c[0]) != G.cell_hash(a[0])  # another base seed, other numbers
    # traced axes share the static key; an image-size axis does not
    assert G.static_key(a[0].cfg) == G.static_key(a[1].cfg)
    w = G.expand(cfg_of({"camera": {"width": [16, 32]}}))
    assert G.static_key(w[0].cfg) != G.static_key(w[1].cfg)
    s = G.expand(cfg_of({"sim": {"iterations": [4, 8]}, "render": {"shadows": [True, False]}}))
    assert len({G.static_key(c.cfg) for c in s}) == 4  # solver and renderer settings sweep too
    # start-pose noise is per episode: an axis of it is one group
    n = G.expand(cfg_of({"episode": {"start_offset_std": [0.0, 0.1], "start_yaw_std": [0, 5]}}))
    assert len(n) == 4 and len({G.static_key(c.cfg) for c in n}) == 1
    assert not C.is_static("episode.start_offset_std") and not C.is_static("episode.start_yaw_std")


def test_docs_list_every_key():
    doc = (Path(__file__).parents[1] / "docs" / "sweep.md").read_text()
    for key, _ in C.leaf_keys():
        assert f"`{key}`" in doc, key
    # the domain configs' own fields are the keys, and their comments the docs
    assert "`sim.iterations`" in doc and "`render.terrain_steps`" in doc
    assert "`controller.lane_k_yaw`" in doc and "`robot.friction`" in doc


@pytest.mark.parametrize("name", ["sweeps.yaml", "mjxrow/sweep/presets.yaml",
                                  "sweeps/spacing_length.yaml", "sweeps/slope_roughness.yaml"])
def test_shipped_sweeps_are_valid(name):
    root = Path(__file__).parents[1]
    cfg = C.load(root / name, sets=["perception.source=ground_truth"])
    cells = G.expand(cfg)
    assert len(cells) * cfg.seeds >= 200, (len(cells), cfg.seeds)
    if name == "sweeps.yaml":
        assert cfg.preset == "zucchini" and cfg.controller.name == "segzeros"
        assert cfg.axis_order == ("field.d_rr", "field.terrain_dh")
        assert len(cfg.field.d_rr) >= 6 and len(cfg.field.terrain_dh) >= 6
        raw = yaml.safe_load((root / name).read_text())
        assert raw["perception"] == {**raw["perception"], "source": "learned",
                                     "checkpoint": "shipped"}


def test_docs_reference_table_is_current():
    doc = (Path(__file__).parents[1] / "docs" / "sweep.md").read_text()
    assert SD.reference_markdown() in doc


def test_docs_command_rewrites_the_table_after_its_marker_and_names_a_bad_file(tmp_path, capsys):
    doc = tmp_path / "keys.md"
    doc.write_text(f"# Keys\n\n{SD.MARK} -->\n| stale | table |\n|---|---|\n\nAfter.\n")
    assert SD.main([str(doc)]) == 0
    text = doc.read_text()
    assert SD.reference_markdown() in text and "| stale |" not in text
    assert text.endswith("\nAfter.\n")
    assert SD.main([str(doc)]) == 0 and "already current" in capsys.readouterr().out
    for bad, why in ((tmp_path / "missing.md", "no such file"), (tmp_path / "plain.md", "no line")):
        if bad.name == "plain.md":
            bad.write_text("# no marker\n")
        with pytest.raises(SystemExit) as e:
            SD.main([str(bad)])
        assert e.value.code == 2 and why in capsys.readouterr().err
