"""The synthetic dataset: the CLI writes the asked samples (RGB, crop mask, class image) with the
paper's splits, resumes without rewriting, refuses a folder of another seed or variety, rejects
bad arguments; the on-the-fly batch function; valid sampled fields with curved rows, gaps and
weeds; camera poses along curved lanes; weeds are their own class, never crop."""

import jax
import jax.numpy as jnp
import numpy as np
import pandas as pd
import pytest
from PIL import Image

from mjxrow import field as F
from mjxrow import render as RD
from mjxrow.field import lanes as L
from mjxrow.seg import scenes as SC
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
    assert len(list(written.glob("*/class/*.png"))) == N
    assert not list(written.rglob(".tmp_*"))
    for i, row in index.iterrows():
        cond = RD.CONDITIONS[i % 4]
        assert row.condition == cond and row.rgb == f"{cond}/rgb/zucchini_{i:06d}.png"
        rgb = np.asarray(Image.open(written / row.rgb))
        mask = np.asarray(Image.open(written / row["mask"]))
        classes = np.asarray(Image.open(written / row.classes))
        assert rgb.shape == (SIZE, SIZE, 3) and rgb.dtype == np.uint8
        assert mask.shape == (SIZE, SIZE) and set(np.unique(mask)) <= {0, 255}
        assert set(np.unique(classes)) <= {RD.SKY, RD.SOIL, RD.PLANT, RD.OBSTACLE, RD.WEED}
        np.testing.assert_array_equal(mask == 255, classes == RD.PLANT)  # the crop, no weeds
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


def test_another_seed_or_variety_is_refused(written, capsys):
    files = {p: p.stat().st_mtime_ns for p in written.rglob("*") if p.is_file()}
    for extra in (["--variety", "none"], ["--seed", "1"]):
        assert run_cli("--crop", "zucchini", "--n", N, "--out", written, "--size", SIZE,
                       "--batch", 4, "--workers", 2, *extra) == 2
        assert "another --seed or --variety" in capsys.readouterr().err
    assert {p: p.stat().st_mtime_ns for p in written.rglob("*") if p.is_file()} == files


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
    # every field the sampler draws fits the dataset's static shape and is valid; a share of
    # them curved (sinusoid, arcs), gappy and weedy; variety "none": none of these
    keys = jax.random.split(jax.random.key(1), 64)
    for crop in ("lettuce", "pear"):
        shape = DS.dataset_shape(crop)
        assert shape.weed_slots > 0 and DS.dataset_shape(crop, "none").weed_slots == 0
        params = jax.vmap(lambda k, c=crop: DS.random_params(c, k))(keys)
        F.validate(params, shape)
        for name in ("row_amplitude", "row_curvature", "gap_rate", "weed_density"):
            share = np.mean(np.asarray(getattr(params, name)) != 0)
            assert 0.2 < share < 0.7, (crop, name, share)
        plain = jax.vmap(lambda k, c=crop: DS.random_params(c, k, "none"))(keys)
        F.validate(plain, DS.dataset_shape(crop, "none"))
        for name in ("row_amplitude", "row_curvature", "gap_rate", "weed_density"):
            assert not np.asarray(getattr(plain, name)).any()
        np.testing.assert_array_equal(plain.d_rr, params.d_rr)  # the same geometry draws


@pytest.fixture(scope="module")
def small():
    """A small flat lettuce field bent into arcs, with a few weeds and no obstacles: (field,
    shape)."""
    params = F.make_params("lettuce", host=True, row_length=6.0, terrain_length=10.0,
                           terrain_width=8.0, p_missing=0.0, stone_density=0.0,
                           branch_density=0.0, terrain_dh=0.0, row_curvature=0.08,
                           weed_density=0.2, weed_size=0.2)
    F.validate(params, shape := F.fit_shape(params, "lettuce"))
    return jax.jit(F.generate, static_argnums=1)(params, shape, jax.random.key(0)), shape


def test_poses_follow_curved_lanes(small):
    """On arcs, a pose lies on a lane's centre line offset by its `lateral` and looks along
    the lane (or back), not along x."""
    field, _ = small
    bend = L.field_bend(field)
    _, _, meta = jax.jit(jax.vmap(lambda k: SC.sample_pose(field, k)))(
        jax.random.split(jax.random.key(2), 64))
    meta = np.asarray(meta)
    s, u = (np.asarray(a) for a in L.to_field(bend, meta[:, 0], meta[:, 1]))
    lanes_u = np.asarray(field.lane_y)[np.asarray(field.lane_active)]
    assert np.abs((u - meta[:, 5])[:, None] - lanes_u[None]).min(1).max() < 1e-3
    along = np.asarray(L.heading(bend, s, u))
    turn = np.angle(np.exp(1j * (meta[:, 3] - along)))
    off = np.minimum(np.abs(turn), np.pi - np.abs(turn))  # forwards or backwards
    assert np.mean(off < np.deg2rad(20)) >= 0.8
    assert np.abs(along).max() > np.deg2rad(10)  # the lane does turn there


def test_a_weed_under_the_camera_is_weed_not_crop(small):
    """One weed in the middle of the widest lane, 1 m in front of a camera looking down at it
    along the curved lane: its pixels are of the weed class and none of them is in the crop
    mask (the dataset's ground truth); without the weed they are soil."""
    field, shape = small
    lane = int(np.argmax(np.where(field.lane_active, field.lane_width, 0.0)))
    bend = L.field_bend(field)
    wx, wy = L.to_world(bend, 0.0, field.lane_y[lane])
    wz = F.terrain_height(field.terrain, field.terrain_size, wx, wy)
    one = np.arange(shape.weed_slots) == 0
    field = field.replace(
        weed_pos=field.weed_pos.at[0].set(jnp.stack([wx, wy, wz])),
        weed_size=field.weed_size.at[0].set(jnp.asarray([0.25, 0.09])), weed_active=one)
    cam_xy = L.to_world(bend, -1.0, field.lane_y[lane])
    pos = jnp.stack([*cam_xy, wz + 0.5]).astype(jnp.float32)
    rot = RD.camera_rot(L.heading(bend, -1.0, field.lane_y[lane]), -np.arctan2(0.5, 1.0))
    intr, cond = RD.Intrinsics(32, 32), RD.conditions("cloudy")
    draw = jax.jit(lambda f: RD.render(f, shape, pos, rot, intr, cond))
    frame = draw(field)
    weed = np.asarray(frame.classes) == RD.WEED
    assert weed.sum() >= 6
    assert not np.asarray(frame.mask)[weed].any()
    bare = draw(field.replace(weed_active=np.zeros_like(one)))
    assert (np.asarray(bare.classes)[weed] == RD.SOIL).all()
    assert not np.asarray(bare.mask)[weed].any()
