"""Host-side checks of field parameters against a simulation configuration (re-exported by
`mjxrow.physics.sim`): requests the traced physics cannot honour are rejected here, before a
batch is compiled, with an error that names the keys to change.

- `patch_relief(params, sim_cfg)`: the terrain height range a world's physics patch can span.
- `fit_patch_z(params, sim_cfg)`: `sim_cfg` with a `patch_z` that holds that relief.
- `check_patch_z(params, sim_cfg)`, `check_lane(params, sim_cfg)`, `check_params` (both).
- `auto_lane_kind(params)`: the lane kind `sim.lane = "auto"` gives each field.

`params` is a FieldParams of scalars or with a leading [B] axis (the message names the first
failing batch index).
"""

from __future__ import annotations

import dataclasses
import math
from typing import TYPE_CHECKING

import numpy as np

from mjxrow import field
from mjxrow.field import params as field_params

if TYPE_CHECKING:
    from mjxrow.physics.model import SimConfig


def _np(params: field.FieldParams) -> dict[str, np.ndarray]:
    return {k: np.atleast_1d(np.asarray(getattr(params, k), np.float64)) for k in field.PARAM_NAMES}


def _where(bad: np.ndarray) -> tuple[int, str]:
    i = int(np.argmax(bad))
    return i, "" if bad.size == 1 else f" (batch index {i})"


def patch_relief(params: field.FieldParams, sim_cfg: SimConfig) -> np.ndarray:
    """float64 [B] (or [1]): bound [m] on the terrain height range under a physics patch:
    peak-to-peak roughness `terrain_dh · scale` plus |slope_x| · patch length plus
    |slope_y| · patch width (`sim_cfg.patch_size`). The patch stores heights in
    [0, `sim_cfg.patch_z`]: a larger range would be clipped (flattened physics terrain)."""
    p = _np(params)
    lx, ly = sim_cfg.patch_size
    return p["terrain_dh"] * p["scale"] + np.abs(p["slope_x"]) * lx + np.abs(p["slope_y"]) * ly


def fit_patch_z(params: field.FieldParams, sim_cfg: SimConfig) -> SimConfig:
    """`sim_cfg` with `patch_z` raised to the next whole metre above every field's
    `patch_relief` (unchanged when it already holds them; whole metres keep the number of
    distinct static configurations, hence compiles, small)."""
    need = float(np.max(patch_relief(params, sim_cfg)))
    if need <= sim_cfg.patch_z:
        return sim_cfg
    return dataclasses.replace(sim_cfg, patch_z=float(math.floor(need) + 1))


def check_patch_z(params: field.FieldParams, sim_cfg: SimConfig) -> None:
    """Raise ValueError when a field's terrain relief under the patch can exceed
    `sim_cfg.patch_z` (its physics terrain would be flattened), naming the largest term."""
    relief = patch_relief(params, sim_cfg)
    bad = relief > sim_cfg.patch_z
    if not bad.any():
        return
    i, where = _where(bad)
    p = _np(params)
    lx, ly = sim_cfg.patch_size
    terms = {"field.slope_x": abs(p["slope_x"][i]) * lx, "field.slope_y": abs(p["slope_y"][i]) * ly,
             "field.terrain_dh": p["terrain_dh"][i] * p["scale"][i]}
    key = max(terms, key=terms.get)
    raise ValueError(
        f"sim.patch_z: {sim_cfg.patch_z:g} m cannot hold the terrain relief under the "
        f"{lx:g} m x {ly:g} m physics patch, up to {relief[i]:.2f} m at {key}="
        f"{p[key.split('.')[1]][i]:g}{where}; raise sim.patch_z above it (sim.fit_patch_z) "
        f"or lower {key}")


def lane_free_width(params: field.FieldParams) -> tuple[np.ndarray, np.ndarray]:
    """(in-group, between-groups) free lane widths [m] (lane width − plant width), float64 [B];
    the in-group one is −inf where rows_per_group = 1 (no such lane)."""
    p = _np(params)
    s = p["scale"]
    multi = np.maximum(np.round(p["rows_per_group"]), 1.0) > 1
    free_in = np.where(multi, (p["d_rr"] - p["plant_width"]) * s, -np.inf)
    return free_in, (p["d_RR"] - p["plant_width"]) * s


def check_lane(params: field.FieldParams, sim_cfg: SimConfig,
               robot_width: float = field.ROBOT_WIDTH) -> None:
    """Raise ValueError when `sim_cfg.lane` asks for a lane kind that no field of `params` can
    give the robot: "in_group" with rows_per_group = 1 or a free in-group width
    (d_rr − plant_width) below robot_width + LANE_CLEARANCE; "between_groups" likewise with
    d_RR. "auto" is checked by `field.validate` (some lane must fit). `field.robot_lane(field,
    mode=sim_cfg.lane)` picks the lane inside traced code."""
    mode, need = sim_cfg.lane, robot_width + field.LANE_CLEARANCE
    if mode == "auto":
        return
    free_in, free_between = lane_free_width(params)
    p = _np(params)
    if mode == "in_group":
        if np.isneginf(free_in).any():
            _, where = _where(np.isneginf(free_in))
            raise ValueError(f"sim.lane: in_group needs rows_per_group > 1, got field."
                             f"rows_per_group=1{where}; use sim.lane='between_groups' or 'auto'")
        free, key = free_in, "d_rr"
    else:
        lay = field_params._layout(field_params._scaled(params))
        one = (np.atleast_1d(np.asarray(lay["n_groups"])) < 2) & (p["rows_per_group"] > 1)
        if one.any():
            i, where = _where(one)
            raise ValueError(f"sim.lane: between_groups needs two row groups, the field holds one "
                             f"at field.terrain_width={p['terrain_width'][i]:g}{where}; widen "
                             f"field.terrain_width or choose another sim.lane")
        free, key = free_between, "d_RR"
    bad = free < need
    if bad.any():
        i, where = _where(bad)
        raise ValueError(
            f"sim.lane: the {mode} lane is {free[i]:.2f} m wide between plants at field.{key}="
            f"{p[key][i]:g} (field.plant_width={p['plant_width'][i]:g}){where}, the robot needs "
            f"{need:.2f} m; widen field.{key} or choose another sim.lane")


def auto_lane_kind(params: field.FieldParams, robot_width: float = field.ROBOT_WIDTH) -> np.ndarray:
    """str [B]: the lane kind "auto" drives on each field, "in_group" where an in-group lane
    fits the robot (field.robot_lane's preference), else "between_groups"."""
    free_in, _ = lane_free_width(params)
    return np.where(free_in >= robot_width + field.LANE_CLEARANCE, "in_group", "between_groups")


def check_params(params: field.FieldParams, sim_cfg: SimConfig) -> None:
    """`check_patch_z` and `check_lane` (call before compiling a batch of these fields)."""
    check_patch_z(params, sim_cfg)
    check_lane(params, sim_cfg)
