"""The synthetic dataset: the CLI writes the asked pairs with the paper's splits, resumes without
rewriting, rejects bad arguments; the on-the-fly batch function; valid sampled fields."""

import jax
import numpy as np
import pandas as pd
import pytest
from PIL import Image

from mjxrow import field as F
from mjxrow import render as RD
from mjxrow.seg import synthesis as DS

N, SIZE = 8, 16


def run_cli(*args):
    """Exit status of the CLI (argparse errors raise SystemExit)."""
    try:
        return DS.main([str(a) for a in args])
    except SystemExit as e:
        return e.code


@pytest.fixture(scope="module")
def written(tmp_path_factory):
    out = tmp_path_factory.mktemp("ds") / "zucchini"
    code = run_cli("--crop", "zucchini", "--n", N, "--out", out, "--size", SIZE,
                   "--batch", 4, "--workers", 2)
    assert code == 0
    return out


def test_writes_the_asked_pairs(written):
    index = pd.read_csv(written / "index.csv")
    assert list(index.columns) == list(DS.COLUMNS)
    assert len(index) == N
    assert sorted(p.name for p in written.glob("*/rgb/*.png")) == sorted(
        f"zucchini_{i:06d}.png" for i in range(N))
    assert len(list(written.glob("*/mask/*.png"))) == N
    assert not list(written.rglob(".tmp_*"))
    for i, row in index.iterrows():
        cond = RD.CONDITIONS[i % 4]
        assert row.condition == cond and row.rgb == f"{cond}/rgb/zucchini_{i:06d}.png"
        rgb = np.asarray(Image.open(written / row.rgb))
        mask = np.asarray(Image.open(written / row["mask"]))
        assert rgb.shape == (SIZE, SIZE, 3) and rgb.dtype == np.uint8
        assert mask.shape == (SIZE, SIZE) and set(np.unique(mask)) <= {0, 255}
    # robot-height cameras about 10° down, most of them inside the field's rows
    assert (index.pitch < np.deg2rad(5)).all() and (index.pitch > np.deg2rad(-40)).all()
    assert (index.lateral.abs() < 1.0).all()


def test_split_fractions(written):
    index = pd.read_csv(written / "index.csv")
    # 2 samples per condition, round(0.3 · 2) = 1 test sample in each
    assert (index.groupby("condition").split.apply(lambda s: (s == "test").sum()) == 1).all()
    s = DS.splits(400, seed=3, test_frac=0.25)
    assert (s == "test").sum() == 100
    assert all((s[c::4] == "test").sum() == 25 for c in range(4))
    assert np.array_equal(s, DS.splits(400, seed=3, test_frac=0.25))
    assert not np.array_equal(s, DS.splits(400, seed=4, test_frac=0.25))


def test_resume_rewrites_nothing(written):
    files = sorted(written.rglob("*.png")) + [written / "index.csv"]
    before = {p: p.stat().st_mtime_ns for p in files}
    index_text = (written / "index.csv").read_text()
    assert run_cli("--crop", "zucchini", "--n", N, "--out", written, "--size", SIZE,
                   "--batch", 4, "--workers", 2) == 0
    assert {p: p.stat().st_mtime_ns for p in files} == before
    # a lost pair is rendered again, identical; the others stay untouched
    lost = written / "cloudy" / "rgb" / "zucchini_000005.png"
    old = np.asarray(Image.open(lost))
    lost.unlink()
    assert run_cli("--crop", "zucchini", "--n", N, "--out", written, "--size", SIZE,
                   "--batch", 4, "--workers", 2) == 0
    assert np.array_equal(np.asarray(Image.open(lost)), old)
    assert all(p.stat().st_mtime_ns == t for p, t in before.items() if p != lost)
    assert (written / "index.csv").read_text() == index_text


def test_resume_renders_damaged_images_again(written, capsys):
    """A PNG cut short, one that is not a PNG and a temp file of a killed run: the re-run
    reports the two images, renders them again (identical to the first run), removes the temp
    file and touches nothing else."""
    cut = written / "sunny" / "rgb" / "zucchini_000004.png"
    junk = written / "crepuscular" / "mask" / "zucchini_000002.png"
    old = {p: p.read_bytes() for p in (cut, junk)}
    cut.write_bytes(old[cut][: len(old[cut]) // 2])
    junk.write_bytes(b"not a png")
    tmp = written / "sunny" / "rgb" / ".tmp_killed.png"
    tmp.write_bytes(b"half")
    others = {p: p.stat().st_mtime_ns for p in written.rglob("*.png")
              if p not in old and not p.name.startswith(".")}
    capsys.readouterr()
    assert run_cli("--crop", "zucchini", "--n", N, "--out", written, "--size", SIZE,
                   "--batch", 4, "--workers", 2) == 0
    err = capsys.readouterr().err
    assert "2 damaged image(s)" in err and "zucchini_000004.png" in err, err
    assert all(p.read_bytes() == b for p, b in old.items())
    assert not list(written.rglob(".tmp_*"))
    assert {p: p.stat().st_mtime_ns for p in others} == others


def test_bad_arguments_exit_2(tmp_path, capsys):
    assert run_cli("--crop", "cabbage", "--n", 4, "--out", tmp_path) == 2
    assert "cabbage" in capsys.readouterr().err
    assert run_cli("--crop", "lettuce", "--n", 0, "--out", tmp_path) == 2
    assert "--n" in capsys.readouterr().err
    blocker = tmp_path / "a_file"
    blocker.write_text("")
    assert run_cli("--crop", "lettuce", "--n", 4, "--out", blocker / "sub") == 2
    assert "cannot write" in capsys.readouterr().err
    assert not list(tmp_path.rglob("*.png"))


def test_batch_fn_and_fields(written):
    # called as is, the batch function shares the CLI's compiled renderer (same crop, size)
    fn = DS.make_batch_fn("zucchini", RD.Intrinsics(SIZE, SIZE))
    rgb, mask = fn(jax.random.key(0), 4)
    assert rgb.shape == (4, SIZE, SIZE, 3) and rgb.dtype == np.uint8
    assert mask.shape == (4, SIZE, SIZE) and mask.dtype == bool
    assert np.asarray(mask).any() and not np.asarray(mask).all()
    again, _ = fn(jax.random.key(0), 4)
    assert np.array_equal(np.asarray(rgb), np.asarray(again))
    other, _ = fn(jax.random.key(1), 4)
    assert not np.array_equal(np.asarray(rgb), np.asarray(other))
    # every field the sampler draws fits the dataset's static shape and is valid
    for crop in ("lettuce", "pear"):
        shape = DS.dataset_shape(crop)
        keys = jax.random.split(jax.random.key(1), 64)
        params = jax.vmap(lambda k, c=crop: DS.random_params(c, k))(keys)
        F.validate(params, shape)
