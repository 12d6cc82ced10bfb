"""The dataset's scenes: random fields around a crop's preset and camera poses in them (pure,
jittable; `mjxrow.seg.synthesis` renders them).

Fields (`random_params`): the preset's geometry, terrain and obstacle numbers varied by factor
and absolute ranges, and with `variety="fields"` (the default) also
- curved rows: a sinusoid (`row_amplitude`, `row_wavelength`) in 45 % of the fields and
  concentric arcs (`row_curvature`) in 45 %, independently (30 % straight, 20 % both),
- gap runs (`gap_rate`, `gap_length`) in half of them,
- weeds (`weed_density`, `weed_size`) in half of them (a third to a half of the images
  show some, by crop),
each drawn inside what `mjxrow.field.checks` allows, so every field is valid, and with at most
`dataset_shape(crop, variety).weed_slots` weeds. `variety="none"` draws the fields the dataset
had before curved rows, gaps and weeds existed, number for number.

Camera poses (`sample_pose`): the robot's view down a lane mostly — a random lane (lanes the
robot fits in four times out of five), a lateral offset inside the lane's free width, anywhere
along the row from 3 m before its start to 1 m past its end, on the lane's centre line
(`mjxrow.field.lanes`: it follows curved rows) and heading along it or back, with a few
degrees of yaw noise, height 0.30-0.65 m and pitch about −10°; one sample in six looks from
higher (0.65-1.5 m) and steeper, one in ten turns to any heading.
"""

from __future__ import annotations

import jax
import jax.numpy as jnp
import numpy as np

from mjxrow import crops
from mjxrow import field as mjxrow_field
from mjxrow import render as mjxrow_render
from mjxrow.field import lanes as field_lanes
from mjxrow.field import params as field_params
from mjxrow.seg import synth as synth_cli

VARIETIES = synth_cli.VARIETIES  # ("fields", "none"): with or without the new field variety

# field variation around the preset: factor ranges, then absolute ranges
_FACTORS = {"d_rr": (0.92, 1.12), "d_RR": (0.92, 1.15), "d_pp": (0.85, 1.2),
            "plant_length": (0.8, 1.2), "plant_width": (0.8, 1.15), "plant_height": (0.75, 1.25),
            "terrain_dh": (0.3, 1.5), "terrain_scale": (0.6, 1.6), "plant_jitter": (0.5, 2.0),
            "stone_density": (0.0, 2.0), "branch_density": (0.0, 2.0)}
_ABSOLUTE = {"p_missing": (0.0, 0.08), "plant_size_var": (0.04, 0.14),
             "slope_x": (-0.03, 0.03), "slope_y": (-0.03, 0.03)}
_MORE_WITH_LESS = ("d_rr", "d_RR", "d_pp")  # counts grow as these shrink

# the variety (world metres): shares of the fields with each feature and the ranges drawn
P_SINE, P_ARC, P_GAPS, P_WEEDS = 0.45, 0.45, 0.5, 0.5
WAVELENGTH = (10.0, 40.0)  # λ of the sinusoid [m]
SINE_SLOPE = (0.05, 0.35)  # steepest slope 2πA/λ of the sinusoid [-] (A up to 2.2 m)
ARC_TURN = (0.2, 1.4)  # the arcs' turn over the rows' length [rad] (radius 36-250 m at 50 m)
GAP_RATE = (0.3, 2.0)  # gaps per 10 m of row
GAP_PLANTS = (1.0, 4.0)  # mean gap length in plant spacings
WEED_DENSITY = (0.2, 3.0)  # weeds per m²
WEED_SIZE = (0.05, 0.30)  # nominal weed diameter [m], at most 80 % of the narrowest lane
MARGIN = 0.9  # the curvature stays this far inside the limits of its check


def _extremes(crop: str, variety: str) -> mjxrow_field.FieldParams:
    """Params at the far end of every range, the one that needs the most room."""
    pre = crops.get(crop).preset
    ext = {k: pre[k] * (lo if k in _MORE_WITH_LESS else hi) for k, (lo, hi) in _FACTORS.items()}
    if variety == "fields":
        s = pre["scale"]
        ext.update(row_amplitude=SINE_SLOPE[1] * WAVELENGTH[1] / (2 * np.pi) / s,
                   row_wavelength=WAVELENGTH[1] / s,
                   row_curvature=ARC_TURN[1] / pre["row_length"],  # κ·scale, as the params hold it
                   weed_density=WEED_DENSITY[1])
    return mjxrow_field.make_params(crop, host=True, **ext)


def dataset_shape(crop: str, variety: str = "fields") -> mjxrow_field.FieldShape:
    """Static shape that holds every field the sampler can draw for `crop` (weed_slots: the
    largest weed density over the largest rows' area)."""
    if variety not in VARIETIES:
        raise ValueError(f"variety: {variety!r} is not one of {VARIETIES}")
    return mjxrow_field.fit_shape(_extremes(crop, variety), crop)


def _uniform(key: jax.Array, lo_hi: tuple[float, float]) -> jax.Array:
    return jax.random.uniform(key, (), minval=lo_hi[0], maxval=lo_hi[1])


def draw_variety(base: mjxrow_field.FieldParams, weed_slots: int, key: jax.Array) -> dict:
    """Curvature, gap and weed params (name → float32 []) for a field of params `base` (the
    preset with its geometry drawn), inside the limits of `field.checks` for it and with at
    most `weed_slots` weeds."""
    q = field_params._scaled(base)
    lay = field_params._layout(q)
    s = base.scale
    ks = jax.random.split(key, 12)
    zero = jnp.zeros((), jnp.float32)
    # the sinusoid: its steepest slope bounds how much it narrows the lanes (cos atan slope)
    sine = jax.random.uniform(ks[0]) < P_SINE
    wavelength = _uniform(ks[1], WAVELENGTH)
    amplitude = jnp.where(sine, _uniform(ks[2], SINE_SLOPE) * wavelength / (2 * jnp.pi), zero)
    # the arcs: a turn over the rows' length, kept inside both limits of the check
    arc = jax.random.uniform(ks[3]) < P_ARC
    kappa = _uniform(ks[4], ARC_TURN) / q["row_length"]
    reach = 0.5 * lay["span"] + amplitude + q["plant_width"]
    kappa = jnp.minimum(kappa, MARGIN * jnp.minimum(1.0 / reach,
                                                    np.pi / q["terrain_length"]))
    sign = jnp.where(jax.random.uniform(ks[5]) < 0.5, -1.0, 1.0)
    curvature = jnp.where(arc, sign * kappa, zero)
    # gap runs: at most half the row in gaps on average
    gaps = jax.random.uniform(ks[6]) < P_GAPS
    gap_length = _uniform(ks[7], GAP_PLANTS) * q["d_pp"]
    gap_rate = jnp.where(gaps, jnp.minimum(_uniform(ks[8], GAP_RATE), 5.0 / gap_length), zero)
    # weeds: narrower than the narrowest lane between the plants, no more than the slots
    squeeze = jnp.cos(jnp.arctan(2 * jnp.pi * amplitude / wavelength))
    free_in = q["d_rr"] * squeeze - q["plant_width"]
    free_between = q["d_RR"] * squeeze - q["plant_width"]
    narrowest = jnp.where(q["rows_per_group"] > 1, jnp.minimum(free_in, free_between),
                          free_between)
    size = jnp.minimum(_uniform(ks[9], WEED_SIZE), 0.8 * narrowest)
    weedy = (jax.random.uniform(ks[10]) < P_WEEDS) & (size >= 0.02) & (weed_slots > 0)
    area = jnp.maximum(q["row_length"] * lay["span"], 1e-6)
    density = jnp.minimum(_uniform(ks[11], WEED_DENSITY), weed_slots / area)
    return dict(row_amplitude=amplitude / s, row_wavelength=wavelength / s,
                row_curvature=curvature * s, gap_rate=gap_rate, gap_length=gap_length / s,
                weed_density=jnp.where(weedy, density, zero),
                weed_size=jnp.where(weedy, size / s, base.weed_size))


def random_params(crop: str, key: jax.Array,
                  variety: str = "fields") -> mjxrow_field.FieldParams:
    """The crop's preset with geometry, terrain and obstacle numbers drawn around it, and
    (variety "fields") curved rows, gap runs and weeds (the module's docstring)."""
    shape = dataset_shape(crop, variety)  # also checks `variety`
    pre = crops.get(crop).preset
    ks = jax.random.split(key, len(_FACTORS) + len(_ABSOLUTE))
    vals = {}
    for kk, (name, (lo, hi)) in zip(ks, _FACTORS.items(), strict=False):
        vals[name] = pre[name] * jax.random.uniform(kk, (), minval=lo, maxval=hi)
    for kk, (name, (lo, hi)) in zip(ks[len(_FACTORS):], _ABSOLUTE.items(), strict=True):
        vals[name] = jax.random.uniform(kk, (), minval=lo, maxval=hi)
    base = mjxrow_field.make_params(crop, **vals)
    if variety == "none":
        return base
    # fold_in: the draws above stay those of variety "none"
    return base.replace(**draw_variety(base, shape.weed_slots, jax.random.fold_in(key, 7)))


def sample_pose(
    field: mjxrow_field.Field, key: jax.Array
) -> tuple[jax.Array, jax.Array, jax.Array]:
    """A camera pose in `field`: (cam_pos float32 [3], cam_rot float32 [3, 3],
    meta float32 [6] = x, y, z [m], yaw, pitch [rad], lateral offset from the lane centre [m]
    (across the rows, in the field frame's u))."""
    ks = jax.random.split(key, 10)
    q = field_params._scaled(field.params)
    free = field.lane_width - q["plant_width"]
    fits = field.lane_active & (free >= mjxrow_field.ROBOT_WIDTH + mjxrow_field.LANE_CLEARANCE)
    robot_lanes = jnp.any(fits)
    pick_fit = (jax.random.uniform(ks[0]) < 0.8) & robot_lanes
    pool = jnp.where(pick_fit, fits, field.lane_active)
    logits = jnp.where(pool, 0.0, -jnp.inf)
    index = jax.random.categorical(ks[1], logits)
    ln = field_lanes.lane(field, index)
    half_free = 0.5 * jnp.maximum(free[index], 0.05)
    lateral = jax.random.uniform(ks[2], (), minval=-0.6, maxval=0.6) * half_free
    s = jax.random.uniform(ks[3], (), minval=field.row_x[0] - 3.0, maxval=field.row_x[1] + 1.0)
    u = ln.u + lateral
    x, y = field_lanes.to_world(ln.bend, s, u)
    along = field_lanes.heading(ln.bend, s, u)
    backward = jax.random.uniform(ks[4]) < 0.5
    yaw = along + jnp.where(backward, jnp.pi, 0.0) + jnp.deg2rad(6.0) * jax.random.normal(ks[5])
    any_heading = jax.random.uniform(ks[6]) < 0.1
    yaw = jnp.where(any_heading, jax.random.uniform(ks[7], (), maxval=2 * jnp.pi), yaw)
    high = jax.random.uniform(ks[8]) < 1.0 / 6.0
    kh, kp = jax.random.split(ks[9])
    h_low = jax.random.uniform(kh, (), minval=0.30, maxval=0.65)
    h_high = jax.random.uniform(kh, (), minval=0.65, maxval=1.5)
    height = jnp.where(high, h_high, h_low)
    p_low = jnp.deg2rad(jnp.clip(-10.0 + 5.0 * jax.random.normal(kp), -25.0, 3.0))
    p_high = jnp.deg2rad(jax.random.uniform(kp, (), minval=-35.0, maxval=-12.0))
    pitch = jnp.where(high, p_high, p_low)
    z = mjxrow_field.terrain_height(field.terrain, field.terrain_size, x, y) + height
    pos = jnp.stack([x, y, z]).astype(jnp.float32)
    meta = jnp.stack([x, y, z, jnp.mod(yaw + jnp.pi, 2 * jnp.pi) - jnp.pi, pitch, lateral])
    return pos, mjxrow_render.camera_rot(yaw, pitch), meta.astype(jnp.float32)
