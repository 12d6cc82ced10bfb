"""Exported worlds: spacings read back from the CSV, MJCF and SDF of a tiny field, MuJoCo loading,
heightfield heights, camera view, CLI errors."""

import os
import subprocess
import sys
import xml.etree.ElementTree as ET

os.environ.setdefault("MUJOCO_GL", "osmesa")

import jax  # noqa: E402
import mujoco  # noqa: E402
import numpy as np  # noqa: E402
import pandas as pd  # noqa: E402
import pytest  # noqa: E402
from PIL import Image  # noqa: E402

from mjxrow import field as F  # noqa: E402
from mjxrow.crops import prims as PL  # noqa: E402
from mjxrow.field import export as Wd  # noqa: E402

# 12 × 12 m terrain, 2 groups of 2 rows: rows at y = -3.6, -1.8, 1.8, 3.6 (gaps 1.8, 3.6, 1.8),
# 8 m rows with a plant every 0.7 m → 12 plants per row.
D_RR, D_RGROUP, D_PP, RPG, N_ROWS, N_PLANTS = 1.8, 3.6, 0.7, 2, 4, 12
K = PL.n_prims("zucchini")  # leaves + a central mound (the last, centred on the plant base)


@pytest.fixture(scope="module")
def tiny():
    params = F.make_params("zucchini", terrain_length=12.0, row_length=8.0, terrain_width=12.0,
                           rows_per_group=RPG, plant_jitter=0.01, p_missing=0.1,
                           stone_density=8.0, branch_density=4.0)
    shape = F.fit_shape(params, "zucchini")
    F.validate(params, shape)
    gen = jax.jit(F.generate, static_argnums=1)
    field = jax.tree.map(np.asarray, gen(params, shape, jax.random.key(3)))
    assert int(field.n_rows) == N_ROWS and field.plant_active.sum() < N_ROWS * N_PLANTS
    return field, shape


@pytest.fixture(scope="module")
def paths(tiny, tmp_path_factory):
    return Wd.export(*tiny, tmp_path_factory.mktemp("worlds"), "tiny")


@pytest.fixture(scope="module")
def model(paths):
    m = mujoco.MjModel.from_xml_path(str(paths["xml"]))
    d = mujoco.MjData(m)
    mujoco.mj_forward(m, d)
    return m, d


def _check_spacing(row, index, x, y):
    """Rows ordered by y with gaps d_rr, d_RR, d_rr; median plant spacing d_pp (2 cm)."""
    rows = np.unique(row)
    assert list(rows) == list(range(N_ROWS))
    row_y = np.array([np.median(y[row == r]) for r in rows])
    assert np.all(np.diff(row_y) > 0), "row index not ordered by y"
    np.testing.assert_allclose(np.diff(row_y), [D_RR, D_RGROUP, D_RR], atol=0.02)
    steps = [np.diff(x[row == r][np.argsort(index[row == r])]) / np.diff(np.sort(index[row == r]))
             for r in rows]
    assert abs(np.median(np.concatenate(steps)) - D_PP) < 0.02
    gaps = np.diff(row_y)
    groups = np.split(rows, np.flatnonzero(gaps > 0.5 * (D_RR + D_RGROUP)) + 1)
    assert [len(g) for g in groups] == [RPG] * (N_ROWS // RPG)


def test_plants_csv_spacing(tiny, paths):
    field, _ = tiny
    t = pd.read_csv(paths["plants"])
    assert {"x", "y", "z", "row", "index", "kind", "length", "width", "height", "yaw"} <= set(t)
    assert len(t) == field.plant_active.sum() and (t["kind"] == "zucchini").all()
    _check_spacing(t["row"].to_numpy(), t["index"].to_numpy(), t["x"].to_numpy(),
                   t["y"].to_numpy())
    # base centres lie on the terrain
    z = F.terrain_height(field.terrain, field.terrain_size, t["x"].to_numpy(), t["y"].to_numpy())
    np.testing.assert_allclose(t["z"], z, atol=2e-4)


def test_lanes_csv(tiny, paths):
    field, _ = tiny
    t = pd.read_csv(paths["lanes"])
    assert list(t.columns) == ["lane", "y", "x_start", "x_end", "z_start", "z_end", "width",
                               "default"]
    np.testing.assert_allclose(t["width"], [D_RR, D_RGROUP, D_RR], atol=1e-3)
    np.testing.assert_allclose(t["y"], [-2.7, 0.0, 2.7], atol=1e-3)
    # rows start at −row_length/2 and end at the last plant slot: −4 + 11 · 0.7 = 3.7 m
    np.testing.assert_allclose(t[["x_start", "x_end"]].to_numpy(), [[-4.0, 3.7]] * 3, atol=1e-3)
    assert t["default"].sum() == 1 and int(t["lane"][t["default"] == 1].iloc[0]) == int(
        F.robot_lane(field))


def _plant_geoms(m):
    out = {}
    for g in range(m.ngeom):
        name = mujoco.mj_id2name(m, mujoco.mjtObj.mjOBJ_GEOM, g)
        if name and name.startswith("plant_"):
            r, p, k = (int(s[1:]) for s in name.split("_")[1:])
            out[(r, p, k)] = g
    return out


def test_mjcf_loads_with_every_primitive(tiny, model):
    field, shape = tiny
    m, d = model
    geoms = _plant_geoms(m)
    assert len(geoms) == field.plant_active.sum() * K
    ids = np.array(list(geoms.values()))
    assert (m.geom_contype[ids] == 0).all() and (m.geom_conaffinity[ids] == 0).all()
    assert (m.geom_group[ids] == 1).all()
    names = [mujoco.mj_id2name(m, mujoco.mjtObj.mjOBJ_GEOM, g) for g in range(m.ngeom)]
    obst = [i for i, n in enumerate(names) if n.startswith(("stone_", "branch_"))]
    assert len(obst) == field.obst_active.sum() > 0 and (m.geom_group[obst] == 2).all()
    assert m.geom_group[names.index("terrain")] == 0
    assert mujoco.mj_name2id(m, mujoco.mjtObj.mjOBJ_CAMERA, "eye") == 0
    # positions, orientations and sizes equal plants.plant_prims (mm, 1e-3 rad)
    prims = jax.tree.map(np.asarray, PL.plant_prims(field, shape))
    keys = list(geoms)
    r, p, k = np.array(keys).T
    np.testing.assert_allclose(d.geom_xpos[ids], prims.centre[r, p, k], atol=1e-3)
    np.testing.assert_allclose(d.geom_xmat[ids].reshape(-1, 3, 3), prims.rot[r, p, k], atol=2e-3)
    np.testing.assert_allclose(m.geom_size[ids], prims.size[r, p, k], atol=1e-3)
    # spacing from the central mounds (k = K-1), which sit on the plant base
    mound = [(key, g) for key, g in geoms.items() if key[2] == K - 1]
    rr = np.array([key[0] for key, _ in mound])
    pp = np.array([key[1] for key, _ in mound])
    xyz = d.geom_xpos[[g for _, g in mound]]
    _check_spacing(rr, pp, xyz[:, 0], xyz[:, 1])


def test_hfield_heights(tiny, model):
    field, _ = tiny
    m, d = model
    g = mujoco.mj_name2id(m, mujoco.mjtObj.mjOBJ_GEOM, "terrain")
    h = m.hfield_data.reshape(m.hfield_nrow[0], m.hfield_ncol[0]) * m.hfield_size[0, 2]
    assert h.shape == field.terrain.shape
    np.testing.assert_allclose(h + m.geom_pos[g, 2], field.terrain, atol=1e-3)
    assert np.ptp(field.terrain) > 0.1  # not trivially flat
    # placement: vertical rays hit the terrain where field.terrain_height says
    rng = np.random.default_rng(0)
    pts = rng.uniform(-5.5, 5.5, (40, 2))
    hit = np.zeros(1, np.int32)
    groups = np.array([1, 0, 0, 0, 0, 0], np.uint8)
    z_ray = [5.0 - mujoco.mj_ray(m, d, np.array([x, y, 5.0]), np.array([0.0, 0.0, -1.0]),
                                 groups, 1, -1, hit) for x, y in pts]
    z_ref = F.terrain_height(field.terrain, field.terrain_size, pts[:, 0], pts[:, 1])
    np.testing.assert_allclose(z_ray, z_ref, atol=1e-3)


def test_eye_camera_looks_down_the_default_lane(tiny, model):
    field, _ = tiny
    m, d = model
    lane = int(F.robot_lane(field))
    cam = mujoco.mj_name2id(m, mujoco.mjtObj.mjOBJ_CAMERA, "eye")
    pos, rot = Wd.lane_camera(field)
    np.testing.assert_allclose(d.cam_xpos[cam], pos, atol=1e-3)
    np.testing.assert_allclose(d.cam_xmat[cam].reshape(3, 3), rot, atol=1e-4)
    assert abs(pos[1] - field.lane_y[lane]) < 1e-3 and -rot[0, 2] > 0.9  # looks along +x
    try:
        renderer = mujoco.Renderer(m, 60, 80)
    except Exception as e:  # no offscreen GL: fail loudly, never skip in silence
        pytest.fail(f"no MuJoCo offscreen rendering with MUJOCO_GL="
                    f"{os.environ.get('MUJOCO_GL')!r}: {e}. Install the system package "
                    "libosmesa6 (apt-get install libosmesa6) or set MUJOCO_GL=egl on a GPU")
    renderer.enable_segmentation_rendering()
    renderer.update_scene(d, camera="eye")
    seg = renderer.render()[..., 0]
    renderer.close()
    names = np.array([mujoco.mj_id2name(m, mujoco.mjtObj.mjOBJ_GEOM, g) or ""
                      for g in range(m.ngeom)] + ["sky"])
    what = np.char.partition(names[seg], "_")[..., 0]
    assert (what[0] == "sky").all()  # camera pitched 15° down, fovy 45°: the top row is sky
    assert what[-1, 40] == "terrain"  # the lane ahead is free
    assert (what[-20:, :15] == "plant").mean() > 0.3  # rows on both sides
    assert (what[-20:, -15:] == "plant").mean() > 0.3


def test_sdf(tiny, paths):
    field, shape = tiny
    root = ET.parse(paths["sdf"]).getroot()
    assert root.tag == "sdf" and root.get("version") == "1.9"
    visuals = [v.get("name") for v in root.iter("visual")]
    plant_vis = [n for n in visuals if n.startswith("plant_")]
    assert len(plant_vis) == len(set(plant_vis)) == field.plant_active.sum() * K
    coll = [c.get("name") for c in root.iter("collision") if c.get("name").startswith("plant_")]
    assert len(coll) == field.plant_active.sum()  # one footprint dome per plant
    prim_root = ET.fromstring(Wd.to_sdf(field, shape, "t", collisions="primitives")[0])
    assert sum(c.get("name").startswith("plant_") for c in prim_root.iter("collision")) == len(
        plant_vis)
    assert sum(n.startswith(("stone_", "branch_")) for n in visuals) == field.obst_active.sum()
    # the heightmap: square 2^n+1, row 0 at +y, heights = pos.z + pixel/65535 · size.z
    hm = root.find(".//collision/geometry/heightmap")
    img = np.asarray(Image.open(paths["sdf"].parent / hm.findtext("uri")), np.float64)
    n = img.shape[0]
    assert img.shape == (n, n) and (n - 1) & (n - 2) == 0
    size = np.array(hm.findtext("size").split(), float)
    z0 = float(hm.findtext("pos").split()[2])
    np.testing.assert_allclose(size[:2], field.terrain_size, atol=1e-3)
    j, i = np.meshgrid(np.arange(0, n, 7), np.arange(0, n, 5), indexing="ij")
    x = (i / (n - 1) - 0.5) * size[0]
    y = (0.5 - j / (n - 1)) * size[1]
    ref = F.terrain_height(field.terrain, field.terrain_size, x, y)
    np.testing.assert_allclose(z0 + img[j, i] / 65535 * size[2], ref, atol=1e-3)


def test_cli_bad_input_names_the_key(tmp_path, capsys):
    for item, key in (("d_rr=-1", "d_rr"), ("bogus=1", "bogus"), ("d_pp", "d_pp"),
                      ("terrain_dh=abc", "terrain_dh"), ("p_missing=1.5", "p_missing")):
        assert Wd.main(["--preset", "lettuce", "--out", str(tmp_path), "--set", item]) == 2
        err = capsys.readouterr().err
        assert key in err and len(err.strip().splitlines()) == 1
    assert not any(tmp_path.iterdir())
    proc = subprocess.run([sys.executable, "-m", "mjxrow.worlds", "--preset", "chard", "--set",
                           "d_RR=0.2", "--out", str(tmp_path)], capture_output=True, text=True)
    assert proc.returncode == 2 and "plant_width" in proc.stderr and "d_RR" in proc.stderr


def test_overrides_grow_the_shape():
    # 30 m wide chard: 10 groups of 3 rows, more than the preset shape's max_rows
    sets = dict(terrain_width=30.0, terrain_length=8.0, row_length=6.0)
    params, shape = Wd.resolve("chard", sets)
    assert F.preset_shape("chard").max_rows < 30 <= shape.max_rows
    assert bool(np.all([np.all(ok) for ok, _ in F.checks(params, shape).values()]))
    assert not bool(F.checks(params, F.preset_shape("chard"))["max_rows"][0])
