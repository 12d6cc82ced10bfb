"""Tile culling (render_tiles): the static tile layout, the conservative cone and shadow box
tests against brute force, the row windows on curved rows against every plant a tile's rays
meet, the tiled exact tests against the per-plant reference, padded images, deep tiles on
grazing views, a precomputed plant table, every kernel alike, and the weeds' radius."""

import dataclasses
import functools

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from mjxrow import field as F
from mjxrow import render as RD
from mjxrow.bench import render as BR
from mjxrow.crops import prims as PL
from mjxrow.field import lanes as LN
from mjxrow.render import geom as G
from mjxrow.render import pallas as RP
from mjxrow.render import tiles as RT
from mjxrow.render import weeds as RW

COMMON = F.FieldShape(crop="zucchini", max_rows=16, max_plants_per_row=40,
                      terrain_cells=(96, 88), obstacle_slots=8)


def test_tile_layout_round_trip():
    # 13 × 18 pixels in tiles of 4: 4 × 5 tiles, the last row and column padded
    intr = RD.Intrinsics(18, 13, 50.0)
    dirs, norm, centre, tan_a, tiles = RT.tile_layout(18, 13, 50.0, 4)
    assert tiles == (4, 5) and dirs.shape == (20, 16, 3) and centre.shape == (20, 3)
    img = np.asarray(RT.untile(jnp.asarray(dirs * norm[..., None]), tiles, 13, 18))
    assert np.allclose(img.reshape(-1, 3), RD.pixel_rays(intr), atol=1e-6)
    # every pixel ray lies inside its tile's cone, the widest barely
    cos = np.sum(dirs * centre[:, None], -1)
    ang = np.arccos(np.clip(cos, -1, 1)).max(1)
    assert np.all(np.tan(ang) <= tan_a) and np.all(tan_a <= np.tan(ang) * 1.01 + 1e-5)
    # the top-left tile's centre: the mean of pixel rays 0..3, up and to the left
    assert centre[0, 0] < 0 and centre[0, 1] > 0 and centre[0, 2] < 0


def _ray_box_entry(o, d, lo, hi, t_max):
    """Brute-force entry t of rays o + t·d ([..., 3], broadcasting) into boxes [lo, hi]
    ([..., 3]): [...] (inf: missed)."""
    inv = 1.0 / np.where(np.abs(d) < 1e-12, 1e-12, d)
    ta, tb = (lo - o) * inv, (hi - o) * inv
    t0 = np.maximum(np.minimum(ta, tb).max(-1), 0.0)
    t1 = np.minimum(np.maximum(ta, tb).min(-1), t_max)
    return np.where(t0 <= t1, t0, np.inf)


def test_cone_entry_bounds_every_tile_ray():
    rng = np.random.default_rng(0)
    dirs, _, centre, tan_a, _ = RT.tile_layout(32, 24, 42.0, 4)
    o = np.array([0.3, -0.2, 0.5], np.float32)
    lo = rng.uniform(-6, 6, (400, 3)).astype(np.float32)
    lo[:, 0] += 8.0  # boxes ahead of a camera looking along +x
    hi = lo + rng.uniform(0.05, 1.0, (400, 3)).astype(np.float32)
    box = [jnp.asarray(b) for b in (lo[:, 0], hi[:, 0], lo[:, 1], hi[:, 1], lo[:, 2], hi[:, 2])]
    rot = np.asarray(RD.camera_rot(0.0, -0.1))
    d = dirs @ rot.T
    c = jnp.asarray(centre @ rot.T)
    t_cut = jnp.full((len(centre),), 30.0)
    sweep = RT.camera_sweep(jnp.asarray(o), c, jnp.asarray(tan_a))
    bound = np.asarray(RT._sweep_entry(*sweep, box, t_cut))  # [T, M]
    e = _ray_box_entry(o, d[:, :, None], lo, hi, 30.0).min(1)  # [T, M]: first tile ray in
    met = np.isfinite(e)
    assert met.sum() > 50
    assert np.all(bound[met] <= e[met] + 1e-4)
    # and the test culls: most (tile, box) pairs are out
    assert np.isfinite(bound).mean() < 0.3


def test_shadow_box_test_is_exact_for_points_in_the_tile_box():
    rng = np.random.default_rng(1)
    sun = np.array([0.5, 0.3, 0.81], np.float32)
    sun /= np.linalg.norm(sun)
    lo_t = rng.uniform(-3, 3, (30, 3)).astype(np.float32)
    hi_t = lo_t + rng.uniform(0.0, 0.8, (30, 3)).astype(np.float32)
    lo = rng.uniform(-3, 3, (200, 3)).astype(np.float32)
    lo[:, 2] += 1.5
    hi = lo + rng.uniform(0.1, 0.8, (200, 3)).astype(np.float32)
    box = [jnp.asarray(b) for b in (lo[:, 0], hi[:, 0], lo[:, 1], hi[:, 1], lo[:, 2], hi[:, 2])]
    sweep, live = RT.shadow_sweep(jnp.asarray(lo_t), jnp.asarray(hi_t), jnp.asarray(sun))
    assert np.asarray(live).all()
    ent = np.asarray(RT._sweep_entry(*sweep, box, jnp.full((30,), 60.0)))
    # points of each tile box, their corners included
    u = np.concatenate([rng.uniform(size=(60, 3)), np.indices((2, 2, 2)).reshape(3, -1).T])
    pts = lo_t[:, None] + u[None] * (hi_t - lo_t)[:, None]  # [30, 68, 3]
    e = _ray_box_entry(pts[:, :, None], sun, lo, hi, 60.0)  # [30, 68, 200]
    hit = np.isfinite(e).any(1)
    assert hit.sum() > 10 and np.all(np.isfinite(ent[hit]))
    assert np.isfinite(ent).mean() < 0.5


generate = jax.jit(F.generate, static_argnums=1)


@pytest.fixture(scope="module")
def lane_scene():
    params = F.make_params("zucchini", terrain_length=14.0, row_length=10.0, terrain_width=14.0,
                           p_missing=0.0)
    fld = jax.tree.map(np.asarray, generate(params, COMMON, jax.random.key(5)))
    lane = int(F.robot_lane(fld))
    y = float(fld.lane_y[lane])
    x0 = float(fld.row_x[0])
    z = float(F.terrain_height(fld.terrain, fld.terrain_size, x0 - 0.5, y)) + 0.35
    return fld, COMMON, np.array([x0 - 0.5, y, z], np.float32)


# curved rows, stronger than the fields' usual ones: arcs turning 0.6 rad over the 10 m rows,
# a sinusoid of 0.5 m with a 6 m wavelength (COMMON: the lane scene's generator compile)
CURVES = {"arc": dict(row_curvature=0.06), "sine": dict(row_amplitude=0.5, row_wavelength=6.0)}


def curved_scene(rows):
    params = F.make_params("zucchini", terrain_length=14.0, row_length=10.0, terrain_width=14.0,
                           p_missing=0.0, **CURVES[rows])
    F.validate(params, COMMON)
    return jax.tree.map(np.asarray, generate(params, COMMON, jax.random.key(6))), COMMON


def _field_pose(fld, s, du, h, turn, pitch_deg):
    """(cam_pos, cam_rot) at (s, u = robot lane + du) in field coordinates, h over the
    ground, turned by `turn` from the lane's heading."""
    bend = LN.field_bend(fld)
    u = float(fld.lane_y[int(F.robot_lane(fld))]) + du
    x, y = (float(v) for v in LN.to_world(bend, jnp.float32(s), jnp.float32(u)))
    yaw = float(LN.heading(bend, jnp.float32(s), jnp.float32(u))) + turn
    z = float(F.terrain_height(fld.terrain, fld.terrain_size, x, y)) + h
    return np.array([x, y, z], np.float32), np.asarray(RD.camera_rot(yaw, np.deg2rad(pitch_deg)))


@functools.partial(jax.jit, static_argnums=1)
def _met(fld, shape, o, d, t_max):
    """Which plants each ray o + t·d ([N, 3]; t in (0.01, t_max [N])) meets: bool [N, R·P]."""
    tab = G.plant_table(fld, shape)
    n, RPn = o.shape[0], tab.box_t.shape[1]
    flat = jnp.broadcast_to(jnp.arange(RPn), (n, RPn))
    col = lambda v: tuple(v[:, i:i + 1] for i in range(3))  # noqa: E731
    t, _ = G.nearest_prim(tab, flat, col(o), col(d), jnp.full((n, 1), 0.01), t_max[:, None])
    return jnp.isfinite(t) & (tab.box_t[0] <= tab.box_t[1])


@functools.partial(jax.jit, static_argnums=(1, 2))
def _windows(fld, shape, row_blocks, o, c, g, tau, t_max):
    tab = G.plant_table(fld, shape)
    return RT._window(tab, shape.max_plants_per_row, o, c, g, tau, t_max, row_blocks)


def _blocks_of(met, shape):
    """[T, R·P] plants met → set of (tile, block id) they lie in."""
    nb = -(-shape.max_plants_per_row // G.BLOCK)
    t, plant = np.nonzero(met)
    r, i = divmod(plant, shape.max_plants_per_row)
    return set(zip(t.tolist(), (r * nb + i // G.BLOCK).tolist(), strict=True))


def test_row_windows_hold_every_plant_a_tile_meets():
    # on arcs and a sinusoid, every plant any ray of a tile meets (camera tiles: along the
    # lane, across the rows from the headland, high and steep; shadow tiles: boxes of ground
    # points, swept to the sun) lies in a block of the tile's row windows, when the windows are
    # long enough to hold a row's blocks met (a window counted from the entry segment's end
    # instead of the row's slots met missed plants of an arc seen from above)
    nb = -(-COMMON.max_plants_per_row // G.BLOCK)
    dirs, _, centre, tan_a, _ = RT.tile_layout(32, 24, 45.0, 4)
    for rows in CURVES:
        fld, shape = curved_scene(rows)
        x0, x1 = (float(v) for v in fld.row_x)
        checked = 0
        for s, du, h, turn, pitch in [(x0 - 1.0, 0.0, 0.4, 0.0, -8.0),
                                      (x1 - 2.0, 0.3, 0.4, np.pi, -4.0),
                                      (x1 + 1.5, 0.0, 0.5, np.pi / 2, -10.0),
                                      (x0 - 1.5, 0.0, 0.5, -1.0, -12.0),
                                      (0.5 * (x0 + x1), 0.0, 2.0, 0.6, -50.0)]:
            pos, rot = _field_pose(fld, s, du, h, turn, pitch)
            d = dirs @ rot.T  # [T, P, 3]
            T_, P_ = d.shape[:2]
            met = np.asarray(_met(fld, shape, jnp.broadcast_to(jnp.asarray(pos), (T_ * P_, 3)),
                                  jnp.asarray(d.reshape(-1, 3)), jnp.full((T_ * P_,), 60.0)))
            met = met.reshape(T_, P_, -1).any(1)
            c = jnp.asarray(centre @ rot.T)
            bid, ok = (np.asarray(x) for x in _windows(
                fld, shape, nb, *RT.camera_sweep(jnp.asarray(pos), c, jnp.asarray(tan_a)),
                jnp.full((T_,), 60.0)))
            kept = {(t, b) for t in range(T_) for b in bid[t][ok[t]].tolist()}
            need = _blocks_of(met, shape)
            assert need <= kept, f"{rows}: {sorted(need - kept)[:5]} missing"
            checked += len(need)
        # shadow rays from boxes of points near the ground around the lane
        rng = np.random.default_rng(0)
        sun = np.array([0.4, -0.5, 0.35], np.float32)
        sun /= np.linalg.norm(sun)
        centres = np.stack([_field_pose(fld, s_, du, 0.05, 0.0, 0.0)[0] for s_, du in
                            zip(rng.uniform(x0, x1, 24), rng.uniform(-2.5, 2.5, 24),
                                strict=True)])
        lo = centres - rng.uniform(0.05, 0.6, (24, 3)).astype(np.float32)
        hi = centres + rng.uniform(0.05, 0.6, (24, 3)).astype(np.float32)
        pts = lo[:, None] + rng.uniform(size=(24, 64, 3)).astype(np.float32) * (hi - lo)[:, None]
        met = np.asarray(_met(fld, shape, jnp.asarray(pts.reshape(-1, 3)),
                              jnp.broadcast_to(jnp.asarray(sun), (24 * 64, 3)),
                              jnp.full((24 * 64,), 60.0))).reshape(24, 64, -1).any(1)
        sweep, _ = RT.shadow_sweep(jnp.asarray(lo), jnp.asarray(hi), jnp.asarray(sun))
        bid, ok = (np.asarray(x) for x in _windows(fld, shape, nb, *sweep,
                                                    jnp.full((24,), 60.0)))
        need = _blocks_of(met, shape)
        assert need <= {(t, b) for t in range(24) for b in bid[t][ok[t]].tolist()}, rows
        assert checked > 40 and len(need) > 10


@functools.cache
def _geometry(shape, intr, cfg):
    return jax.jit(lambda f, p, r: RD.geometry(f, shape, p, r, intr, cfg))


def _reference_classes(fld, shape, intr, pos, rot):
    """Per-pixel tiles (tile = 1: every ray culled on its own) with every candidate kept."""
    cfg = RD.RenderConfig(tile=1, block_keep=64, keep=64, deep_keep=0)
    return np.asarray(_geometry(shape, intr, cfg)(fld, pos, rot)[1])


def test_tiles_see_what_single_rays_see_on_a_padded_image(lane_scene):
    fld, shape, pos = lane_scene
    intr = RD.Intrinsics(30, 22, 45.0)  # neither side a multiple of the tile
    rot = np.asarray(RD.camera_rot(0.1, np.deg2rad(-12.0)))
    ref = _reference_classes(fld, shape, intr, pos, rot)
    depth, cls = _geometry(shape, intr, RD.DEFAULT_CONFIG)(fld, pos, rot)
    assert cls.shape == (22, 30) and depth.shape == (22, 30)
    assert (ref == RD.PLANT).sum() > 60
    assert np.array_equal(np.asarray(cls), ref)


# -m slow (.ci/slow): 20 s of CPU compilation; the suite keeps the reach bound of the deep pass
@pytest.mark.slow
def test_deep_tiles_complete_grazing_views(lane_scene):
    # looking along the lane a little towards a row: each tile's rays meet the row's plants
    # at many depths, more than `keep` candidates
    fld, shape, pos = lane_scene
    intr = RD.Intrinsics(48, 32, 45.0)
    rot = np.asarray(RD.camera_rot(0.08, np.deg2rad(-6.0)))
    ref = _reference_classes(fld, shape, intr, pos, rot)
    shallow = RD.RenderConfig(keep=2, deep_keep=0)
    deep = RD.RenderConfig(keep=2, deep_keep=30, deep_share=0.5)
    cls0 = np.asarray(_geometry(shape, intr, shallow)(fld, pos, rot)[1])
    cls1 = np.asarray(_geometry(shape, intr, deep)(fld, pos, rot)[1])
    cls = np.asarray(_geometry(shape, intr, RD.DEFAULT_CONFIG)(fld, pos, rot)[1])
    assert np.sum(cls0 != ref) >= 20, np.sum(cls0 != ref)  # two candidates per tile miss
    assert np.sum(cls1 != ref) <= 2  # the deep tiles test the rest
    assert np.sum(cls != ref) <= 2


# the Pallas kernels run in their interpreter on a CPU: minutes; -m slow (.ci/slow)
@pytest.mark.parametrize("kernel", ["scan", "fused",
                                    pytest.param("pallas", marks=pytest.mark.slow)])
def test_tiled_exact_matches_per_plant_reference(lane_scene, kernel):
    fld, shape, _ = lane_scene
    tab = G.plant_table(fld, shape)
    rng = np.random.default_rng(2)
    active = np.flatnonzero(np.asarray(fld.plant_active).reshape(-1))
    ids = jnp.asarray(rng.choice(active, (6, 7)), jnp.int32)
    valid = jnp.asarray(rng.uniform(size=(6, 7)) < 0.8)
    # rays aimed at the candidates' plant centres, from one side
    cb = np.asarray(tab.box_t)
    ctr = np.stack([0.5 * (cb[0] + cb[1]), 0.5 * (cb[2] + cb[3]), 0.5 * (cb[4] + cb[5])], -1)
    target = ctr[np.asarray(ids)][:, rng.integers(0, 7, 4)] + rng.normal(0, 0.1, (6, 4, 3))
    o = target + np.array([0.0, 2.0, 0.6])
    d = (target - o) / np.linalg.norm(target - o, axis=-1, keepdims=True)
    o, d = jnp.asarray(o, jnp.float32), jnp.asarray(d, jnp.float32)
    t_min, t_max = jnp.full((6, 4), 0.01), jnp.full((6, 4), 50.0)
    xyz = lambda v: tuple(v[..., i] for i in range(3))  # noqa: E731
    # reference: every candidate of the ray's tile through nearest_prim
    flat = jnp.repeat(ids, 4, axis=0)
    col = lambda v: tuple(v.reshape(-1, 3)[:, i:i + 1] for i in range(3))  # noqa: E731
    tr, kr = G.nearest_prim(tab, flat, col(o), col(d), t_min.reshape(-1, 1),
                            t_max.reshape(-1, 1))
    tr = jnp.where(jnp.repeat(valid, 4, axis=0), tr, jnp.inf)
    # entry bounds: 0 (no skipping), or the tightest lower bound (each candidate's nearest hit
    # over its tile's rays; the Pallas kernel skips a candidate once every ray's hit is nearer)
    tight = np.min(np.asarray(tr).reshape(6, 4, 7), axis=1)
    for entry in (jnp.where(valid, 0.0, jnp.inf), jnp.where(valid, tight, jnp.inf)):
        args = (tab, ids, entry, xyz(o), xyz(d), t_min, t_max)
        t, plant, k = RT.exact(*args, kernel=kernel)
        t_any = RT.exact(*args, any_hit=True, kernel=kernel)
        _check_exact(t, plant, k, t_any, tr, kr, flat)
    # a bound beyond the rays' reach: nothing is tested
    far = RT.exact(tab, ids, jnp.full((6, 7), 60.0), xyz(o), xyz(d), t_min, t_max,
                   kernel=kernel)[0]
    assert np.all(np.isinf(np.asarray(far)))


def _check_exact(t, plant, k, t_any, tr, kr, flat):
    best = np.argmin(np.asarray(tr), 1)
    t_ref = np.asarray(tr)[np.arange(24), best]
    assert np.isfinite(t_ref).sum() >= 10
    # the fused reduction keeps the index in t's low mantissa bits (relative error < 2^-17
    # for 7 candidates × up to 8 primitives)
    assert np.allclose(np.asarray(t).reshape(-1), t_ref, rtol=1e-5)
    assert np.array_equal(np.isfinite(np.asarray(t_any)).reshape(-1), np.isfinite(t_ref))
    hit = np.isfinite(t_ref)
    assert np.array_equal(np.asarray(plant).reshape(-1)[hit], np.asarray(flat)[np.arange(24),
                                                                              best][hit])
    assert np.array_equal(np.asarray(k).reshape(-1)[hit], np.asarray(kr)[np.arange(24),
                                                                          best][hit])


# -m slow (.ci/slow): 21 s of CPU compilation for one more renderer program
@pytest.mark.slow
def test_precomputed_table_gives_the_same_frame(lane_scene):
    fld, shape, pos = lane_scene
    intr = RD.Intrinsics(16, 16, 45.0)
    rot = np.asarray(RD.camera_rot(0.0, np.deg2rad(-10.0)))
    cond = RD.conditions("sunny")
    tab = jax.jit(RD.plant_table, static_argnums=1)(fld, shape)
    a = jax.jit(lambda f, p, r: RD.render(f, shape, p, r, intr, cond))(fld, pos, rot)
    b = jax.jit(lambda f, p, r, t: RD.render(f, shape, p, r, intr, cond, table=t))(
        fld, pos, rot, tab)
    for x, y in zip(jax.tree.leaves(a), jax.tree.leaves(b), strict=True):
        assert np.array_equal(np.asarray(x), np.asarray(y))
    assert np.asarray(a.mask).any()


# -m slow (.ci/slow): the Pallas kernels run in their interpreter on a CPU (minutes); the fused
# kernel's own program costs 20 s of CPU compilation, and every other render test runs it
@pytest.mark.slow
@pytest.mark.parametrize("kernel", ["fused", "pallas"])
def test_every_kernel_renders_the_same_frame(lane_scene, kernel):
    fld, shape, pos = lane_scene
    intr = RD.Intrinsics(24, 16, 45.0)
    rot = np.asarray(RD.camera_rot(0.3, np.deg2rad(-12.0)))
    cond = RD.conditions("long_shadows")
    frames = [jax.jit(lambda f, p, r, c=c: RD.render(f, shape, p, r, intr, cond, cfg=c))(
        fld, pos, rot) for c in (RD.RenderConfig(kernel=k) for k in ("scan", kernel))]
    a = frames[0]
    assert np.asarray(a.mask).any()
    for b in frames[1:]:
        assert np.array_equal(np.asarray(a.classes), np.asarray(b.classes))
        assert np.allclose(np.asarray(a.depth), np.asarray(b.depth), rtol=1e-4, atol=1e-5)
        assert np.max(np.abs(np.asarray(a.rgb, int) - np.asarray(b.rgb, int))) <= 1


def test_weed_primitives_lie_within_their_radius(lane_scene):
    # the weed table's selection grows each weed by `weeds.radius`: every primitive of every
    # weed (sizes, yaws and phases spread out) lies within it of the weed's base point
    rng = np.random.default_rng(3)
    n = 64
    d = rng.uniform(0.02, 0.5, n)
    fld = lane_scene[0].replace(
        weed_pos=rng.uniform(-3, 3, (n, 3)).astype(np.float32),
        weed_size=np.stack([d, d * rng.uniform(0.2, 0.8, n)], -1).astype(np.float32),
        weed_yaw=rng.uniform(0, 2 * np.pi, n).astype(np.float32),
        weed_phase=rng.uniform(0, 1, n).astype(np.float32), weed_active=np.ones(n, bool))
    pr = jax.tree.map(np.asarray, PL.weed_prims(fld))
    far = np.linalg.norm(pr.centre - fld.weed_pos[:, None], axis=-1) + pr.size.max(-1)
    assert np.all(far.max(-1) <= np.asarray(RW.radius(fld)))
    assert np.all(pr.material == PL.WEED)


@pytest.mark.slow  # the Pallas kernels run in their interpreter on a CPU: minutes (.ci/slow)
def test_every_kernel_draws_obstacles_and_their_shadows_alike(lane_scene):
    fld, shape, pos = lane_scene
    x, y = float(pos[0]), float(pos[1])
    ground = [float(F.terrain_height(fld.terrain, fld.terrain_size, x + dx, y + dy))
              for dx, dy in ((1.2, 0.0), (2.2, 0.3))]
    n = fld.obst_pos.shape[0]
    opos = np.zeros((n, 3), np.float32)
    opos[0] = (x + 1.2, y, ground[0] + 0.08)  # a stone ahead
    opos[1] = (x + 2.2, y + 0.3, ground[1] + 0.04)  # a branch across the lane
    size = np.zeros((n, 2), np.float32)
    size[0], size[1] = (0.08, 0.0), (0.04, 0.3)
    fld = fld.replace(obst_pos=opos, obst_size=size, obst_yaw=np.full(n, 1.2, np.float32),
                      obst_kind=np.array([0, 1] + [0] * (n - 2), np.int32),
                      obst_active=np.arange(n) < 2)
    intr = RD.Intrinsics(16, 16, 50.0)
    rot = np.asarray(RD.camera_rot(0.0, np.deg2rad(-20.0)))
    cond = RD.conditions("long_shadows")
    frames = [jax.jit(lambda f, p, r, c=c: RD.render(f, shape, p, r, intr, cond, cfg=c))(
        fld, pos, rot) for c in (RD.RenderConfig(kernel=k) for k in ("scan", "pallas"))]
    a, b = frames
    assert np.sum(np.asarray(a.classes) == RD.OBSTACLE) >= 4
    assert np.array_equal(np.asarray(a.classes), np.asarray(b.classes))
    assert np.allclose(np.asarray(a.depth), np.asarray(b.depth), rtol=1e-4, atol=1e-5)
    assert np.max(np.abs(np.asarray(a.rgb, int) - np.asarray(b.rgb, int))) <= 1


def test_default_tile_follows_the_resolution():
    assert [RD.default_tile(RD.Intrinsics(r, r)) for r in (16, 32, 64, 100, 128, 224, 512)] == [
        4, 4, 8, 8, 16, 16, 16]
    cfg = RD.resolve(RD.DEFAULT_CONFIG, "zucchini", RD.Intrinsics(128, 96))
    assert cfg.tile == 8 and cfg.kernel == "scan"  # the narrower side decides; CPU: scan


def test_kernel_environment_override(monkeypatch):
    monkeypatch.setenv("MJXROW_RENDER_KERNEL", "fused")
    assert RD.resolve(RD.DEFAULT_CONFIG, "pear").kernel == "fused"
    assert RD.resolve(RD.RenderConfig(kernel="scan"), "pear").kernel == "scan"  # explicit wins
    monkeypatch.setenv("MJXROW_RENDER_KERNEL", "triton")
    with pytest.raises(ValueError, match="MJXROW_RENDER_KERNEL"):
        RD.resolve(RD.DEFAULT_CONFIG, "pear")


def test_config_validates():
    with pytest.raises(ValueError, match="tile"):
        RD.RenderConfig(tile=0)
    with pytest.raises(ValueError, match="deep_share"):
        RD.RenderConfig(deep_share=1.5)
    with pytest.raises(ValueError, match="render.kernel"):
        RD.RenderConfig(kernel="cuda")
    with pytest.raises(ValueError, match="power-of-two"):
        RP.exact(None, jnp.zeros((2, 3), jnp.int32), jnp.zeros((2, 3)), (0.0,) * 3,
                 (0.0,) * 3, jnp.zeros((2, 9)), jnp.ones((2, 9)))
    assert dataclasses.replace(RD.DEFAULT_CONFIG, deep_keep=0).deep_keep == 0
    with pytest.raises(ValueError, match="render.settle"):
        RD.RenderConfig(settle="fuse")
    assert RD.resolve(RD.DEFAULT_CONFIG, "pear").settle == "loop"  # the CPU's default
    assert BR.parse_sets(["settle=barrier", "keep=8"]) == {"settle": "barrier", "keep": 8}
    with pytest.raises(ValueError, match="'kernel=cuda'"):
        BR.parse_sets(["kernel=cuda"])


def test_default_settle_by_backend_and_resolution(monkeypatch):
    from mjxrow.render import config

    assert config.default_settle(RD.Intrinsics(64, 64)) == "loop"  # this CPU
    monkeypatch.setattr(config.jax, "default_backend", lambda: "gpu")
    assert config.default_settle(RD.Intrinsics(64, 64)) == "barrier"
    assert config.default_settle(RD.Intrinsics(48, 32)) == "barrier"
    assert config.default_settle(RD.Intrinsics(128, 128)) == "none"
    assert config.default_settle(None) == "none"
    assert RD.resolve(RD.DEFAULT_CONFIG, "zucchini", RD.Intrinsics(224, 224)).settle == "none"
    assert RD.resolve(RD.RenderConfig(settle="loop"), "zucchini",
                      RD.Intrinsics(64, 64)).settle == "loop"  # an explicit choice stays


def test_deep_share_by_crop_and_tiles_across():
    # the crop's share up to 8 tiles across the shorter side, 8 / n of it for n tiles across,
    # never less than half
    res = lambda crop, w, h=None, **kw: RD.resolve(RD.RenderConfig(**kw), crop,  # noqa: E731
                                                   RD.Intrinsics(w, h or w))
    for crop, share in (("zucchini", 0.25), ("lettuce", 0.25)):
        assert res(crop, 64).deep_share == share  # 8 tiles of 8 px
        assert res(crop, 128).deep_share == share  # 8 tiles of 16 px
        assert res(crop, 224).deep_share == pytest.approx(share * 8 / 14)  # 14 tiles of 16 px
        assert res(crop, 224, 128).deep_share == share  # the shorter side counts
        assert res(crop, 32).deep_share == share  # 8 tiles of 4 px
    assert res("zucchini", 224, tile=8).deep_share == 0.125  # 28 tiles across: half
    assert res("zucchini", 224, deep_share=0.3).deep_share == 0.3  # an explicit choice stays
    assert RD.resolve(RD.DEFAULT_CONFIG, "zucchini").deep_share == 0.25  # no intrinsics


@pytest.mark.slow  # a compile per settle mode (a GPU-side choice; the CPU's is "loop"): -m slow
def test_settle_modes_draw_the_same_image():
    shape, fields, pos, rot, conds = BR.worlds("zucchini", 2, 1)
    intr = RD.Intrinsics(16, 16)
    rgb = [np.asarray(jax.jit(jax.vmap(functools.partial(
        RD.render, shape=shape, intr=intr, cfg=RD.RenderConfig(settle=mode))))(
            fields, cam_pos=pos, cam_rot=rot, cond=conds).rgb)
        for mode in RD.SETTLES]
    assert all(np.array_equal(rgb[0], other) for other in rgb[1:])


# -m slow (.ci/slow): 45 s of CPU compilation; test_render keeps obstacles against MuJoCo
@pytest.mark.slow
def test_obstacles_culled_per_tile_match_every_obstacle():
    # a camera looking down on two crossing branches: the tiles' nearest two obstacles give
    # the same picture (and the same shadows) as every ray testing all the frame's obstacles
    shape, fields, _, _, _ = BR.worlds("pear", 4, 3)
    fld = jax.tree.map(lambda x: x[0], fields)
    act = np.flatnonzero(np.asarray(fld.obst_active))
    pos = np.asarray(fld.obst_pos)[act]
    near = np.linalg.norm(pos[:, None, :2] - pos[None, :, :2], axis=-1) + 1e3 * np.eye(len(act))
    i, j = np.unravel_index(np.argmin(near), near.shape)
    cam = jnp.asarray(0.5 * (pos[i] + pos[j]) + np.array([-0.2, 0.0, 0.8]), jnp.float32)
    rot = RD.camera_rot(0.0, -1.3)
    intr = RD.Intrinsics(64, 64, 60.0)
    out = []
    for keep in (8, 2):
        cfg = RD.RenderConfig(obstacle_keep=keep)
        out.append(jax.jit(lambda f, p, q, cfg=cfg: RD.render(
            f, shape, p, q, intr, RD.conditions("long_shadows"), cfg=cfg))(fld, cam, rot))
    a, b = out
    assert np.sum(np.asarray(a.classes) == RD.OBSTACLE) >= 30
    assert np.array_equal(np.asarray(a.classes), np.asarray(b.classes))
    assert np.array_equal(np.asarray(a.rgb), np.asarray(b.rgb))


# -m slow (.ci/slow): 19 s of CPU compilation for one more renderer program
@pytest.mark.slow
def test_deep_sub_tiles_keep_what_whole_deep_tiles_drop(lane_scene):
    # the same grazing view, deep lists too short for a whole tile: split into 2 x 2 sub-tiles
    # (each its own cone and cut), the deep pass finds the plants the whole tile's list drops
    fld, shape, pos = lane_scene
    intr = RD.Intrinsics(48, 32, 45.0)
    rot = np.asarray(RD.camera_rot(0.08, np.deg2rad(-6.0)))
    ref = _reference_classes(fld, shape, intr, pos, rot)
    short = dict(tile=8, keep=2, deep_keep=6, deep_share=0.5)
    miss = [int(np.sum(np.asarray(_geometry(shape, intr, RD.RenderConfig(
        **short, deep_split=n))(fld, pos, rot)[1]) != ref)) for n in (1, 2, 4)]
    assert miss[1] < miss[0] and miss[2] <= miss[1], miss
    with pytest.raises(ValueError, match="render.deep_split"):
        RD.RenderConfig(deep_split=3)


def test_reach_bounds_every_plant_a_cull_leaves_out(lane_scene):
    # `cull`'s reach (where the deep pass's second list starts): every plant a tile's list
    # leaves out enters each of the tile's rays at or beyond it (short lists, so that most
    # grazing tiles leave plants out; windows holding every block of a row)
    fld, shape, pos = lane_scene
    P = shape.max_plants_per_row
    nb = -(-P // G.BLOCK)
    tab = G.plant_table(fld, shape)
    dirs, _, centre, tan_a, _ = RT.tile_layout(48, 32, 45.0, 8)
    rot = np.asarray(RD.camera_rot(0.08, np.deg2rad(-6.0)))
    d = dirs @ rot.T
    sweep = RT.camera_sweep(jnp.asarray(pos), jnp.asarray(centre @ rot.T), jnp.asarray(tan_a))
    t_max = jnp.full((len(centre),), 40.0)
    ids, _, rest, reach = (np.asarray(x) for x in RT.cull(tab, P, *sweep, t_max, nb, 3, 4))
    box = np.asarray(tab.box_t)
    lo, hi = box[0::2].T, box[1::2].T  # [R·P, 3]
    e = _ray_box_entry(pos, d[:, :, None], lo, hi, 40.0).min(1)  # [T, R·P]
    left = 0
    for t in range(len(centre)):
        out = np.ones(lo.shape[0], bool)
        out[ids[t]] = False
        out &= np.isfinite(e[t]) & np.all(lo <= hi, 1)  # met; an inactive plant's box is empty
        assert np.all(e[t][out] >= reach[t] - 1e-4), (t, e[t][out].min(), reach[t])
        left += out.sum()
    assert left > 20 and np.sum(reach < 40.0) > 5  # the lists are short: the bound bites
