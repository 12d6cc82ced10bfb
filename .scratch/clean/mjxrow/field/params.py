"""Parametric row-crop fields: `FieldParams` (traced), `FieldShape` (static), `generate`.

Conventions: metres, z up, rows run along +x, the lateral axis is y, the field is centred at
the origin. Rows are laid in groups: inside a group rows are `d_rr` apart, consecutive groups
`d_RR` apart (from the last row of one group to the first row of the next); the number of
groups follows from the terrain width. Rows are indexed 0..R-1 by increasing y; lane `i` is the
strip between rows `i` and `i + 1`.
"""

from __future__ import annotations

import dataclasses
import math
from typing import Any

import jax
import jax.numpy as jnp
import numpy as np
from flax import struct

from mjxrow import crops

ROBOT_WIDTH = 0.430  # m, lateral footprint of the UGV (robot.py holds the rest)
LANE_CLEARANCE = 0.10  # m, free width a lane needs beyond the robot's width
HEADLAND = 1.0  # m, minimum border between the outermost rows and the terrain edge
N_TERRAIN_MODES = 48  # sinusoids summed for the terrain roughness


@struct.dataclass
class FieldParams:
    """Numbers that describe one field. Every one is a `jax.Array` (scalar per field, or [B]
    when batched), so sweeping any of them never recompiles."""

    d_rr: jax.Array  # row-to-row distance inside a group [m]
    d_RR: jax.Array  # distance between the facing rows of two consecutive groups [m]
    d_pp: jax.Array  # plant-to-plant distance along a row [m]
    rows_per_group: jax.Array  # rows in one group [count, integral value]
    row_length: jax.Array  # length of every row along x [m]
    terrain_length: jax.Array  # terrain extent along x [m]
    terrain_width: jax.Array  # terrain extent along y [m]
    plant_length: jax.Array  # nominal plant extent along the row (x) [m]
    plant_width: jax.Array  # nominal plant extent across the row (y) [m]
    plant_height: jax.Array  # nominal plant height [m]
    plant_size_var: jax.Array  # relative std of each plant's size [-]
    plant_jitter: jax.Array  # std of each plant's position around its nominal place [m]
    p_missing: jax.Array  # probability that a plant is missing [-]
    terrain_dh: jax.Array  # terrain irregularity |ΔH|: peak-to-peak height of the roughness [m]
    terrain_scale: jax.Array  # horizontal scale (wavelength) of the roughness [m]
    slope_x: jax.Array  # longitudinal slope dz/dx [-]
    slope_y: jax.Array  # lateral slope dz/dy [-]
    stone_density: jax.Array  # stones per 100 m² of lane [count / 100 m²]
    branch_density: jax.Array  # fallen branches per 100 m² of lane [count / 100 m²]
    scale: jax.Array  # global factor on every length of the field [-]
    row_amplitude: jax.Array  # amplitude A of the rows' common sinusoid [m] (0: straight)
    row_wavelength: jax.Array  # wavelength λ of the rows' sinusoid [m]
    row_curvature: jax.Array  # curvature κ of the rows bent as concentric arcs [1/m] (0: straight)
    gap_rate: jax.Array  # runs of missing plants (gaps) per 10 m of row [count / 10 m]
    gap_length: jax.Array  # mean length of a gap, a run of missing plants [m]
    weed_density: jax.Array  # weeds per m² of ground between and inside the rows [count / m²]
    weed_size: jax.Array  # nominal weed diameter [m]


PARAM_NAMES: tuple[str, ...] = tuple(f.name for f in dataclasses.fields(FieldParams))


@dataclasses.dataclass(frozen=True)
class FieldShape:
    """Static description that fixes array shapes: one compile per distinct value. `crop`: a
    registered crop's name (`mjxrow.crops.names()`), which fixes the plants' primitives."""

    crop: str = "zucchini"
    max_rows: int = 16
    max_plants_per_row: int = 80
    terrain_cells: tuple[int, int] = (160, 256)  # (ny, nx) height samples
    obstacle_slots: int = 32
    weed_slots: int = 0  # weeds a field can hold (0: no weeds)

    def __post_init__(self):
        crops.get(self.crop)  # ValueError naming an unknown crop
        for name in ("max_rows", "max_plants_per_row", "obstacle_slots"):
            if int(getattr(self, name)) < (2 if name == "max_rows" else 1):
                raise ValueError(f"{name}: must be a positive count, got {getattr(self, name)}")
        if int(self.weed_slots) < 0:
            raise ValueError(f"weed_slots: must be a count (≥ 0), got {self.weed_slots}")
        ny, nx = self.terrain_cells
        if ny < 2 or nx < 2:
            raise ValueError(f"terrain_cells: need at least 2×2 samples, got {self.terrain_cells}")


@struct.dataclass
class Field:
    """One generated field (add a leading [B] axis to every array for a batch).

    R = shape.max_rows, P = shape.max_plants_per_row, S = shape.obstacle_slots,
    W = shape.weed_slots, (NY, NX) = shape.terrain_cells. Rows, lanes and `row_x` are in field
    coordinates (s along the rows, u across them: `mjxrow.field.lanes`; x and y of a straight
    field); plants, obstacles, weeds and the terrain in world coordinates.
    """

    params: FieldParams
    plant_pos: jax.Array  # float32 [R, P, 3], plant base centre on the terrain surface [m]
    plant_size: jax.Array  # float32 [R, P, 3], (length along the row, width, height) [m]
    plant_yaw: jax.Array  # float32 [R, P], turn of the plant's leaves about z [rad]
    plant_heading: jax.Array  # float32 [R, P], direction of the row at the plant [rad] (the
    # plant's length axis; 0 on straight rows)
    plant_phase: jax.Array  # float32 [R, P], per-plant random number in [0, 1) for its shape
    plant_active: jax.Array  # bool [R, P]
    plant_row: jax.Array  # int32 [R, P], row index of each plant
    row_y: jax.Array  # float32 [R], lateral position (u) of each row [m]
    row_active: jax.Array  # bool [R]
    row_x: jax.Array  # float32 [2], s of the first and the last plant slot of every row [m]
    row_phase: jax.Array  # float32 [], phase φ of the rows' sinusoid [rad]
    lane_y: jax.Array  # float32, lateral position (u) of the centre line of lane i [m]
    lane_width: jax.Array  # float32, distance between the rows bounding lane i [m]
    lane_active: jax.Array  # bool
    terrain: jax.Array  # float32 [NY, NX], heights [m]; sample (j, i) lies at terrain_xy(j, i)
    terrain_size: jax.Array  # float32 [2], (length along x, width along y) [m]
    obst_pos: jax.Array  # float32 [S, 3], obstacle centre [m]
    obst_size: jax.Array  # float32 [S, 2], stone: (radius, 0); branch: (radius, half length) [m]
    obst_yaw: jax.Array  # float32 [S], branch direction about z [rad]
    obst_kind: jax.Array  # int32 [S], 0 stone, 1 fallen branch
    obst_active: jax.Array  # bool [S]
    weed_pos: jax.Array  # float32 [W, 3], weed base centre on the terrain surface [m]
    weed_size: jax.Array  # float32 [W, 2], (diameter, height) [m]
    weed_yaw: jax.Array  # float32 [W], orientation about z [rad]
    weed_phase: jax.Array  # float32 [W], per-weed random number in [0, 1) for its shape
    weed_active: jax.Array  # bool [W]
    n_rows: jax.Array  # int32 [], rows actually laid
    valid: jax.Array  # bool [], False when the params describe an impossible field


STONE, BRANCH = 0, 1


def make_params(preset: str = "zucchini", *, host: bool = False, **overrides: Any) -> FieldParams:
    """FieldParams of a crop's preset (`mjxrow.crops.get(preset).preset`) with `overrides`
    (name → number, or array for a batch). `host`: numpy arrays, for checks on the host that
    should run no device program (`checks`, `fit_shape` and `validate` take either)."""
    if preset not in crops.CROPS:
        raise ValueError(f"preset: unknown preset {preset!r}; expected one of {crops.names()}")
    unknown = sorted(set(overrides) - set(PARAM_NAMES))
    if unknown:
        raise ValueError(f"{unknown[0]}: unknown field parameter; known: {', '.join(PARAM_NAMES)}")
    values = {**crops.get(preset).preset, **overrides}
    stray = sorted(set(values) - set(PARAM_NAMES))
    if stray:
        raise ValueError(f"{stray[0]}: unknown field parameter in crop {preset!r}'s preset")
    missing = [k for k in PARAM_NAMES if k not in values]
    if missing:
        raise ValueError(f"{missing[0]}: crop {preset!r}'s preset has no value for it")
    xp = np if host else jnp
    return FieldParams(**{k: xp.asarray(values[k], xp.float32) for k in PARAM_NAMES})


def stack_params(params: list[FieldParams]) -> FieldParams:
    """[FieldParams] → one FieldParams with a leading [B] axis (numpy if all are numpy)."""
    return jax.tree.map(lambda *xs: stack_leaves(xs), *params)


def stack_leaves(xs: Any) -> Any:
    """Leaves → one array with a leading [N] axis: numpy when all are host values (numbers,
    numpy), so that a batch's parameters reach the device in one transfer with no program
    compiled for the stacking; jnp otherwise (`array_namespace`)."""
    xp = array_namespace(*xs)
    return xp.stack([xp.asarray(x) for x in xs])


def array_namespace(*xs: Any):
    """The array namespace for `xs`: numpy when all are host arrays or numbers (so that host
    work, such as the checks of a sweep's cells or stacking a batch's parameters, runs no
    device program per operation), else jnp (device arrays, tracers, PRNG keys)."""
    host = all(isinstance(x, (np.ndarray, np.generic, int, float)) for x in xs)
    return np if host else jnp


# ---------------------------------------------------------------------------------------------
# Layout (jnp, or numpy for host params; shared by generate, validate and the shape fitter)


def _scaled(p: FieldParams) -> dict[str, jax.Array]:
    xp = array_namespace(*jax.tree.leaves(p))
    s = p.scale
    lengths = ("d_rr", "d_RR", "d_pp", "row_length", "terrain_length", "terrain_width",
               "plant_length", "plant_width", "plant_height", "terrain_dh", "terrain_scale",
               "plant_jitter", "row_amplitude", "row_wavelength", "gap_length", "weed_size")
    out = {k: getattr(p, k) for k in PARAM_NAMES}
    out.update({k: getattr(p, k) * s for k in lengths})
    out["row_curvature"] = p.row_curvature / s
    out["rows_per_group"] = xp.maximum(xp.round(p.rows_per_group), 1.0)
    return out


def _layout(q: dict[str, jax.Array]) -> dict[str, jax.Array]:
    """Counts implied by scaled params: groups, rows, plants per row, obstacles."""
    xp = array_namespace(*q.values())
    rpg = q["rows_per_group"]
    group_w = (rpg - 1.0) * q["d_rr"]
    pitch = group_w + q["d_RR"]
    usable = q["terrain_width"] - 2.0 * HEADLAND - group_w
    n_groups = xp.where(usable >= 0, xp.floor(usable / pitch + 1e-6) + 1.0, 0.0)
    n_rows = n_groups * rpg
    n_plants = xp.floor(q["row_length"] / q["d_pp"] + 1e-6) + 1.0
    lane_area = q["row_length"] * xp.maximum(n_rows - 1.0, 0.0) * (pitch / rpg) / 100.0
    n_stones = xp.round(q["stone_density"] * lane_area)
    n_branches = xp.round(q["branch_density"] * lane_area)
    span = xp.maximum((n_groups - 1.0) * pitch + group_w, 0.0)  # first row to last row
    n_weeds = xp.round(q["weed_density"] * q["row_length"] * span)
    # the rows' largest departure across from their straight layout over the terrain's
    # length: the sinusoid's amplitude plus the arcs' sagitta (1 − cos(κT/2)) / |κ|, written
    # so that it is exactly 0 on a straight field; the terrain is widened by it on each side
    a = xp.minimum(xp.abs(q["row_curvature"]) * 0.5 * q["terrain_length"], 0.5 * np.pi)
    sagitta = 0.5 * q["terrain_length"] * xp.sin(0.5 * a) * xp.sinc(0.5 * a / np.pi)
    ground_width = q["terrain_width"] + 2.0 * (q["row_amplitude"] + sagitta)
    # the narrowest width across a lane: d · cos of the sinusoid's steepest angle
    squeeze = xp.cos(xp.arctan(2.0 * np.pi * q["row_amplitude"] / q["row_wavelength"]))
    return dict(n_groups=n_groups, n_rows=n_rows, n_plants=n_plants, pitch=pitch,
                group_w=group_w, n_stones=n_stones, n_branches=n_branches, span=span,
                n_weeds=n_weeds, ground_width=ground_width, squeeze=squeeze)


def checks(params: FieldParams, shape: FieldShape) -> dict[str, tuple[jax.Array, str]]:
    """Each impossible-field condition: name → (ok: bool array, reason). Traced-friendly."""
    q = _scaled(params)
    lay = _layout(q)
    xp = array_namespace(*q.values())
    lengths = ("d_rr", "d_RR", "d_pp", "row_length", "terrain_length", "terrain_width",
               "plant_length", "plant_width", "plant_height", "terrain_scale", "scale")
    out: dict[str, tuple[jax.Array, str]] = {}
    for k in lengths:
        out[k] = (getattr(params, k) > 0, "must be positive")
    for k in ("plant_size_var", "plant_jitter", "terrain_dh", "stone_density", "branch_density",
              "row_amplitude", "gap_rate", "weed_density"):
        out[k] = (getattr(params, k) >= 0, "must be non-negative")
    for k in ("row_wavelength", "gap_length", "weed_size"):
        out[k] = (getattr(params, k) > 0, "must be positive")
    out["row_wavelength"] = (
        (q["row_wavelength"] > 0) & ((q["row_amplitude"] == 0) | (q["row_wavelength"] > q["d_pp"])),
        "the rows' wavelength must be longer than the plant spacing d_pp",
    )
    k_abs = xp.abs(q["row_curvature"])
    out["row_curvature"] = (
        (k_abs * (0.5 * lay["span"] + q["row_amplitude"] + q["plant_width"]) < 1.0)
        & (k_abs * 0.5 * q["terrain_length"] <= 0.5 * np.pi),
        "the rows cross or turn back: 1/|row_curvature| must exceed half the width of the rows, "
        "and the terrain's length bend less than a half circle",
    )
    out["gap_length"] = (
        (q["gap_length"] > 0) & (params.gap_rate * q["gap_length"] < 10.0),
        "gaps cover the whole row (gap_rate · gap_length must stay below 10 m per 10 m)",
    )
    out["p_missing"] = ((params.p_missing >= 0) & (params.p_missing < 1), "must lie in [0, 1)")
    out["rows_per_group"] = (params.rows_per_group >= 1, "must be at least 1")
    multi_row = q["rows_per_group"] > 1
    out["plant_width"] = (
        (q["plant_width"] > 0)
        & (xp.where(multi_row, q["plant_width"] < q["d_rr"], True))
        & (q["plant_width"] < q["d_RR"]),
        "plants are wider than their row spacing (d_rr or d_RR)",
    )
    out["row_length"] = (
        (q["row_length"] > 0) & (q["row_length"] <= q["terrain_length"] - 2 * HEADLAND),
        f"rows must fit the terrain length with {HEADLAND} m headlands",
    )
    out["terrain_width"] = (
        (q["terrain_width"] > 0) & (lay["n_rows"] >= 2),
        "fewer than two rows fit the terrain width with these spacings",
    )
    out["max_rows"] = (lay["n_rows"] <= shape.max_rows,
                       f"more rows than the shape allows (max_rows={shape.max_rows})")
    out["max_plants_per_row"] = (
        lay["n_plants"] <= shape.max_plants_per_row,
        f"more plants per row than the shape allows (max_plants_per_row="
        f"{shape.max_plants_per_row}); raise d_pp or the shape",
    )
    out["obstacle_slots"] = (
        lay["n_stones"] + lay["n_branches"] <= shape.obstacle_slots,
        f"more obstacles than the shape allows (obstacle_slots={shape.obstacle_slots})",
    )
    free_in = xp.where(multi_row, q["d_rr"] * lay["squeeze"] - q["plant_width"], -1.0)
    free_between = q["d_RR"] * lay["squeeze"] - q["plant_width"]
    out["robot_lane"] = (
        xp.maximum(free_in, free_between) >= ROBOT_WIDTH + LANE_CLEARANCE,
        f"no lane is wide enough for the robot ({ROBOT_WIDTH} m + {LANE_CLEARANCE} m clearance)",
    )
    narrowest = xp.where(multi_row, xp.minimum(free_in, free_between), free_between)
    out["weed_size"] = (
        (q["weed_size"] > 0) & ((params.weed_density == 0) | (q["weed_size"] < narrowest)),
        "weeds are larger than the lane between the plants",
    )
    out["weed_slots"] = (lay["n_weeds"] <= shape.weed_slots,
                         f"more weeds than the shape allows (weed_slots={shape.weed_slots})")
    return out


def validate(params: FieldParams, shape: FieldShape) -> None:
    """Raise ValueError naming the first parameter that makes the field impossible.

    Works on single or batched params (the message names the first failing index)."""
    for name, (ok, reason) in checks(params, shape).items():
        ok = np.asarray(ok)
        if not ok.all():
            where = "" if ok.ndim == 0 else f" (batch index {int(np.argmin(ok.reshape(-1)))})"
            raise ValueError(f"{name}: {reason}{where}")


def fit_shape(params: FieldParams, crop: str, cell: float = 0.25, round_to: int = 8,
              obstacle_slots: int | None = None) -> FieldShape:
    """Smallest static FieldShape (rounded up) that holds every field of `params` (host)."""
    q = jax.tree.map(np.asarray, _scaled(params))
    lay = jax.tree.map(np.asarray, _layout(q))

    def up(n):
        return int(max(round_to, math.ceil(float(np.max(n)) / round_to) * round_to))

    nx = up(np.max(q["terrain_length"]) / cell + 1)
    ny = up(np.max(lay["ground_width"]) / cell + 1)
    slots = obstacle_slots or up(np.max(lay["n_stones"] + lay["n_branches"]) + 1)
    n_weeds = float(np.max(lay["n_weeds"]))
    return FieldShape(crop=crop, max_rows=up(np.max(lay["n_rows"])),
                      max_plants_per_row=up(np.max(lay["n_plants"])), terrain_cells=(ny, nx),
                      obstacle_slots=slots, weed_slots=up(n_weeds) if n_weeds > 0 else 0)


def preset_shape(preset: str) -> FieldShape:
    return fit_shape(make_params(preset), preset)


