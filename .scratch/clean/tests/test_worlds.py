"""Exported worlds: spacings read back from the CSV, MJCF and SDF of a tiny field, MuJoCo loading
and stepping with the robot, heightfield heights, camera view, both Gazebo flavours (parsed by
sdformat where installed), a curved field with gaps and weeds in every format, the export of a
sweep episode, CLI errors."""

import os
import shutil
import subprocess
import sys
import xml.etree.ElementTree as ET
from pathlib import Path

os.environ.setdefault("MUJOCO_GL", "osmesa")

import jax  # noqa: E402
import mujoco  # noqa: E402
import numpy as np  # noqa: E402
import pandas as pd  # noqa: E402
import pytest  # noqa: E402
from PIL import Image  # noqa: E402

from mjxrow import field as F  # noqa: E402
from mjxrow.crops import prims as PL  # noqa: E402
from mjxrow.worlds import cli as worlds_cli  # noqa: E402
from mjxrow.worlds import export as Wd  # noqa: E402
from mjxrow.worlds import mjcf as worlds_mjcf  # noqa: E402
from mjxrow.worlds import replay  # noqa: E402
from mjxrow.worlds import scene as S  # noqa: E402

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
    return Wd.export(*tiny, tmp_path_factory.mktemp("worlds"), "tiny", gazebo="both")


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
                               "default"] + [f"spawn_{k}" for k in ("x", "y", "z", "roll",
                                                                    "pitch", "yaw")] + [
        f"{k}_{end}" for k in ("y", "s", "heading") for end in ("start", "end")]
    # straight rows: the ends' world coordinates are the field coordinates, heading +x
    np.testing.assert_array_equal(t[["y_start", "y_end"]].to_numpy(), t[["y", "y"]].to_numpy())
    np.testing.assert_array_equal(t[["s_start", "s_end"]].to_numpy(),
                                  t[["x_start", "x_end"]].to_numpy())
    assert (t[["heading_start", "heading_end"]] == 0).all().all()
    np.testing.assert_allclose(t["width"], [D_RR, D_RGROUP, D_RR], atol=1e-3)
    np.testing.assert_allclose(t["y"], [-2.7, 0.0, 2.7], atol=1e-3)
    # rows start at −row_length/2 and end at the last plant slot: −4 + 11 · 0.7 = 3.7 m
    np.testing.assert_allclose(t[["x_start", "x_end"]].to_numpy(), [[-4.0, 3.7]] * 3, atol=1e-3)
    assert t["default"].sum() == 1 and int(t["lane"][t["default"] == 1].iloc[0]) == int(
        F.robot_lane(field))
    # spawn: path_length (here the 8 m rows' length) before the row end, on the centre line,
    # heading +x, chassis origin above the terrain by about the wheels' radius
    robot = S.robot_for(field)
    np.testing.assert_allclose(t["spawn_x"], 3.7 - robot.sim.path_length, atol=1e-3)
    np.testing.assert_allclose(t["spawn_y"], t["y"], atol=1e-3)
    np.testing.assert_allclose(t["spawn_yaw"], 0.0, atol=1e-3)
    ground = F.terrain_height(field.terrain, field.terrain_size, t["spawn_x"].to_numpy(),
                              t["spawn_y"].to_numpy())
    lift = t["spawn_z"] - ground
    assert (lift > 0.5 * robot.robot.wheel_radius).all() and (lift < 0.3).all(), lift


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
    # no plant in the lane ahead (the robot stands in it, further back; stones lie in it)
    ahead = set(what[-20:, 38:42].ravel())
    assert "terrain" in ahead and "plant" not in ahead, ahead
    assert (what[-20:, :15] == "plant").mean() > 0.3  # rows on both sides
    assert (what[-20:, -15:] == "plant").mean() > 0.3


def test_mjcf_robot_drives_from_the_lane_start(tiny, paths, model):
    field, _ = tiny
    m, d = model
    lanes = pd.read_csv(paths["lanes"])
    spawn = lanes[lanes["default"] == 1].iloc[0]
    assert m.nu == 4 and m.nkey == 4  # wheel actuators with a ctrlrange; keyframes
    assert (m.actuator_ctrlrange[:, 1] > 0).all() and m.actuator_ctrllimited.all()
    assert mujoco.mj_name2id(m, mujoco.mjtObj.mjOBJ_CAMERA, "front") >= 0
    chassis = mujoco.mj_name2id(m, mujoco.mjtObj.mjOBJ_BODY, "chassis")
    np.testing.assert_allclose(d.xpos[chassis][:2], spawn[["spawn_x", "spawn_y"]], atol=1e-3)
    ground = float(F.terrain_height(field.terrain, field.terrain_size, *d.xpos[chassis][:2]))
    for key, moved in (("start", (0.0, 0.02)), ("forward", (0.3, 5.0))):
        mujoco.mj_resetDataKeyframe(m, d, mujoco.mj_name2id(m, mujoco.mjtObj.mjOBJ_KEY, key))
        x0 = d.qpos[0]
        for _ in range(int(1.0 / m.opt.timestep)):
            mujoco.mj_step(m, d)
        # on the ground (the origin a wheel radius above it, give or take the tilt), upright
        z = d.xpos[chassis][2] - ground
        assert 0.03 < z < 0.2, (key, z)
        assert d.xmat[chassis][8] > 0.95
        assert moved[0] <= d.qpos[0] - x0 <= moved[1], (key, d.qpos[0] - x0)
        assert abs(d.qpos[1] - spawn["spawn_y"]) < 0.1


def _model_file(world: Path, uri: str) -> Path:
    """A model:// URI of an export resolved against its `models/` folder."""
    assert uri.startswith("model://"), uri
    p = world.parent / "models" / uri.removeprefix("model://")
    assert p.exists(), uri
    return p


def _models(paths, flavour):
    world = paths["sdf" if flavour == "sim" else "world"]
    root = ET.parse(world).getroot()
    inc = {i.findtext("name"): _model_file(world, i.findtext("uri")) for i in root.iter("include")}
    assert set(inc) == {"field", "robot"}
    return world, root, {k: ET.parse(v / "model.sdf").getroot() for k, v in inc.items()}


@pytest.mark.parametrize("flavour", ["sim", "classic"])
def test_sdf(tiny, paths, flavour):
    field, shape = tiny
    world, root, models = _models(paths, flavour)
    version = "1.9" if flavour == "sim" else "1.6"
    assert {r.get("version") for r in (root, *models.values())} == {version}
    assert root.find("world/physics/max_step_size") is not None
    fm = models["field"]
    visuals = [v.get("name") for v in fm.iter("visual")]
    plant_vis = [n for n in visuals if n.startswith("plant_") and "_end" not in n]
    assert len(plant_vis) == len(set(plant_vis)) == field.plant_active.sum() * K
    coll = [c.get("name") for c in fm.iter("collision") if c.get("name").startswith("plant_")]
    assert len(coll) == field.plant_active.sum()  # one footprint dome per plant
    assert sum(n.startswith(("stone_", "branch_")) and "_end" not in n
               for n in visuals) == field.obst_active.sum()
    for v in fm.iter("visual"):  # shaded sides: ambient as well as diffuse
        if v.get("name") != "terrain":
            assert v.find("material/ambient") is not None and v.find("material/diffuse") is not None
    for uri in fm.iter("uri"):
        _model_file(world, uri.text)
    if flavour == "classic":  # SDF 1.6 geometry only
        assert fm.find(".//ellipsoid") is None and fm.find(".//capsule") is None
        meshes = {m.findtext("uri") for m in fm.iter("mesh")}
        assert len(meshes) == 1 and meshes.pop().endswith("sphere.dae")
    # the heightmap: square 2^n+1, row 0 at +y, heights = pos.z + pixel/(2^bits − 1) · size.z
    hm = fm.find(".//collision/geometry/heightmap")
    img = Image.open(_model_file(world, hm.findtext("uri")))
    top = 255 if flavour == "classic" else 65535
    assert img.mode == ("L" if flavour == "classic" else "I;16")
    img = np.asarray(img, np.float64)
    n = img.shape[0]
    assert img.shape == (n, n) and (n - 1) & (n - 2) == 0
    size = np.array(hm.findtext("size").split(), float)
    z0 = float(hm.findtext("pos").split()[2])
    np.testing.assert_allclose(size[:2], field.terrain_size, atol=1e-3)
    j, i = np.meshgrid(np.arange(0, n, 7), np.arange(0, n, 5), indexing="ij")
    x = (i / (n - 1) - 0.5) * size[0]
    y = (0.5 - j / (n - 1)) * size[1]
    ref = F.terrain_height(field.terrain, field.terrain_size, x, y)
    np.testing.assert_allclose(z0 + img[j, i] / top * size[2], ref,
                               atol=1e-3 + size[2] / top)
    # the robot: four wheel joints, a camera with our image size and field of view, spawned at
    # the default lane's start
    rm = models["robot"]
    assert len(rm.findall("model/joint")) == 4
    cam = rm.find(".//sensor[@type='camera']/camera")
    robot = S.robot_for(field)
    assert (int(cam.findtext("image/width")), int(cam.findtext("image/height"))) == robot.image
    assert abs(float(cam.findtext("horizontal_fov")) - robot.hfov) < 1e-5
    lanes = pd.read_csv(paths["lanes"])
    spawn = lanes[lanes["default"] == 1].iloc[0]
    pose = np.array(root.find("world/include[name='robot']/pose").text.split(), float)
    np.testing.assert_allclose(pose[:2], spawn[["spawn_x", "spawn_y"]], atol=1e-3)


@pytest.mark.parametrize("flavour", ["sim", "classic"])
def test_sdf_robot_drive_is_mujocos(tiny, paths, flavour):
    """The Gazebo robot's wheels carry the MuJoCo robot's drive: axle inertia = a 0.5 kg,
    0.098 m solid sphere's 0.4·m·r² (1.92e-3 kg·m²) + the motor armature 0.05 kg·m² (half of
    it about the other two axes, as a disc's); effort
    limit 5 N·m; and Classic's ODE solver runs without over-relaxation, with the friction
    cone (docs/gazebo.md: with Gazebo's defaults the robot veered off its lane)."""
    field, _ = tiny
    world, root, models = _models(paths, flavour)
    cfg = S.robot_for(field).robot
    assert (cfg.wheel_mass, cfg.wheel_radius, cfg.armature, cfg.wheel_torque) == (
        0.5, 0.098, 0.05, 5.0)
    links = {ln.get("name"): ln for ln in models["robot"].iter("link")}
    for name in ("left_front", "right_front", "left_rear", "right_rear"):
        inertia = links[f"wheel_{name}"].find("inertial/inertia")
        moments = [float(inertia.findtext(k)) for k in ("ixx", "iyy", "izz")]
        np.testing.assert_allclose(moments, [1.9208e-3 + 0.025, 1.9208e-3 + 0.05,
                                             1.9208e-3 + 0.025], rtol=1e-5)
        joint = models["robot"].find(f"model/joint[@name='{name}']")
        assert joint.findtext("axis/xyz").split() == ["0", "1", "0"]
        assert float(joint.findtext("axis/limit/effort")) == 5.0
        assert float(joint.findtext("axis/dynamics/damping")) == 0.0
    if flavour == "classic":
        solver = root.find("world/physics/ode/solver")
        assert solver.findtext("type") == "quick"
        assert float(solver.findtext("sor")) == 1.0
        assert solver.findtext("friction_model") == "cone_model"


def _sdformat() -> str | None:
    """`ign` when it has the sdformat `sdf` command, else None (the test fails when
    MJXROW_REQUIRE_SDFORMAT is set, as .ci/run does; else it skips, saying why)."""
    ign = shutil.which("ign")
    if ign:
        out = subprocess.run([ign, "sdf", "--help"], capture_output=True, text=True)
        if out.returncode == 0 and "-k" in out.stdout + out.stderr:
            return ign
    if os.environ.get("MJXROW_REQUIRE_SDFORMAT"):
        pytest.fail("MJXROW_REQUIRE_SDFORMAT is set but `ign sdf` is not installed "
                    "(Debian: ignition-tools libsdformat-dev)")
    pytest.skip("`ign sdf` not installed (Debian: ignition-tools libsdformat-dev); "
                "set MJXROW_REQUIRE_SDFORMAT=1 to make this a failure")


# lines the tools print on a healthy install (a missing optional backtrace library)
SDFORMAT_NOISE = ("Library error: libignition-tools-backward.so not found",)


@pytest.mark.parametrize("export", ["paths", "curvy_paths"])
def test_sdformat_parses_every_file(request, export):
    ign = _sdformat()
    paths = request.getfixturevalue(export)
    out_dir = paths["xml"].parent
    files = [paths["sdf"], paths["world"], *sorted(out_dir.glob("models/*/model.sdf"))]
    assert len(files) == 6
    env = {**os.environ, "SDF_PATH": str(out_dir / "models")}
    for f in files:
        res = subprocess.run([ign, "sdf", "-k", str(f)], capture_output=True, text=True,
                             env=env, cwd="/")
        lines = [ln for ln in (res.stdout + res.stderr).splitlines()
                 if ln.strip() and not ln.startswith(SDFORMAT_NOISE)]
        # `ign sdf -k` can print an error and still exit 0: any other line fails
        assert res.returncode == 0 and lines == ["Valid."], (f.name, res.returncode, lines)


def test_sdformat_check_catches_errors(tmp_path):
    """The check above can fail: an unresolved include is reported."""
    ign = _sdformat()
    bad = tmp_path / "bad.sdf"
    bad.write_text('<?xml version="1.0"?><sdf version="1.6"><world name="w"><include><uri>'
                   "model://missing</uri></include></world></sdf>")
    res = subprocess.run([ign, "sdf", "-k", str(bad)], capture_output=True, text=True,
                         env={**os.environ, "SDF_PATH": str(tmp_path)})
    lines = [ln for ln in (res.stdout + res.stderr).splitlines()
             if ln.strip() and not ln.startswith(SDFORMAT_NOISE)]
    assert res.returncode != 0 or lines != ["Valid."]


# ---------------------------------------------------------------------------------------------
# A curved field (arcs and a sinusoid) with gap runs and weeds: 2 rows of 6 m on 8 × 6 m


@pytest.fixture(scope="module")
def curvy():
    params = F.make_params("zucchini", host=True, terrain_length=8.0, row_length=6.0,
                           terrain_width=6.0, rows_per_group=2, stone_density=8.0,
                           branch_density=4.0, row_curvature=0.06, row_amplitude=0.15,
                           row_wavelength=4.0, gap_rate=2.0, gap_length=1.0, weed_density=1.0)
    shape = F.fit_shape(params, "zucchini")
    F.validate(params, shape)
    gen = jax.jit(F.generate, static_argnums=1)
    field = jax.tree.map(np.asarray, gen(jax.tree.map(jax.numpy.asarray, params), shape,
                                         jax.random.key(1)))
    assert int(field.n_rows) == 2 and field.weed_active.sum() >= 5
    assert np.ptp(field.plant_heading[field.plant_active]) > 0.2
    return field, shape


@pytest.fixture(scope="module")
def curvy_paths(curvy, tmp_path_factory):
    return Wd.export(*curvy, tmp_path_factory.mktemp("curvy"), "curvy", gazebo="both")


@pytest.fixture(scope="module")
def curvy_model(curvy_paths):
    m = mujoco.MjModel.from_xml_path(str(curvy_paths["xml"]))
    d = mujoco.MjData(m)
    mujoco.mj_forward(m, d)
    return m, d


def _weed_geoms(m) -> dict[tuple[int, int], int]:
    out = {}
    for g in range(m.ngeom):
        name = mujoco.mj_id2name(m, mujoco.mjtObj.mjOBJ_GEOM, g) or ""
        if name.startswith("weed_"):
            i, k = name.removeprefix("weed_").split("_k")
            out[(int(i), int(k))] = g
    return out


def test_curved_mjcf_has_the_prims_of_plants_and_weeds(curvy, curvy_paths, curvy_model):
    field, shape = curvy
    m, d = curvy_model
    plants = _plant_geoms(m)
    assert len(plants) == field.plant_active.sum() * K
    prims = jax.tree.map(np.asarray, PL.plant_prims(field, shape))
    r, p, k = np.array(list(plants)).T
    ids = np.array(list(plants.values()))
    np.testing.assert_allclose(d.geom_xpos[ids], prims.centre[r, p, k], atol=1e-3)
    np.testing.assert_allclose(d.geom_xmat[ids].reshape(-1, 3, 3), prims.rot[r, p, k], atol=2e-3)
    # weeds: every primitive of weed_prims, visual only, in the plants' group, palette colours
    weeds = _weed_geoms(m)
    n_weed = PL.weed_prims(field).centre.shape[1]
    active = np.flatnonzero(field.weed_active)
    assert sorted(weeds) == [(i, j) for i in active for j in range(n_weed)]
    wp = jax.tree.map(np.asarray, PL.weed_prims(field))
    i, k = np.array(list(weeds)).T
    ids = np.array(list(weeds.values()))
    assert (m.geom_contype[ids] == 0).all() and (m.geom_conaffinity[ids] == 0).all()
    assert (m.geom_group[ids] == 1).all()
    assert (m.geom_type[ids] == mujoco.mjtGeom.mjGEOM_ELLIPSOID).all()
    np.testing.assert_allclose(d.geom_xpos[ids], wp.centre[i, k], atol=1e-3)
    np.testing.assert_allclose(d.geom_xmat[ids].reshape(-1, 3, 3), wp.rot[i, k], atol=2e-3)
    np.testing.assert_allclose(m.geom_size[ids], wp.size[i, k], atol=1e-3)
    palette = np.array(PL.WEED_PALETTE)[worlds_mjcf.weed_rgb(field.weed_phase[i])]
    np.testing.assert_allclose(m.geom_rgba[ids, :3], palette, atol=6e-3)
    assert len(np.unique(m.geom_rgba[ids, :3], axis=0)) > 1
    # the weeds CSV: the same weeds
    t = pd.read_csv(curvy_paths["weeds"])
    np.testing.assert_array_equal(t["weed"], active)
    np.testing.assert_allclose(t[["x", "y", "z"]], field.weed_pos[active], atol=1e-4)
    np.testing.assert_allclose(t[["diameter", "height"]], field.weed_size[active], atol=1e-4)
    np.testing.assert_allclose(t["yaw"], field.weed_yaw[active], atol=1e-4)


def test_curved_start_and_camera_on_the_lane_centre_line(curvy, curvy_paths, curvy_model):
    """The robot's start (lanes CSV, MJCF, both SDF worlds) lies on its lane's centre line
    path_length before the row end, heading along the line; the `eye` camera stands on the
    default lane's centre line and looks along it."""
    field, _ = curvy
    m, d = curvy_model
    lanes = pd.read_csv(curvy_paths["lanes"])
    poly = pd.read_csv(curvy_paths["lanes_polyline"])
    robot = S.robot_for(field)
    for i, field_lane in enumerate(S.field_lanes(field)):
        ln = F.lanes.lane(field, int(field_lane))
        s = ln.s_end - robot.sim.path_length
        row = lanes[lanes["lane"] == i].iloc[0]
        np.testing.assert_allclose(row[["spawn_x", "spawn_y"]], F.lanes.point(ln, s), atol=1e-3)
        np.testing.assert_allclose(row["spawn_yaw"], F.lanes.heading(ln.bend, s, ln.u),
                                   atol=1e-3)
        # the goal: the centre line's end, the polyline's last point
        np.testing.assert_allclose(row[["x_end", "y_end"]], F.lanes.goal(ln), atol=2e-4)
        pts = poly[poly["lane"] == i]
        np.testing.assert_allclose(pts[["x", "y"]].iloc[-1], F.lanes.goal(ln), atol=2e-4)
        np.testing.assert_allclose(pts[["x", "y"]], F.lanes.point(ln, pts["s"].to_numpy()),
                                   atol=2e-4)
    assert np.ptp(lanes["spawn_yaw"]) < 0.2 and np.abs(lanes["spawn_yaw"]).max() > 0.05
    spawn = lanes[lanes["default"] == 1].iloc[0]
    chassis = mujoco.mj_name2id(m, mujoco.mjtObj.mjOBJ_BODY, "chassis")
    np.testing.assert_allclose(d.xpos[chassis][:2], spawn[["spawn_x", "spawn_y"]], atol=1e-3)
    forward = d.xmat[chassis].reshape(3, 3)[:, 0]
    assert abs(np.arctan2(forward[1], forward[0]) - spawn["spawn_yaw"]) < 1e-3
    for flavour in ("sim", "classic"):
        _, root, _ = _models(curvy_paths, flavour)
        pose = np.array(root.find("world/include[name='robot']/pose").text.split(), float)
        np.testing.assert_allclose(pose[[0, 1, 5]], spawn[["spawn_x", "spawn_y", "spawn_yaw"]],
                                   atol=1e-3)
    ln = F.lanes.lane(field, int(F.robot_lane(field)))
    s0 = field.row_x[0] - 1.0
    cam = mujoco.mj_name2id(m, mujoco.mjtObj.mjOBJ_CAMERA, "eye")
    np.testing.assert_allclose(d.cam_xpos[cam][:2], F.lanes.point(ln, s0), atol=1e-3)
    look = -d.cam_xmat[cam].reshape(3, 3)[:, 2]
    assert abs(np.arctan2(look[1], look[0]) - F.lanes.heading(ln.bend, s0, ln.u)) < 1e-3


@pytest.mark.parametrize("flavour", ["sim", "classic"])
def test_curved_sdf_weeds_and_footprints(curvy, curvy_paths, flavour):
    """Weeds are visuals only (the MJCF's names, positions and sizes); each plant's footprint
    collision is turned along its row."""
    field, shape = curvy
    _, _, models = _models(curvy_paths, flavour)
    fm = models["field"]
    link = fm.find("model/link[@name='weeds']")
    assert link is not None and link.find("collision") is None
    assert not [c for c in fm.iter("collision") if c.get("name").startswith("weed_")]
    wp = jax.tree.map(np.asarray, PL.weed_prims(field))
    vis = {v.get("name"): v for v in link.iter("visual")}
    active = np.flatnonzero(field.weed_active)
    assert sorted(vis) == sorted(f"weed_{i}_k{k}" for i in active
                                 for k in range(wp.centre.shape[1]))
    for name, v in vis.items():
        i, k = (int(x) for x in name.removeprefix("weed_").split("_k"))
        pose = np.array(v.findtext("pose").split(), float)
        np.testing.assert_allclose(pose[:3], wp.centre[i, k], atol=1e-3)
        radii = v.findtext("geometry/ellipsoid/radii") or v.findtext("geometry/mesh/scale")
        np.testing.assert_allclose(np.array(radii.split(), float), wp.size[i, k], atol=1e-3)
    order, new_row = S.active_rows(field)
    for c in fm.iter("collision"):
        name = c.get("name")
        if name.startswith("plant_"):
            r, p = (int(x[1:]) for x in name.split("_")[1:])
            pose = np.array(c.findtext("pose").split(), float)
            fr = order[r]
            np.testing.assert_allclose(pose[:3], field.plant_pos[fr, p], atol=1e-3)
            assert abs(pose[5] - field.plant_heading[fr, p]) < 1e-3


def test_cli_exports_a_curved_weedy_field(tmp_path):
    """`--set` of the new field keys reaches every export: weeds in the CSV and the MJCF, the
    lanes' polylines along the arcs."""
    sets = ["terrain_length=8", "row_length=6", "terrain_width=6", "rows_per_group=2",
            "row_curvature=0.05", "gap_rate=1", "weed_density=1", "sim.path_length=3"]
    args = [a for s in sets for a in ("--set", s if s.startswith("sim.") else f"field.{s}")]
    assert worlds_cli.main(["--preset", "zucchini", "--gazebo", "none", "--out", str(tmp_path),
                            *args]) == 0
    weeds = pd.read_csv(tmp_path / "zucchini_weeds.csv")
    assert len(weeds) >= 5
    m = mujoco.MjModel.from_xml_path(str(tmp_path / "zucchini.xml"))
    assert len(_weed_geoms(m)) == 5 * len(weeds)
    poly = pd.read_csv(tmp_path / "zucchini_lanes_polyline.csv")
    heading = poly.groupby("lane")["heading"].agg(np.ptp)
    np.testing.assert_allclose(heading, 0.05 * np.ptp(poly["s"]), rtol=1e-3)


def test_cli_bad_input_names_the_key(tmp_path, capsys):
    for args, key in ((["--set", "field.d_rr=-1"], "field.d_rr"),
                      (["--set", "field.bogus=1"], "field.bogus"),
                      (["--set", "d_pp"], "d_pp"),
                      (["--set", "field.terrain_dh=abc"], "field.terrain_dh"),
                      (["--set", "field.p_missing=1.5"], "field.p_missing"),
                      (["--set", "robot.wheel_radius=-1"], "robot.wheel_radius"),
                      (["--from-run", str(tmp_path / "none"), "--cell", "0", "--episode", "0"],
                       "--from-run")):
        assert worlds_cli.main(["--preset", "lettuce", "--out", str(tmp_path), *args]) == 2
        err = capsys.readouterr().err
        assert key in err and len(err.strip().splitlines()) == 1, err
    assert not any(tmp_path.iterdir())
    proc = subprocess.run([sys.executable, "-m", "mjxrow.worlds", "--preset", "chard", "--set",
                           "field.d_RR=0.2", "--out", str(tmp_path)], capture_output=True,
                          text=True)
    assert proc.returncode == 2 and "field.d_RR" in proc.stderr and "wider" in proc.stderr


def test_overrides_grow_the_shape():
    # 30 m wide chard: 10 groups of 3 rows, more than the preset shape's max_rows
    run, shape = replay.resolve_run("chard", 0, ["field.terrain_width=30.0",
                                                 "field.terrain_length=8.0",
                                                 "field.row_length=6.0", "sim.path_length=5"])
    params = run.field_params()
    assert F.preset_shape("chard").max_rows < 30 <= shape.max_rows
    assert bool(np.all([np.all(ok) for ok, _ in F.checks(params, shape).values()]))
    assert not bool(F.checks(params, F.preset_shape("chard"))["max_rows"][0])


# ---------------------------------------------------------------------------------------------
# The field of a sweep episode

SWEEP = {"name": "replay", "seeds": 2, "batch_size": 2, "controller": {"name": "oracle"},
         "perception": {"source": "ground_truth"},
         "field": {"row_length": 6.0, "terrain_length": 10.0, "terrain_width": 10.0,
                   "rows_per_group": 2, "terrain_dh": 0.1},
         "sim": {"path_length": 1.5}, "episode": {"start_offset_std": 0.1},
         "camera": {"width": 16, "height": 16}}


def test_from_run_exports_the_episode_the_sweep_ran(tmp_path):
    """A 2-episode sweep whose evaluator builds its batch as the real one does (rollout.build)
    and records the fields; `--from-run` then regenerates episode 1's field exactly."""
    from mjxrow.rollout import build as B
    from mjxrow.sweep import config as C
    from mjxrow.sweep import run as SW

    seen = {}

    def evaluate(group, cfg, on_batch_done):
        by_cell = {c.index: c.cfg for c in group.cells}
        built = B.build(list(by_cell.values()), group.shape)
        batch = built.batch([(by_cell[c], e) for c, e in group.episodes])
        fields = jax.tree.map(np.asarray, batch.fields)
        rows = []
        for i, (c, e) in enumerate(group.episodes):
            seen[(c, e)] = jax.tree.map(lambda x, i=i: x[i], fields)
            rows.append({"cell": c, "episode": e, "lane": int(batch.lanes[i]), "success": True})
        rows = pd.DataFrame(rows)
        on_batch_done(rows)
        return rows

    run_dir = tmp_path / "run"
    SW.run(C.from_dict(SWEEP), run_dir, evaluate=evaluate, progress=False, figures=False)
    out = tmp_path / "world"
    assert worlds_cli.main(["--from-run", str(run_dir), "--cell", "0", "--episode", "1",
                        "--gazebo", "none", "--out", str(out)]) == 0
    ref = seen[(0, 1)]
    assert not np.array_equal(ref.plant_pos, seen[(0, 0)].plant_pos)
    t = pd.read_csv(out / "zucchini_c0_e1_plants.csv")
    r, p = np.nonzero(ref.plant_active)
    want = np.sort(ref.plant_pos[r, p], axis=0)
    np.testing.assert_allclose(np.sort(t[["x", "y", "z"]].to_numpy(), axis=0), want, atol=6e-5)
    ep = replay.from_run(run_dir, 0, 1)
    # the same field: the same plants and obstacles, their places to float rounding (XLA
    # compiles a batch of fields and a single field into different programs, which may round
    # a multiply-add differently: 1 ulp)
    np.testing.assert_array_equal(ep.field.plant_active, ref.plant_active)
    for name in ("plant_pos", "plant_size", "terrain", "obst_pos"):
        np.testing.assert_allclose(getattr(ep.field, name), getattr(ref, name), rtol=0,
                                   atol=2e-6, err_msg=name)
    # the start: the lane results.csv names, path_length before the row end, off the centre
    # line by the start noise (std 0.1 m)
    res = pd.read_csv(run_dir / "results.csv")
    lane = int(res[(res["cell"] == 0) & (res["episode"] == 1)]["lane"].iloc[0])
    lanes = pd.read_csv(out / "zucchini_c0_e1_lanes.csv")
    spawn = lanes[lanes["lane"] == ep.start.lane].iloc[0]
    assert int(S.field_lanes(ep.field)[ep.start.lane]) == lane
    np.testing.assert_allclose(spawn["spawn_x"], spawn["x_end"] - 1.5, atol=1e-3)
    assert 1e-4 < abs(spawn["spawn_y"] - spawn["y"]) < 0.4


def test_cli_needs_what_to_export(tmp_path, capsys):
    for args in ([], ["--preset", "chard", "--all"]):
        with pytest.raises(SystemExit) as exit_info:
            worlds_cli.main(["--out", str(tmp_path / "w"), *args])
        assert exit_info.value.code == 2
        assert "--preset" in capsys.readouterr().err
    assert not (tmp_path / "w").exists()
