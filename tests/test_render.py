"""The ray caster against MuJoCo's own renderer and against brute force: plant masks, depth,
sky, shadows, determinism, on straight fields and on curved, weedy ones (weeds their own class,
never crop). Tiny fields and images; one compile per function, preset and shape."""

import dataclasses
import functools
import json
import os
import subprocess
import sys
import textwrap

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from mjxrow import crops
from mjxrow import field as F
from mjxrow import render as RD
from mjxrow.crops import prims as PL
from mjxrow.field import lanes as LN
from mjxrow.render import geom as G
from mjxrow.render import shade as S
from mjxrow.render import terrain as T
from mjxrow.render import weeds as RW
from mjxrow.worlds import export as WD

H, W = 48, 64
INTR = RD.Intrinsics(W, H, 45.0)
SMALL = dict(terrain_length=14.0, row_length=10.0, terrain_width=14.0)
SIZES = {"pear": dict(terrain_length=20.0, row_length=16.0, terrain_width=22.0),
         "vineyard": dict(terrain_length=16.0, row_length=12.0, terrain_width=14.0)}


generate = jax.jit(F.generate, static_argnums=1)


@functools.cache
def geometry_fn(shape):
    """Depth and classes of one field seen from a batch of cameras (one compile per shape)."""
    return jax.jit(jax.vmap(lambda f, p, r: RD.geometry(f, shape, p, r, INTR),
                            in_axes=(None, 0, 0)))


# one static shape holds every tiny field (generation does not depend on the crop), so the
# generator compiles once; rendering takes the shape with the crop's name
COMMON = F.FieldShape(crop="zucchini", max_rows=16, max_plants_per_row=40,
                      terrain_cells=(96, 88), obstacle_slots=8)
# weeds need slots: one shape for the curved, weedy fields
CURVED = dataclasses.replace(COMMON, weed_slots=256)
ROWS = {"arc": dict(row_curvature=0.03), "sine": dict(row_amplitude=0.5, row_wavelength=10.0)}
WEEDY = dict(weed_density=0.6, weed_size=0.16, gap_rate=1.0)


def tiny_field(crop, seed=1, shape=COMMON, **kw):
    params = F.make_params(crop, **{**SIZES.get(crop, SMALL), **kw})
    F.validate(params, shape)
    fld = jax.tree.map(np.asarray, generate(params, shape, jax.random.key(seed)))
    assert bool(fld.valid)
    return fld, dataclasses.replace(shape, crop=crop)


def curved_field(crop, rows, seed=1, **kw):
    """A tiny field of curved rows (`ROWS[rows]`) with weeds and gap runs."""
    fld, shape = tiny_field(crop, seed, CURVED, **ROWS[rows], **{**WEEDY, **kw})
    assert fld.weed_active.sum() > 20
    assert np.ptp(fld.plant_heading[fld.plant_active]) > 0.1  # the rows do turn
    return fld, shape


def lane_poses(fld, headland=False):
    """Four cameras on the robot's lane, placed in field coordinates (s along the rows, u
    across) and turned by the lane's heading (`mjxrow.field.lanes`; x = s, y = u on straight
    rows): at the lane start, mid-lane looking back, high and steep, past the end. With
    `headland`: two more beyond the row ends, looking back into the rows at an angle."""
    lane = int(F.robot_lane(fld))
    u = float(fld.lane_y[lane])
    x0, x1 = (float(v) for v in fld.row_x)
    bend = LN.field_bend(fld)
    out = []
    views = [(x0 - 1.0, 0.0, 0.45, 0.0, -10.0), (0.0, 0.15, 0.4, np.pi, -8.0),
             (x0 + 2.0, -0.2, 1.2, 0.25, -25.0), (x1 + 0.5, 0.0, 0.7, np.pi - 0.2, -15.0)]
    if headland:
        views += [(x1 + 1.2, 0.0, 0.45, np.pi - 0.7, -10.0), (x0 - 1.2, 0.0, 0.45, 0.9, -12.0)]
    for s, du, h, turn, pitch in views:
        s_, u_ = jnp.float32(s), jnp.float32(u + du)
        x, y = (float(v) for v in LN.to_world(bend, s_, u_))
        yaw = float(LN.heading(bend, s_, u_)) + turn
        assert abs(x) < 0.5 * fld.terrain_size[0] - 0.2  # over the terrain: no side walls
        z = float(F.terrain_height(fld.terrain, fld.terrain_size, x, y)) + h
        out.append((np.array([x, y, z], np.float32),
                    np.asarray(RD.camera_rot(yaw, np.deg2rad(pitch)))))
    pos, rot = zip(*out, strict=True)
    return np.stack(pos), np.stack(rot)


# ---------------------------------------------------------------------------------------------
# MuJoCo reference (rendered in a subprocess: MuJoCo picks its GL backend at import time, and
# another test module may have imported it before MUJOCO_GL could be set)

_MJ_SCRIPT = textwrap.dedent("""
    import json, os, sys
    os.environ["MUJOCO_GL"] = "osmesa"
    import mujoco, numpy as np
    job = json.load(open(sys.argv[1]))
    out = {}
    for crop, item in job.items():
        assets = {k: bytes.fromhex(v) for k, v in item["assets"].items()}
        m = mujoco.MjModel.from_xml_string(item["xml"], assets)
        d = mujoco.MjData(m)
        cam = mujoco.mj_name2id(m, mujoco.mjtObj.mjOBJ_CAMERA, "eye")
        names = [mujoco.mj_id2name(m, mujoco.mjtObj.mjOBJ_GEOM, i) or "" for i in range(m.ngeom)]
        plant = np.array([n.startswith("plant_") for n in names] + [False])
        weed = np.array([n.startswith("weed_") for n in names] + [False])
        obst = np.array([n.startswith(("stone_", "branch_")) for n in names] + [False])
        r = mujoco.Renderer(m, item["h"], item["w"])
        for j, (pos, rot) in enumerate(zip(item["pos"], item["rot"])):
            q = np.zeros(4)
            mujoco.mju_mat2Quat(q, np.asarray(rot, np.float64).ravel())
            m.cam_pos[cam], m.cam_quat[cam], m.cam_fovy[cam] = pos, q, item["fovy"]
            mujoco.mj_forward(m, d)
            r.enable_segmentation_rendering()
            r.update_scene(d, camera=cam)
            seg = r.render()
            r.disable_segmentation_rendering()
            r.enable_depth_rendering()
            r.update_scene(d, camera=cam)
            depth = r.render()
            r.disable_depth_rendering()
            gid = np.where(seg[..., 1] == int(mujoco.mjtObj.mjOBJ_GEOM), seg[..., 0], -1)
            out[f"{crop}_{j}_plant"] = plant[gid]
            out[f"{crop}_{j}_weed"] = weed[gid]
            out[f"{crop}_{j}_obst"] = obst[gid]
            out[f"{crop}_{j}_sky"] = seg[..., 0] < 0
            out[f"{crop}_{j}_depth"] = depth
        r.close()
    np.savez(sys.argv[2], **out)
""")


# every preset on straight rows; one curved field with weeds and gap runs (their weeds drawn
# by MuJoCo as `weed_*` geoms), from the lane and the headland
MJ_CASES = [(crop, "straight") for crop in crops.names()] + [("zucchini", "sine")]


@pytest.fixture(scope="module")
def mujoco_scenes(tmp_path_factory):
    """Per case of MJ_CASES: tiny field, shape, camera poses (curved rows: also two in the
    headland), and MuJoCo's plant/weed/obstacle/sky masks and depth for every pose."""
    tmp = tmp_path_factory.mktemp("mj")
    scenes, job = {}, {}
    for crop, rows in MJ_CASES:
        fld, shape = tiny_field(crop) if rows == "straight" else curved_field(crop, rows)
        pos, rot = lane_poses(fld, headland=rows != "straight")
        xml, assets = WD.to_mjcf(fld, shape, crop)
        scenes[crop, rows] = (fld, shape, pos, rot)
        job[f"{crop}_{rows}"] = dict(xml=xml, assets={k: v.hex() for k, v in assets.items()},
                                     pos=pos.tolist(), rot=rot.tolist(), h=H, w=W,
                                     fovy=INTR.fovy)
    (tmp / "job.json").write_text(json.dumps(job))
    env = {**os.environ, "MUJOCO_GL": "osmesa"}
    res = subprocess.run([sys.executable, "-c", _MJ_SCRIPT, str(tmp / "job.json"),
                          str(tmp / "out.npz")], capture_output=True, text=True, env=env,
                         timeout=300)
    assert res.returncode == 0, ("MuJoCo's offscreen renderer (MUJOCO_GL=osmesa) failed; it "
                                 "needs the system package libosmesa6 (apt-get install "
                                 "libosmesa6):\n" + res.stderr[-2000:])
    ref = dict(np.load(tmp / "out.npz"))
    return scenes, ref


@pytest.mark.parametrize("crop,rows", MJ_CASES, ids=[f"{c}-{r}" for c, r in MJ_CASES])
def test_agrees_with_mujoco(mujoco_scenes, crop, rows):
    scenes, ref = mujoco_scenes
    fld, shape, pos, rot = scenes[crop, rows]
    depth, cls = (np.asarray(x) for x in geometry_fn(shape)(fld, pos, rot))
    weed_inter, weed_union = 0, 0
    for j in range(len(pos)):
        key = f"{crop}_{rows}_{j}"
        mj_plant, mj_sky, mj_weed = ref[f"{key}_plant"], ref[f"{key}_sky"], ref[f"{key}_weed"]
        mask = cls[j] == RD.PLANT
        assert mj_plant.sum() > 40, "the pose should see plants"
        iou = (mask & mj_plant).sum() / (mask | mj_plant).sum()
        assert iou >= 0.9, f"{crop} {rows} pose {j}: plant-mask IoU {iou:.3f}"
        # weeds are never crop: what MuJoCo draws of a weed is not in our crop mask (a pixel
        # on a weed's edge in front of a plant aside)
        in_crop = (mask & mj_weed).sum()
        assert in_crop <= 2 + 0.05 * mj_weed.sum(), f"{crop} {rows} pose {j}: weeds as crop"
        weed = cls[j] == RD.WEED
        weed_inter += (weed & mj_weed).sum()
        weed_union += (weed | mj_weed).sum()
        # depth over terrain and plant pixels (both renderers agree it is one of them)
        ours = (cls[j] == RD.SOIL) | mask
        theirs = ~mj_sky & ~ref[f"{key}_obst"] & ~mj_weed
        both = ours & theirs
        assert both.mean() > 0.4
        err = np.median(np.abs(depth[j] - ref[f"{key}_depth"])[both])
        assert err <= 0.05, f"{crop} {rows} pose {j}: median |depth error| {err:.3f} m"
        # sky where MuJoCo draws none of the world, within a few edge pixels
        assert np.sum((cls[j] == RD.SKY) != mj_sky) <= 0.01 * H * W
    if rows != "straight":  # the weeds' pixels, pooled over the poses (a weed is small)
        assert weed_union > 30, "the poses should see weeds"
        iou = weed_inter / weed_union
        assert iou >= 0.75, f"{crop} {rows}: weed IoU {iou:.3f}"


# ---------------------------------------------------------------------------------------------
# One zucchini scene for the rest: flat terrain and no obstacles where shadows are compared


@pytest.fixture(scope="module")
def scene():
    fld, shape = tiny_field("zucchini", seed=3, p_missing=0.0, terrain_dh=0.0,
                            stone_density=0.0, branch_density=0.0)
    render = jax.jit(lambda f, p, r, c: RD.render(f, shape, p, r, INTR, c))
    return fld, shape, render


@functools.partial(jax.jit, static_argnums=1)
def brute_force(fld, shape, pos, rot, sun):
    """Every plant, weed, obstacle and a dense terrain march: (t [N], class [N]) of each pixel
    of the camera, and whether each pixel's surface point sees the sun `sun` [3] past every
    plant and weed."""
    dc = RD.pixel_rays(INTR)
    d = jnp.asarray(dc / np.linalg.norm(dc, axis=-1, keepdims=True) @ rot.T)
    o = jnp.broadcast_to(jnp.asarray(pos), d.shape)
    n = d.shape[0]
    tab = G.plant_table(fld, shape)
    sun = jnp.asarray(sun)
    RP = tab.box_t.shape[1]
    flat = jnp.broadcast_to(jnp.arange(RP), (n, RP))
    ok = tab.box_t[0][flat] <= tab.box_t[1][flat]  # active plants
    tmin, far = jnp.full((n,), 0.01), jnp.full((n,), 150.0)

    def plants(o, d, tmax, tab=tab, flat=flat, ok=ok):
        xyz = lambda v: tuple(v[:, i:i + 1] for i in range(3))  # noqa: E731
        t, _ = G.nearest_prim(tab, flat, xyz(o), xyz(d), tmin[:, None] * 0, tmax[:, None])
        return jnp.min(jnp.where(ok, t, jnp.inf), axis=1)

    def weeds(o, d, tmax):
        if not shape.weed_slots:
            return jnp.full((n,), jnp.inf)
        wt = RW.all_weeds(fld)
        wf = jnp.broadcast_to(jnp.arange(shape.weed_slots), (n, shape.weed_slots))
        return plants(o, d, tmax, wt, wf, wt.box_t[0][wf] <= wt.box_t[1][wf])

    t_ter, _ = T.trace_terrain(fld.terrain, fld.terrain_size, o, d, tmin, far, 400, 12)
    obst = G.obstacle_table(fld, jnp.asarray(pos), -jnp.asarray(rot[:, 2]),
                            shape.obstacle_slots)
    t_obs, _, _ = G.trace_obstacles(obst, o, d, tmin)
    t_wd = weeds(o, d, jnp.minimum(jnp.minimum(t_ter, t_obs), far))
    t_pl = plants(o, d, jnp.minimum(jnp.minimum(jnp.minimum(t_ter, t_obs), t_wd), far))
    t = jnp.minimum(jnp.minimum(jnp.minimum(t_pl, t_obs), t_ter), t_wd)
    cls = jnp.where(~jnp.isfinite(t), RD.SKY, jnp.where(
        t == t_pl, RD.PLANT, jnp.where(t == t_wd, RD.WEED, jnp.where(t == t_obs, RD.OBSTACLE,
                                                                    RD.SOIL))))
    p = o + jnp.where(jnp.isfinite(t), t, 0.0)[:, None] * d
    ps, ds, reach = p + 1e-3 * sun, jnp.broadcast_to(sun, p.shape), jnp.full((n,), 60.0)
    lit = ~jnp.isfinite(plants(ps, ds, reach)) & ~jnp.isfinite(weeds(ps, ds, reach))
    return t, cls, lit


def test_mask_is_the_nearest_surface(scene):
    fld, shape, render = scene
    pos, rot = lane_poses(fld)
    for j in range(len(pos)):
        fr = render(fld, pos[j], rot[j], RD.conditions("sunny"))
        mask, cls = np.asarray(fr.mask), np.asarray(fr.classes)
        assert np.array_equal(mask, cls == RD.PLANT)
        t_ref, cls_ref, _ = brute_force(fld, shape, pos[j], rot[j], _sun(0.0))
        t_ref, cls_ref = np.asarray(t_ref), np.asarray(cls_ref).reshape(H, W)
        assert np.mean(cls == cls_ref) >= 0.995, f"pose {j}"
        plant = mask & (cls_ref == RD.PLANT)
        norm = np.linalg.norm(RD.pixel_rays(INTR), axis=-1).reshape(H, W)
        depth_ref = t_ref.reshape(H, W) / norm
        assert np.allclose(np.asarray(fr.depth)[plant], depth_ref[plant], atol=1e-3)


def test_curved_weedy_fields_agree_with_every_plant():
    # arcs and a sinusoid, with weeds and gaps: the tiles' culling through the row segments
    # (render.rows) and the weeds' culling keep what every plant and every weed tested by every
    # ray gives, along the lane and from the headland (the shape of the MuJoCo case: no
    # compile of its own beyond the brute force)
    for rows in ROWS:
        fld, shape = curved_field("zucchini", rows, seed=4)
        pos, rot = lane_poses(fld, headland=True)
        depth, cls = (np.asarray(x) for x in geometry_fn(shape)(fld, pos, rot))
        weeds_seen = 0
        for j in range(len(pos)):
            _, ref, _ = brute_force(fld, shape, pos[j], rot[j], _sun(0.0))
            ref = np.asarray(ref).reshape(H, W)
            mask, mask_ref = cls[j] == RD.PLANT, ref == RD.PLANT
            assert mask_ref.sum() > 40, f"{rows} pose {j} should see plants"
            iou = (mask & mask_ref).sum() / (mask | mask_ref).sum()
            assert iou >= 0.98, f"{rows} pose {j}: plant-mask IoU {iou:.4f}"
            assert np.mean(cls[j] == ref) >= 0.995, f"{rows} pose {j}"
            weeds_seen += (ref == RD.WEED).sum()
            assert np.sum((cls[j] == RD.WEED) != (ref == RD.WEED)) <= 3
        assert weeds_seen > 20


def test_fields_without_weed_slots_do_no_weed_work(scene, monkeypatch):
    # W = 0 (the static default): the renderer never builds a weed table; with weed slots it
    # does (traced only, nothing compiled)
    fld, shape, _ = scene
    pos, rot = lane_poses(fld)
    cond = RD.conditions("long_shadows")
    slots = dataclasses.replace(shape, weed_slots=4)
    empty = fld.replace(weed_pos=np.zeros((4, 3), np.float32),
                        weed_size=np.full((4, 2), 0.1, np.float32),
                        weed_yaw=np.zeros(4, np.float32), weed_phase=np.zeros(4, np.float32),
                        weed_active=np.zeros(4, bool))
    built, table = [], RW.table
    monkeypatch.setattr(RW, "table", lambda *a, **k: built.append(1) or table(*a, **k))
    for s, f in ((shape, fld), (slots, empty)):
        jax.eval_shape(lambda f, p, r, s=s: RD.render(f, s, p, r, INTR, cond), f, pos[0], rot[0])
        assert len(built) == (s.weed_slots > 0)


def test_sky_camera_sees_no_plant(scene):
    fld, shape, render = scene
    pos, _ = lane_poses(fld)
    fr = render(fld, pos[0], RD.camera_rot(0.3, np.deg2rad(80.0)), RD.conditions("sunny"))
    assert not np.asarray(fr.mask).any()
    assert (np.asarray(fr.classes) == RD.SKY).all()
    assert (np.asarray(fr.depth) == RD.SKY_DEPTH).all()
    rgb = np.asarray(fr.rgb, np.float32)
    assert rgb[..., 2].mean() > rgb[..., 0].mean() + 20  # a blue sky


def _sun(azimuth_deg, elevation_deg=35.0):
    a, e = np.deg2rad(azimuth_deg), np.deg2rad(elevation_deg)
    return np.array([np.cos(e) * np.cos(a), np.cos(e) * np.sin(a), np.sin(e)], np.float32)


def test_plants_cast_shadows_away_from_the_sun(scene):
    fld, shape, render = scene
    lane = int(F.robot_lane(fld))
    pos = np.array([0.0, float(fld.lane_y[lane]), 1.6], np.float32)
    rot = np.asarray(RD.camera_rot(0.0, np.deg2rad(-65.0)))
    soil = np.asarray(render(fld, pos, rot, RD.conditions("sunny")).classes) == RD.SOIL
    frames, lit = [], []
    for az in (90.0, -90.0):  # sun toward +y, then toward −y: mirrored shadows, same n·l
        sun = _sun(az)
        cond = RD.conditions("sunny").replace(sun_dir=jnp.asarray(sun))
        frames.append(np.asarray(render(fld, pos, rot, cond).rgb, np.float32).mean(-1))
        lit.append(np.asarray(brute_force(fld, shape, pos, rot, sun)[2]).reshape(H, W))
    shade_a = soil & ~lit[0] & lit[1]  # shadowed under sun A only
    both = soil & lit[0] & lit[1]
    assert shade_a.sum() > 30 and both.sum() > 30
    assert frames[0][shade_a].mean() < 0.7 * frames[1][shade_a].mean()
    ratio = frames[0][both].mean() / frames[1][both].mean()
    assert 0.95 < ratio < 1.05


def test_the_shadow_strength_fades_the_cast_shadows(scene):
    """`Conditions.shadow` (training's `env.randomize.shadow_strength`) scales the cast
    shadows: 0 draws the image without them (`render.shadows` off), 1 the usual one; soil in a
    plant's shadow brightens as the strength falls, sunlit soil stays as it is."""
    fld, shape, render = scene
    lane = int(F.robot_lane(fld))
    pos = np.array([0.0, float(fld.lane_y[lane]), 1.6], np.float32)
    rot = np.asarray(RD.camera_rot(0.0, np.deg2rad(-65.0)))
    sun = _sun(90.0)
    cond = RD.conditions("sunny").replace(sun_dir=jnp.asarray(sun))
    grey = {s: np.asarray(render(fld, pos, rot, cond.replace(shadow=np.float32(s))).rgb,
                          np.float32).mean(-1) for s in (0.0, 0.5, 1.0)}
    off = jax.jit(lambda f, p, r, c: RD.render(f, shape, p, r, INTR, c,
                                               cfg=RD.RenderConfig(shadows=False)))
    np.testing.assert_allclose(grey[0.0], np.asarray(off(fld, pos, rot, cond).rgb,
                                                     np.float32).mean(-1), atol=1.0)
    np.testing.assert_array_equal(grey[1.0], np.asarray(render(fld, pos, rot, cond).rgb,
                                                        np.float32).mean(-1))
    soil = np.asarray(render(fld, pos, rot, cond).classes) == RD.SOIL
    lit = np.asarray(brute_force(fld, shape, pos, rot, sun)[2]).reshape(H, W)
    shaded, sunlit = soil & ~lit, soil & lit
    assert shaded.sum() > 30 and sunlit.sum() > 30
    assert grey[1.0][shaded].mean() < grey[0.5][shaded].mean() < grey[0.0][shaded].mean()
    assert abs(grey[1.0][sunlit].mean() - grey[0.0][sunlit].mean()) < 1.0


def test_same_inputs_same_images(scene):
    fld, shape, render = scene
    pos, rot = lane_poses(fld)
    cond = RD.conditions("crepuscular")
    a = render(fld, pos[1], rot[1], cond)
    b = render(jax.tree.map(np.copy, fld), pos[1].copy(), rot[1].copy(), cond)
    for x, y in zip(jax.tree.leaves(a), jax.tree.leaves(b), strict=True):
        assert np.array_equal(np.asarray(x), np.asarray(y))
    # the geometry-only path sees exactly what the renderer draws
    depth, cls = geometry_fn(shape)(fld, pos[1:2], rot[1:2])
    assert np.array_equal(np.asarray(cls[0]), np.asarray(a.classes))
    assert np.array_equal(np.asarray(depth[0]), np.asarray(a.depth))
    other = render(fld, pos[1], rot[1], RD.conditions("sunny"))
    assert np.array_equal(np.asarray(other.mask), np.asarray(a.mask))
    assert np.abs(np.asarray(other.rgb, float) - np.asarray(a.rgb, float)).mean() > 10


def test_conditions_differ_and_validate():
    names = RD.CONDITIONS
    assert names == ("sunny", "cloudy", "crepuscular", "long_shadows")
    elev = {n: float(np.degrees(np.arcsin(RD.conditions(n).sun_dir[2]))) for n in names}
    assert elev["crepuscular"] < elev["long_shadows"] < elev["sunny"]
    warm = RD.conditions("crepuscular").sun_rgb
    assert warm[0] > 2 * warm[2]  # low warm sun
    assert RD.conditions("cloudy").sun_rgb.max() < 0.3 * RD.conditions("sunny").sun_rgb.max()
    k = jax.random.key(0)
    varied = RD.conditions("long_shadows", k)
    e = float(np.degrees(np.arcsin(varied.sun_dir[2])))
    assert 9.0 <= e <= 20.0
    by_index = RD.condition_by_index(jnp.int32(2), k)
    assert np.allclose(by_index.sun_dir, RD.conditions("crepuscular", k).sun_dir)
    with pytest.raises(ValueError, match="condition"):
        RD.conditions("foggy")
    with pytest.raises(ValueError, match="fovy"):
        RD.Intrinsics(64, 64, 190.0)
    with pytest.raises(ValueError, match="keep"):
        RD.RenderConfig(keep=0)


def test_camera_rot_convention():
    rot = np.asarray(RD.camera_rot(0.0, 0.0))
    # looking along +x: right = −y, up = +z, backwards = −x (MuJoCo: the camera looks along −z)
    assert np.allclose(rot, [[0, 0, -1], [-1, 0, 0], [0, 1, 0]], atol=1e-6)
    rot = np.asarray(RD.camera_rot(np.pi / 2, np.deg2rad(-30.0)))
    assert np.allclose(-rot[:, 2], [0.0, np.cos(np.pi / 6), -0.5], atol=1e-6)
    assert np.allclose(rot.T @ rot, np.eye(3), atol=1e-6) and np.linalg.det(rot) > 0


def test_terrain_eval_matches_field():
    fld, _ = tiny_field("lettuce", terrain_dh=0.3)
    rng = np.random.default_rng(0)
    x = rng.uniform(-7, 7, 500).astype(np.float32)
    y = rng.uniform(-7, 7, 500).astype(np.float32)
    h, _, _ = T.terrain_eval(fld.terrain, fld.terrain_size, x, y)
    ref = F.terrain_height(fld.terrain, fld.terrain_size, x, y)
    assert np.allclose(np.asarray(h), np.asarray(ref), atol=1e-5)


# The textures as they were written first, one class at a time (every pixel evaluated every
# class's noises): `shade.surfaces` evaluates six noise slots per pixel and must give the same.
def _fbm2(x, y, octaves, seed):
    total, amp, norm = 0.0, 1.0, 0.0
    for o in range(octaves):
        total = total + amp * S.value_noise2(x, y, seed + 17 * o)
        norm += amp
        x, y = 2.03 * x + 5.1, 2.03 * y - 3.7
        amp *= 0.5
    return total / norm


def _reference_surfaces(crop, cls, material, p, local, phase, plant, k, is_branch, normal, d,
                        cond):
    lin = lambda rgb: jnp.asarray(rgb, jnp.float32) ** 2.2  # noqa: E731
    x, y, z = p[:, 0], p[:, 1], p[:, 2]
    patches = _fbm2(x * 0.45, y * 0.45, 3, seed=1)
    clods = S.value_noise2(x * 9.0, y * 9.0, seed=2)
    grit = S.value_noise2(x * 40.0, y * 40.0, seed=3)
    f = (0.62 + 0.75 * patches) * (0.82 + 0.36 * clods) * (0.9 + 0.2 * grit)
    warm = 1.0 + 0.10 * (patches - 0.5)[:, None] * jnp.array([1.0, 0.2, -0.8])
    a_soil = lin((0.43, 0.32, 0.22)) * cond.soil_tint * f[:, None] * warm

    spec = crops.get(crop)
    base = lin(spec.palette)[material]
    per_plant = 0.80 + 0.40 * phase
    yellow = 1.0 + 0.18 * (phase - 0.5)[:, None] * jnp.array([1.0, 0.3, -1.0])
    per_prim = 0.85 + 0.30 * S.hash01(plant, k, seed=5)
    mottle = S.value_noise2(14.0 * (x + z), 14.0 * (y - 0.7 * z), seed=6)
    u0, u1 = local[:, 0], local[:, 1]
    midrib = jnp.exp(-((u1 / 0.07) ** 2)) * (u0 > -0.9)
    lateral = jnp.clip((jnp.cos(2 * jnp.pi * (3.5 * u0 - 2.2 * jnp.abs(u1))) - 0.8) * 5, 0, 1)
    veins = jnp.clip(midrib + 0.6 * lateral * (jnp.abs(u1) < 0.8), 0, 1)
    rim = jnp.clip((u0 * u0 + u1 * u1 - 0.55) * 2.5, 0, 1)
    f_leaf = (0.8 + 0.4 * mottle) * (1.0 + 0.45 * veins) * (1.0 - 0.25 * rim)
    if spec.silver_leaf:
        silver = jnp.clip((S.value_noise2(30 * x, 30 * y, seed=7) - 0.62) * 4, 0, 1)
        f_leaf = f_leaf + 0.6 * silver
    clumps = _fbm2(9.0 * (x + 0.5 * z), 9.0 * (y - 0.5 * z), 2, seed=9)
    f_canopy = 0.55 + 0.9 * clumps * (0.8 + 0.4 * mottle)
    f_trunk = 0.7 + 0.6 * S.value_noise2(40.0 * (x + y), 3.0 * z, seed=10)
    fine = jnp.where(material == PL.LEAF, f_leaf,
                     jnp.where(material == PL.CANOPY, f_canopy,
                               jnp.where(material == PL.TRUNK, f_trunk, 0.8 + 0.4 * mottle)))
    a_plant = base * cond.leaf_tint * yellow * (per_plant * per_prim * fine)[:, None]
    s = 12.0
    bump = jnp.stack([S.value_noise2(s * (x + z), s * y, seed=12),
                      S.value_noise2(s * (y + z), s * x, seed=13),
                      S.value_noise2(s * (x - y), s * z, seed=14)], -1) - 0.5
    m = normal + jnp.where(material == PL.CANOPY, 1.1, 0.35)[:, None] * bump
    bumped = m / jnp.maximum(jnp.linalg.norm(m, axis=-1, keepdims=True), 1e-6)

    n_obst = 0.8 + 0.4 * S.value_noise2(25 * x + 3 * z, 25 * y, seed=8)
    a_obst = jnp.where(is_branch[:, None], lin((0.42, 0.31, 0.20)),
                       lin((0.55, 0.53, 0.50))) * n_obst[:, None]

    h = jnp.maximum(d[:, 2], 0.03)
    clouds = _fbm2(1.7 * (d[:, 0] / h), 1.7 * (d[:, 1] / h), 4, seed=11)
    is_plant = (cls == S.PLANT)[:, None]
    albedo = jnp.where(is_plant, a_plant,
                       jnp.where((cls == S.OBSTACLE)[:, None], a_obst, a_soil))
    return albedo, jnp.where(is_plant, bumped, normal), S._sky(d, cond, clouds)


@pytest.mark.parametrize("crop", ["zucchini", "pear"])
def test_surfaces_from_noise_slots_match_each_class_textures(crop):
    n = 3000
    ks = jax.random.split(jax.random.key(7), 9)
    unit = lambda kk: (lambda v: v / jnp.linalg.norm(v, axis=-1, keepdims=True))(  # noqa: E731
        jax.random.normal(kk, (n, 3)))
    args = (jax.random.randint(ks[0], (n,), 0, 4),  # cls
            jax.random.randint(ks[1], (n,), 0, 5),  # material
            jax.random.uniform(ks[2], (n, 3), minval=-12.0, maxval=12.0),  # p
            jax.random.uniform(ks[3], (n, 3), minval=-1.2, maxval=1.2),  # local
            jax.random.uniform(ks[4], (n,)),  # phase
            jax.random.randint(ks[5], (n,), 0, 400),  # plant
            jax.random.randint(ks[6], (n,), 0, 30),  # k
            jax.random.bernoulli(ks[7], 0.5, (n,)),  # is_branch
            unit(ks[8]), unit(jax.random.fold_in(ks[8], 1)))  # normal, view direction
    cond = RD.conditions("sunny", jax.random.key(3))
    got = jax.jit(functools.partial(S.surfaces, crop))(*args, cond)
    want = jax.jit(functools.partial(_reference_surfaces, crop))(*args, cond)
    cls = np.asarray(args[0])
    for name, g, w, rows in (("albedo", got[0], want[0], cls != S.SKY),
                             ("normal", got[1], want[1], slice(None)),
                             ("sky", got[2], want[2], cls == S.SKY)):
        np.testing.assert_allclose(np.asarray(g)[rows], np.asarray(w)[rows], rtol=2e-6,
                                   atol=1e-7, err_msg=name)
    # and kept in memory (the CPU's `settle`), the same numbers
    kept = jax.jit(functools.partial(S.surfaces, crop, keep=G.materialise))(*args, cond)
    for g, w in zip(got, kept, strict=True):
        np.testing.assert_allclose(np.asarray(g), np.asarray(w), rtol=2e-6, atol=1e-7)
