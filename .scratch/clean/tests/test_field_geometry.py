"""The geometry of curved rows, gap runs and weeds, read back from the exported CSVs alone
(`worlds.export.write_tables`): a sinusoid and an arc fitted to each row's plants match the
parameters, lane centre lines lie midway between their rows, gap runs and weeds have their
configured rates, zero values of the new parameters give the old field to the bit, and bad
values are refused by the worlds CLI."""

import hashlib

import jax
import jax.numpy as jnp
import numpy as np
import pandas as pd
import pytest
from scipy import optimize

from mjxrow import field as F
from mjxrow.worlds import cli as worlds_cli
from mjxrow.worlds import export as Wd

D_RR = 1.8  # zucchini's row-to-row distance inside a group [m]
# plants on their curves (0.5 mm jitter, none missing), no obstacles: the rows' shape alone
CLEAN = dict(plant_jitter=0.0005, p_missing=0.0, stone_density=0.0, branch_density=0.0,
             terrain_dh=0.05, rows_per_group=3, terrain_width=8.0)
SINE = dict(CLEAN, terrain_length=18.0, row_length=16.0, row_amplitude=0.25, row_wavelength=8.0)
ARC = dict(CLEAN, terrain_length=12.0, row_length=10.0, row_curvature=0.05)
# one static shape for every field of this file (one compile): room for GAPS' rows and weeds
SHAPE = F.FieldShape(crop="zucchini", max_rows=16, max_plants_per_row=408,
                     terrain_cells=(48, 104), obstacle_slots=8, weed_slots=960)
OLD = dict(terrain_length=12.0, row_length=10.0, terrain_width=8.0, rows_per_group=3)
# sha256 of the plants CSV (the columns it had then) of OLD, seed 7, on SHAPE (without
# weed_slots), written by the generator and exporter of commit d3e6c3d, before curved rows,
# gaps and weeds existed
OLD_COLUMNS = ["row", "index", "x", "y", "z", "kind", "length", "width", "height", "yaw"]
OLD_SHA256 = "6f769d32ab761407cb4388911a185db270b0437795ef2d6ebb7038238f2277b1"
# gap runs and weeds: 9 straight rows of 100 m, a plant slot every 0.25 m
GAPS = dict(plant_jitter=0.002, p_missing=0.0, stone_density=0.0, branch_density=0.0,
            terrain_dh=0.05, terrain_length=102.0, row_length=100.0, terrain_width=12.0,
            rows_per_group=1, d_RR=1.2, d_pp=0.25, plant_width=0.3, plant_length=0.3,
            gap_rate=3.0, gap_length=1.0, weed_density=1.0)

_generate = jax.jit(F.generate, static_argnums=1)


def _tables(tmp_path, overrides, seed=0) -> dict[str, pd.DataFrame]:
    """The CSVs of one zucchini field on SHAPE, as written by the export and read back."""
    params = F.make_params("zucchini", host=True, **overrides)
    F.validate(params, SHAPE)
    fld = _generate(jax.tree.map(jnp.asarray, params), SHAPE, jax.random.key(seed))
    paths = Wd.write_tables(fld, SHAPE, tmp_path, "f")
    return {k: pd.read_csv(p) for k, p in paths.items()}


def _rows(plants: pd.DataFrame) -> list[np.ndarray]:
    """[n, 2] (x, y) of each row's plants, rows in the CSV's order, plants by slot."""
    return [g.sort_values("index")[["x", "y"]].to_numpy() for _, g in plants.groupby("row")]


def _fit_sine(xy: np.ndarray) -> np.ndarray:
    """(c, A, λ, φ) of y = c + A·sin(2πx/λ + φ) through the points: the best λ of a grid by
    linear least squares, then all four refined."""
    x, y = xy.T

    def linear(lam):
        basis = np.stack([np.ones_like(x), np.sin(2 * np.pi * x / lam),
                          np.cos(2 * np.pi * x / lam)], 1)
        coef, res, *_ = np.linalg.lstsq(basis, y, rcond=None)
        return coef, float(np.sum((basis @ coef - y) ** 2))

    lam = min(np.geomspace(2.0, 40.0, 400), key=lambda v: linear(v)[1])
    (c, a, b), _ = linear(lam)
    p0 = [c, np.hypot(a, b), lam, np.arctan2(b, a)]
    fit = optimize.least_squares(
        lambda p: p[0] + p[1] * np.sin(2 * np.pi * x / p[2] + p[3]) - y, p0)
    c, amp, lam, phi = fit.x
    if amp < 0:
        amp, phi = -amp, phi + np.pi
    return np.array([c, amp, lam, np.mod(phi, 2 * np.pi)])


def _fit_circle(xy: np.ndarray) -> tuple[np.ndarray, float]:
    """(centre [2], radius) of the circle through the points (algebraic fit, then refined)."""
    x, y = xy.T
    a = np.stack([x, y, np.ones_like(x)], 1)
    (p, q, r), *_ = np.linalg.lstsq(a, x * x + y * y, rcond=None)
    c0 = np.array([p / 2, q / 2])
    fit = optimize.least_squares(lambda v: np.hypot(x - v[0], y - v[1]) - v[2],
                                 [*c0, np.sqrt(r + c0 @ c0)])
    return fit.x[:2], float(fit.x[2])


def _lane_points(polyline: pd.DataFrame) -> list[np.ndarray]:
    """[n, 2] (x, y) of each lane's centre line, lanes in order, points along s."""
    out = []
    for _, g in polyline.groupby("lane"):
        assert (np.diff(g["point"]) == 1).all() and (np.diff(g["s"]) > 0).all()
        out.append(g[["x", "y"]].to_numpy())
    return out


def test_sine_rows_match_the_parameters(tmp_path):
    t = _tables(tmp_path, SINE)
    rows = _rows(t["plants"])
    assert len(rows) == 3
    fits = np.array([_fit_sine(xy) for xy in rows])
    c, amp, lam, phi = fits.T
    np.testing.assert_allclose(amp, SINE["row_amplitude"], atol=0.02)
    np.testing.assert_allclose(lam, SINE["row_wavelength"], rtol=0.02)
    # one curve shifted across: the same phase in every row, d_rr apart along y
    assert np.ptp(np.angle(np.exp(1j * (phi - phi[0])))) < 0.02
    np.testing.assert_allclose(np.diff(c), D_RR, atol=0.005)
    # lanes: the centre line midway between its rows, measured from each of its points to the
    # nearest point of each row's fitted curve (the rows' sinusoids only shift across, so the
    # two distances differ by under 2 mm at this amplitude and wavelength)
    xs = np.arange(-12.0, 12.0, 0.001)
    curves = [np.stack([xs, ci + ai * np.sin(2 * np.pi * xs / li + pi)], 1)
              for ci, ai, li, pi in fits]
    lanes = _lane_points(t["lanes_polyline"])
    assert len(lanes) == 2
    step = np.diff(t["lanes_polyline"].groupby("lane")["s"].apply(np.asarray).iloc[0])
    assert step.max() <= min(Wd.POLYLINE_STEP, SINE["row_wavelength"] / 32) + 1e-4
    for i, pts in enumerate(lanes):
        d = [np.min(np.linalg.norm(pts[:, None] - curve[None, ::5], axis=-1), 1)
             for curve in curves[i:i + 2]]
        np.testing.assert_allclose(d[0], d[1], atol=0.004)
        np.testing.assert_allclose(d[0], 0.5 * D_RR, atol=0.5 * D_RR * 0.1)
    # the lanes CSV: each lane's ends are its polyline's, and its goal on the same curve
    lanes_t = t["lanes"]
    for i, pts in enumerate(lanes):
        row = lanes_t[lanes_t["lane"] == i].iloc[0]
        np.testing.assert_allclose(pts[0], row[["x_start", "y_start"]], atol=2e-4)
        np.testing.assert_allclose(pts[-1], row[["x_end", "y_end"]], atol=2e-4)


def test_arc_rows_are_concentric_with_the_curvature(tmp_path):
    t = _tables(tmp_path, ARC)
    rows = _rows(t["plants"])
    assert len(rows) == 3
    kappa = ARC["row_curvature"]
    # each row alone: a circle about (0, 1/κ) (the rows bend towards +y); the middle row,
    # through the field's centre, has the curvature of the parameter
    centres, radii = zip(*(_fit_circle(xy) for xy in rows), strict=True)
    np.testing.assert_allclose(centres, [[0.0, 1.0 / kappa]] * 3, atol=0.03)
    np.testing.assert_allclose(1.0 / radii[1], kappa, rtol=0.01)
    # all rows about one centre: they fit to the millimetre, each d_rr inside the one before
    pts = np.concatenate(rows)
    which = np.concatenate([np.full(len(xy), i) for i, xy in enumerate(rows)])
    fit = optimize.least_squares(
        lambda v: np.hypot(pts[:, 0] - v[0], pts[:, 1] - v[1]) - v[2:][which],
        [*np.mean(centres, 0), *radii])
    centre, radii = fit.x[:2], fit.x[2:]
    assert np.max(np.abs(fit.fun)) < 0.002
    np.testing.assert_allclose(-np.diff(radii), D_RR, atol=0.003)
    # lanes: on the arc midway between their rows
    for i, pts in enumerate(_lane_points(t["lanes_polyline"])):
        d = [np.abs(np.linalg.norm(pts - centre, axis=1) - radii[j]) for j in (i, i + 1)]
        np.testing.assert_allclose(d[0], d[1], atol=0.004)
        np.testing.assert_allclose(d[0], 0.5 * D_RR, atol=0.004)
    # every lane turns by κ per metre of s (the angle the arcs sweep)
    lanes = t["lanes"]
    np.testing.assert_allclose(lanes["heading_end"] - lanes["heading_start"],
                               kappa * (lanes["s_end"] - lanes["s_start"]), atol=2e-4)


def test_gap_runs_and_weeds_have_their_rates(tmp_path):
    t = _tables(tmp_path, GAPS)
    plants, lanes, weeds = t["plants"], t["lanes"], t["weeds"]
    # the plant spacing from the plants, the slots of a row from its ends
    steps = [np.diff(g.sort_values("index")[["x", "index"]].to_numpy(), axis=0)
             for _, g in plants.groupby("row")]
    d_pp = float(np.median(np.concatenate([s[:, 0] / s[:, 1] for s in steps])))
    assert abs(d_pp - GAPS["d_pp"]) < 1e-3
    n_slots = int(round((lanes["x_end"][0] - lanes["x_start"][0]) / d_pp)) + 1
    runs = []
    for _, g in plants.groupby("row"):
        missing = np.ones(n_slots, bool)
        missing[g["index"].to_numpy()] = False
        edges = np.diff(np.r_[0, missing.astype(int), 0])
        runs += list(np.flatnonzero(edges == -1) - np.flatnonzero(edges == 1))
    n_rows = plants["row"].nunique()
    assert n_rows == 9 and len(runs) > 200
    mean_length = np.mean(runs) * d_pp
    rate = len(runs) / (n_rows * n_slots * d_pp) * 10.0
    assert abs(mean_length / GAPS["gap_length"] - 1) < 0.2, mean_length
    assert abs(rate / GAPS["gap_rate"] - 1) < 0.2, rate
    # weeds: per m² over the ground from the first row to the last, along the rows
    y_rows = plants.groupby("row")["y"].median().to_numpy()
    x0, x1 = lanes["x_start"][0], lanes["x_end"][0]
    inside = weeds["x"].between(x0, x1) & weeds["y"].between(y_rows[0], y_rows[-1])
    area = (x1 - x0) * (y_rows[-1] - y_rows[0])
    assert abs(inside.sum() / area / GAPS["weed_density"] - 1) < 0.1
    assert inside.mean() > 0.95  # they lie there, not beyond the rows
    np.testing.assert_allclose(weeds["diameter"].mean(), F.make_params("zucchini").weed_size,
                               rtol=0.05)
    np.testing.assert_allclose(weeds["height"], 0.35 * weeds["diameter"], atol=2e-4)


def test_zero_values_give_the_old_field(tmp_path):
    """The new parameters at zero (their preset values, and zeros with other wavelengths,
    gap lengths and weed sizes) give, seed for seed, the plants CSV of the generator before
    they existed."""
    base = _tables(tmp_path / "a", OLD, seed=7)["plants"]
    zeros = _tables(tmp_path / "b", dict(OLD, row_amplitude=0.0, row_wavelength=3.0,
                                          row_curvature=0.0, gap_rate=0.0, gap_length=4.0,
                                          weed_density=0.0, weed_size=0.5), seed=7)
    pd.testing.assert_frame_equal(base, zeros["plants"], check_exact=True)
    assert (base["heading"] == 0).all() and len(zeros["weeds"]) == 0
    text = base[OLD_COLUMNS].to_csv(index=False, float_format="%.4f")
    assert hashlib.sha256(text.encode()).hexdigest() == OLD_SHA256
    lanes = zeros["lanes"]
    np.testing.assert_array_equal(lanes["y_start"], lanes["y"])
    np.testing.assert_array_equal(lanes["y_end"], lanes["y"])
    np.testing.assert_array_equal(lanes["x_start"], lanes["s_start"])
    assert (lanes[["heading_start", "heading_end"]] == 0).all().all()


@pytest.mark.parametrize("sets, key", [
    (["field.row_curvature=1.0"], "field.row_curvature"),  # rows cross near the centre
    (["field.row_amplitude=0.1", "field.row_wavelength=0.1"], "field.row_wavelength"),
    (["field.weed_density=1", "field.weed_size=2"], "field.weed_size"),  # wider than the lane
])
def test_cli_refuses_impossible_rows_and_weeds(tmp_path, capsys, sets, key):
    out = tmp_path / "w"
    args = [a for s in sets for a in ("--set", s)]
    assert worlds_cli.main(["--preset", "lettuce", "--gazebo", "none", "--out", str(out),
                            *args]) == 2
    err = capsys.readouterr().err
    assert key in err and len(err.strip().splitlines()) == 1, err
    assert not out.exists()
