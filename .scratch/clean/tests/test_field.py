"""Facts of the field generator: spacings, determinism, terrain bounds, validation, tracing."""

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from mjxrow import crops
from mjxrow import field as F

SMALL = dict(terrain_length=14.0, row_length=10.0, terrain_width=14.0, p_missing=0.0)


def _gen(preset="zucchini", key=0, **kw):
    p = F.make_params(preset, **{**SMALL, **kw})
    shape = F.fit_shape(p, preset)
    return F.generate(p, shape, jax.random.key(key)), p, shape


def _measured_rows(f):
    y = np.asarray(f.row_y)[np.asarray(f.row_active)]
    return y, np.diff(y)


def test_zucchini_spacings_and_groups():
    f, p, _ = _gen(plant_jitter=0.0)
    y, gaps = _measured_rows(f)
    # 14 m wide, 7 rows per group at 1.8 m, 3.6 m between groups: (14 - 2 - 10.8) < 14.4 ⇒ 1 group
    assert len(y) == 7 and np.allclose(gaps, 1.8, atol=0.02)
    f2, *_ = _gen(terrain_width=38.0)
    y2, gaps2 = _measured_rows(f2)
    assert len(y2) == 14  # two groups fit 38 m
    assert np.allclose(gaps2[:6], 1.8, atol=0.02) and abs(gaps2[6] - 3.6) < 0.02
    assert abs(y2.mean()) < 1e-4  # centred
    # rows per group read back from the gaps
    assert np.sum(np.isclose(gaps2, 3.6, atol=0.02)) + 1 == 2


def test_plant_spacing_without_jitter():
    f, p, _ = _gen(plant_jitter=0.0, d_pp=0.7)
    x = np.asarray(f.plant_pos[0, :, 0])[np.asarray(f.plant_active[0])]
    assert np.allclose(np.diff(x), 0.7, atol=0.02)
    assert len(x) == int(10.0 / 0.7) + 1
    assert x[0] == pytest.approx(-5.0, abs=1e-5)


def test_pear_single_rows():
    f, p, _ = _gen("pear", terrain_length=20.0, row_length=16.0, terrain_width=22.0)
    y, gaps = _measured_rows(f)
    assert np.allclose(gaps, 5.0, atol=0.02) and len(y) == 5


def test_plants_sit_on_terrain():
    f, *_ = _gen(terrain_dh=0.3, slope_x=0.05)
    z = F.terrain_height(f.terrain, f.terrain_size, f.plant_pos[..., 0], f.plant_pos[..., 1])
    assert np.allclose(np.asarray(f.plant_pos[..., 2]), np.asarray(z), atol=1e-5)


def test_terrain_height_interpolates_grid_nodes():
    f, *_ = _gen(terrain_dh=0.3)
    x, y = F.terrain_axes(f.terrain_size, f.terrain.shape)
    X, Y = jnp.meshgrid(x[3:9], y[2:7])
    h = F.terrain_height(f.terrain, f.terrain_size, X, Y)
    assert np.allclose(np.asarray(h), np.asarray(f.terrain[2:7, 3:9]), atol=1e-5)


def test_same_key_same_field_different_key_different_jitter():
    a, *_ = _gen(key=3)
    b, *_ = _gen(key=3)
    c, *_ = _gen(key=4)
    for la, lb in zip(jax.tree.leaves(a), jax.tree.leaves(b), strict=True):
        assert np.array_equal(np.asarray(la), np.asarray(lb))
    assert not np.allclose(np.asarray(a.plant_pos), np.asarray(c.plant_pos))
    assert not np.allclose(np.asarray(a.terrain), np.asarray(c.terrain))


@pytest.mark.parametrize("dh", [0.05, 0.2, 0.3])
def test_terrain_roughness_bound(dh):
    f, *_ = _gen(terrain_dh=dh)
    t = np.asarray(f.terrain)
    ptp = t.max() - t.min()
    assert ptp <= dh + 1e-5
    assert ptp > 0.9 * dh  # not trivially flat
    assert np.std(t) > 0.1 * dh


def test_slope_plane():
    f, *_ = _gen(terrain_dh=0.0, slope_x=0.1, slope_y=-0.05)
    x, y = F.terrain_axes(f.terrain_size, f.terrain.shape)
    expect = 0.1 * x[None, :] - 0.05 * y[:, None]
    assert np.allclose(np.asarray(f.terrain), np.asarray(expect), atol=1e-4)


def test_default_lane_prefers_group_lane_unless_too_narrow():
    f, p, _ = _gen(terrain_width=38.0)
    lane = int(F.robot_lane(f))
    assert float(f.lane_width[lane]) == pytest.approx(1.8, abs=1e-4)  # zucchini: in-group lane
    f, p, _ = _gen("lettuce", terrain_width=12.0)
    lane = int(F.robot_lane(f))
    assert float(f.lane_width[lane]) == pytest.approx(1.4, abs=1e-4)  # lettuce: between groups
    assert bool(f.lane_active[lane])


def test_presets_generate_valid_fields():
    for crop in crops.names():
        p = F.make_params(crop)
        shape = F.preset_shape(crop)
        F.validate(p, shape)
        f = jax.eval_shape(lambda p, k, shape=shape: F.generate(p, shape, k), p, jax.random.key(0))
        assert f.plant_pos.shape == (shape.max_rows, shape.max_plants_per_row, 3)


@pytest.mark.parametrize(
    "override, name",
    [
        (dict(d_rr=-1.0), "d_rr"),
        (dict(d_pp=0.0), "d_pp"),
        (dict(plant_width=2.0), "plant_width"),
        (dict(row_length=100.0), "row_length"),
        (dict(terrain_width=4.0), "terrain_width"),
        (dict(p_missing=1.0), "p_missing"),
        (dict(d_RR=0.95, d_rr=0.95), "robot_lane"),
    ],
)
def test_validate_names_the_parameter(override, name):
    p = F.make_params("zucchini", **{**SMALL, **override})
    shape = F.FieldShape(crop="zucchini", max_rows=16, max_plants_per_row=80,
                         terrain_cells=(32, 32), obstacle_slots=64)
    with pytest.raises(ValueError, match=rf"^{name}:"):
        F.validate(p, shape)
    assert not bool(F.generate(p, shape, jax.random.key(0)).valid)


def test_validate_shape_limits():
    p = F.make_params("zucchini", **SMALL)
    shape = F.fit_shape(p, "zucchini")
    small = F.FieldShape(crop="zucchini", max_rows=shape.max_rows, max_plants_per_row=5,
                         terrain_cells=shape.terrain_cells, obstacle_slots=shape.obstacle_slots)
    with pytest.raises(ValueError, match="^max_plants_per_row:"):
        F.validate(p, small)
    with pytest.raises(ValueError, match="unknown field parameter"):
        F.make_params("zucchini", d_rrr=1.0)


def test_batched_validity_flag_does_not_crash():
    base = F.make_params("zucchini", **SMALL)
    shape = F.FieldShape(crop="zucchini", max_rows=16, max_plants_per_row=80,
                         terrain_cells=(32, 32), obstacle_slots=64)
    params = jax.tree.map(lambda x: jnp.stack([x, x]), base)
    params = params.replace(d_rr=jnp.array([1.8, -1.0]))
    keys = jax.random.split(jax.random.key(0), 2)
    f = jax.vmap(F.generate, in_axes=(0, None, 0))(params, shape, keys)
    assert np.asarray(f.valid).tolist() == [True, False]
    with pytest.raises(ValueError, match=r"^d_rr: .*batch index 1"):
        F.validate(params, shape)


def test_traced_parameter_change_does_not_retrace():
    traces = []

    def gen(p, k):
        traces.append(1)
        return F.generate(p, shape, k).plant_pos

    p = F.make_params("zucchini", **SMALL)
    shape = F.fit_shape(F.make_params("zucchini", **{**SMALL, "d_rr": 1.2}), "zucchini")
    g = jax.jit(gen)
    a = g(p, jax.random.key(0))
    b = g(p.replace(d_rr=jnp.asarray(1.2, jnp.float32), terrain_dh=jnp.asarray(0.1, jnp.float32)),
          jax.random.key(0))
    assert len(traces) == 1
    assert not np.allclose(np.asarray(a), np.asarray(b))


# ---------------------------------------------------------------------------------------------
# Curved rows: the field frame (mjxrow.field.lanes)

BENDS = [dict(curvature=0.04, amplitude=0.0), dict(curvature=-0.02, amplitude=0.0),
         dict(curvature=0.0, amplitude=0.6), dict(curvature=0.015, amplitude=0.4)]


def _bend(curvature, amplitude, wavelength=9.0, phase=0.7):
    f = lambda v: jnp.float32(v)  # noqa: E731
    return F.lanes.Bend(curvature=f(curvature), amplitude=f(amplitude), wavelength=f(wavelength),
                        phase=f(phase))


@pytest.mark.parametrize("kw", BENDS)
def test_field_frame_round_trip_and_direction(kw):
    b = _bend(**kw)
    s, u = jnp.meshgrid(jnp.linspace(-20.0, 20.0, 9), jnp.linspace(-8.0, 8.0, 7))
    x, y = F.lanes.to_world(b, s, u)
    s2, u2 = F.lanes.to_field(b, x, y)
    np.testing.assert_allclose(s2, s, atol=2e-5 * 20)
    np.testing.assert_allclose(u2, u, atol=2e-5 * 20)
    # the direction is the tangent of the curve u = const (finite differences)
    h = 1e-2
    xa, ya = F.lanes.to_world(b, s - h, u)
    xb, yb = F.lanes.to_world(b, s + h, u)
    np.testing.assert_allclose(F.lanes.heading(b, s, u), jnp.arctan2(yb - ya, xb - xa), atol=2e-3)


def test_arcs_keep_the_row_spacing_and_sines_the_shift():
    arc = _bend(0.05, 0.0)
    s = jnp.linspace(-15.0, 15.0, 31)
    p0 = jnp.stack(F.lanes.to_world(arc, s, 0.0), -1)
    p1 = jnp.stack(F.lanes.to_world(arc, s, 1.8), -1)
    np.testing.assert_allclose(jnp.linalg.norm(p1 - p0, axis=-1), 1.8, atol=1e-4)  # radial
    sine = _bend(0.0, 0.5)
    x, y = F.lanes.to_world(sine, s, 2.0)
    np.testing.assert_array_equal(x, s)
    np.testing.assert_allclose(y - 2.0, 0.5 * jnp.sin(2 * jnp.pi * s / 9.0 + 0.7), atol=1e-5)


def test_a_straight_frame_is_the_identity_to_the_bit():
    b = _bend(0.0, 0.0)
    s = jnp.linspace(-25.0, 25.0, 101, dtype=jnp.float32)
    u = jnp.linspace(-9.0, 9.0, 101, dtype=jnp.float32)
    x, y = F.lanes.to_world(b, s, u)
    np.testing.assert_array_equal(x, s)
    np.testing.assert_array_equal(y, u)
    np.testing.assert_array_equal(F.lanes.to_field(b, x, y)[0], s)
    np.testing.assert_array_equal(F.lanes.heading(b, s, u), 0.0)


@pytest.mark.parametrize("kw", BENDS)
def test_project_measures_the_offset_across_the_line(kw):
    ln = F.lanes.Lane(u=jnp.float32(1.0), s_end=jnp.float32(20.0), bend=_bend(**kw))
    s = jnp.linspace(-10.0, 10.0, 11)
    on = F.lanes.point(ln, s)
    d = F.lanes.heading(ln.bend, s, ln.u)
    left = jnp.stack([-jnp.sin(d), jnp.cos(d)], -1)
    s0, off0, d0 = F.lanes.project(ln, on)
    np.testing.assert_allclose(s0, s, atol=1e-4)
    np.testing.assert_allclose(off0, 0.0, atol=1e-4)
    np.testing.assert_allclose(d0, d, atol=1e-5)
    # 0.3 m to the left, perpendicular to the line (on a sinusoid s is x: it moves with the
    # point, and the offset is good to first order in the line's curvature)
    _, off, _ = F.lanes.project(ln, on + 0.3 * left)
    np.testing.assert_allclose(off, 0.3, atol=5e-3)
    np.testing.assert_allclose(F.lanes.goal(ln), F.lanes.point(ln, 20.0), atol=1e-6)


def test_new_parameters_at_zero_give_the_same_field():
    shape = F.preset_shape("zucchini")
    key = jax.random.key(4)
    base = F.generate(F.make_params("zucchini"), shape, key)
    zero = F.generate(F.make_params("zucchini", row_amplitude=0.0, row_curvature=0.0,
                                    gap_rate=0.0, weed_density=0.0, row_wavelength=3.0,
                                    gap_length=2.5, weed_size=0.2), shape, key)
    for name in ("plant_pos", "plant_size", "plant_yaw", "plant_active", "obst_pos", "terrain"):
        np.testing.assert_array_equal(getattr(zero, name), getattr(base, name), err_msg=name)


@pytest.mark.parametrize("override, key", [
    (dict(row_curvature=0.2), "row_curvature"),  # radius 5 m: rows cross
    (dict(row_amplitude=0.3, row_wavelength=0.5), "row_wavelength"),  # below d_pp = 0.7 m
    (dict(weed_density=1.0, weed_size=1.2), "weed_size"),  # wider than the 0.9 m free lane
    (dict(gap_rate=5.0, gap_length=2.5), "gap_length"),  # gaps would cover the row
])
def test_impossible_curves_gaps_and_weeds_name_the_key(override, key):
    params = F.make_params("zucchini", host=True, **override)
    shape = F.fit_shape(params, "zucchini")
    with pytest.raises(ValueError, match=f"^{key}: "):
        F.validate(params, shape)


def test_gap_runs_have_the_configured_rate_and_length():
    q = dict(d_pp=jnp.float32(0.5), gap_length=jnp.float32(2.0), gap_rate=jnp.float32(1.5))
    gap = np.asarray(F.gap_runs(q, (64, 2000), jax.random.key(0)))  # 64 rows of 1 km
    starts = gap[:, 1:] & ~gap[:, :-1]
    runs = gap.sum() / max(starts.sum() + gap[:, 0].sum(), 1)
    assert abs(runs * 0.5 - 2.0) < 0.1, runs * 0.5
    rate = (starts.sum() + gap[:, 0].sum()) / (64 * 2000 * 0.5) * 10.0
    assert abs(rate - 1.5) < 0.1, rate
    none = F.gap_runs(dict(q, gap_rate=jnp.float32(0.0)), (4, 100), jax.random.key(0))
    assert not np.asarray(none).any()
