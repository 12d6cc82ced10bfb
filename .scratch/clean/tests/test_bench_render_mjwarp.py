"""`python -m mjxrow.bench render_mjwarp`: the one-line error without Warp (before any work), its
arguments, the camera poses along the lanes (checked through MuJoCo's own kinematics), the
geom-id → class table and the agreement figures; the render itself, against ours, only where
Warp has a CUDA device."""

import argparse
import importlib

import jax
import mujoco
import numpy as np
import pytest

from mjxrow import field as F
from mjxrow import render as RD
from mjxrow.bench import render_mjwarp as RM
from mjxrow.bench.__main__ import main as bench_main
from mjxrow.worlds import mjcf

CAM_HEIGHT, PITCH = 0.4, -10.0


@pytest.fixture(scope="module")
def tiny():
    """A 12 × 12 m zucchini field: 2 groups of 2 rows (3 lanes), 8 m rows, stones and branches."""
    params = F.make_params("zucchini", terrain_length=12.0, row_length=8.0, terrain_width=12.0,
                           rows_per_group=2, stone_density=8.0, branch_density=4.0)
    shape = F.fit_shape(params, "zucchini")
    field = jax.tree.map(np.asarray, jax.jit(F.generate, static_argnums=1)(
        params, shape, jax.random.key(3)))
    xml, assets = mjcf.to_mjcf(field, shape, "tiny")
    return field, shape, xml, assets


def _no_warp(monkeypatch, missing):
    real = importlib.import_module
    monkeypatch.setattr(importlib, "import_module",
                        lambda name, *a: (_ for _ in ()).throw(ImportError(name))
                        if name == missing else real(name, *a))
    monkeypatch.setattr(RM, "exported", lambda *a: pytest.fail("work began before the check"))


@pytest.mark.parametrize("missing", RM.NEEDS)
def test_missing_packages_say_so_in_one_line_first(monkeypatch, missing):
    _no_warp(monkeypatch, missing)
    with pytest.raises(SystemExit) as exit_info:
        bench_main(["render_mjwarp", "--batch", "2", "--no-record", "--no-cache"])
    assert exit_info.value.code == RM.MISSING
    assert "pip install warp-lang" in exit_info.value.code


def test_arguments():
    p = argparse.ArgumentParser()
    RM.add_args(p)
    a = p.parse_args([])
    assert (a.preset, a.batch, a.res, a.shadows, a.repeats) == ("zucchini", 1024, [64, 128],
                                                                ["on", "off"], 5)
    a = p.parse_args(["--preset", "pear", "--batch", "2", "--res", "16", "32", "--shadows", "off",
                      "--repeats", "1"])
    assert (a.preset, a.batch, a.res, a.shadows, a.repeats) == ("pear", 2, [16, 32], ["off"], 1)
    with pytest.raises(SystemExit):
        p.parse_args(["--shadows", "maybe"])


def test_lane_poses(tiny):
    field, *_ = tiny
    lanes = field.lane_y[[0, 1, 2]]  # the 3 lanes between the 4 rows, by y
    pos, rot = RM.lane_poses(field, CAM_HEIGHT, PITCH, 12)
    assert pos.shape == (12, 3) and rot.shape == (12, 3, 3)
    np.testing.assert_allclose(pos[:, 1], np.tile(lanes, 4), atol=1e-6)
    assert np.all((pos[:, 0] >= field.row_x[0]) & (pos[:, 0] <= field.row_x[1]))
    assert len(np.unique(pos[:, 0].round(3))) == 12
    ground = F.terrain_height(field.terrain, field.terrain_size, pos[:, 0], pos[:, 1])
    np.testing.assert_allclose(pos[:, 2] - ground, CAM_HEIGHT, atol=1e-5)
    forward = -rot[:, :, 2]  # the camera looks along its −z
    np.testing.assert_allclose(np.sign(forward[:, 0]), [1, 1, 1, -1, -1, -1] * 2)
    np.testing.assert_allclose(np.degrees(np.arcsin(forward[:, 2])), PITCH, atol=1e-4)
    np.testing.assert_allclose(rot.transpose(0, 2, 1) @ rot, np.broadcast_to(np.eye(3), rot.shape),
                               atol=1e-6)


@pytest.mark.parametrize("shadows", [True, False])
def test_camera_rig_follows_the_poses_in_mujoco(tiny, shadows):
    """MuJoCo's own kinematics put the rig's camera exactly at the poses our renderer gets."""
    field, _, xml, assets = tiny
    m = RM.camera_model(xml, assets, 42.0, shadows)
    cam = mujoco.mj_name2id(m, mujoco.mjtObj.mjOBJ_CAMERA, RM.CAMERA)
    assert cam >= 0 and m.cam_fovy[cam] == 42.0 and m.nmocap == 1
    assert m.nlight >= 1 and np.all(m.light_castshadow == shadows)
    pos, rot = RM.lane_poses(field, CAM_HEIGHT, PITCH, 4)
    d = mujoco.MjData(m)
    for p, q, r in zip(pos, RM.rot_quat(rot), rot, strict=True):
        d.mocap_pos[0], d.mocap_quat[0] = p, q
        mujoco.mj_forward(m, d)
        np.testing.assert_allclose(d.cam_xpos[cam], p, atol=1e-5)
        np.testing.assert_allclose(d.cam_xmat[cam].reshape(3, 3), r, atol=1e-5)


def test_geom_classes(tiny):
    *_, xml, assets = tiny
    m = RM.camera_model(xml, assets, 42.0, False)
    table = RM.geom_classes(m)
    names = [mujoco.mj_id2name(m, mujoco.mjtObj.mjOBJ_GEOM, g) for g in range(m.ngeom)]
    assert table.shape == (m.ngeom + 1,) and table[0] == RD.SKY
    assert table[1 + names.index("terrain")] == RD.SOIL
    assert np.sum(table == RD.PLANT) == sum(n.startswith("plant_") for n in names) > 0
    assert np.sum(table == RD.OBSTACLE) == sum(n.startswith(("stone_", "branch_"))
                                               for n in names) > 0


def test_agreement_figures():
    sky, soil, plant = RD.SKY, RD.SOIL, RD.PLANT
    ours = np.array([[[plant, plant], [soil, soil]], [[sky, sky], [soil, soil]]], np.uint8)
    theirs = np.array([[[plant, soil], [soil, soil]], [[sky, soil], [soil, soil]]], np.uint8)
    a = RM.agreement(ours, theirs)
    assert a["plant_iou"] == 0.5  # pose 0: 1 of 2; pose 1 has no plant and is left out
    assert a["class_agree"] == 6 / 8
    assert (a["non_sky_ours"], a["non_sky_mjwarp"]) == (6 / 8, 7 / 8)


def _warp_gpu() -> bool:
    try:
        for name in RM.NEEDS:
            importlib.import_module(name)
        import warp
    except (ImportError, RuntimeError):
        return False
    return bool(warp.is_cuda_available())


@pytest.mark.skipif(not _warp_gpu(), reason="needs warp-lang and a CUDA device for Warp")
def test_mujoco_warp_sees_what_we_see(tiny):
    """2 worlds at 16 × 16 through MJX's warp renderer: the plant masks match ours."""
    from mjxrow.bench import render as BR

    field, shape, xml, assets = tiny
    RM.check_packages()
    b, res = 2, 16
    pos, rot = RM.lane_poses(field, CAM_HEIGHT, PITCH, b)
    m = RM.camera_model(xml, assets, 42.0, False)
    mx, d = RM.warp_worlds(m, pos, rot)
    rc, fn = RM.warp_render(m, b, res, False)
    rgb, depth, seg = fn(mx, d)
    assert rgb.shape[0] == depth.shape[0] == seg.shape[0] == b
    theirs = RM.warp_classes(rc, seg, RM.geom_classes(m))
    cond = jax.tree.map(lambda x: np.broadcast_to(x, (b, *x.shape)), RD.conditions("sunny"))
    ours_fn = BR.batched_render(shape, RD.Intrinsics(res, res, 42.0),
                                RD.RenderConfig(shadows=False), b, b, shared_field=True)
    ours = np.asarray(ours_fn(field, pos, rot, cond).classes)
    a = RM.agreement(ours, theirs)
    assert a["plant_iou"] > 0.9 and a["class_agree"] > 0.95, a
