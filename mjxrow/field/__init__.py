"""Parametric row-crop fields: `FieldParams` (traced), `FieldShape` (static), `generate`, and
the exports to MuJoCo / Gazebo (`mjxrow.field.export`). The crops themselves (presets, plants)
live in `mjxrow.crops`."""

from mjxrow import crops as _crops
from mjxrow.field.generate import generate, robot_lane, terrain_axes, terrain_height
from mjxrow.field.params import (
    BRANCH,
    HEADLAND,
    LANE_CLEARANCE,
    PARAM_NAMES,
    ROBOT_WIDTH,
    STONE,
    Field,
    FieldParams,
    FieldShape,
    array_namespace,
    checks,
    fit_shape,
    make_params,
    preset_shape,
    stack_leaves,
    stack_params,
    validate,
)


def __getattr__(name: str):
    """`CROPS` (the registered crop names) and `PRESETS` (name → preset), read from the
    registry when asked. Kept for the modules that still use them; new code calls
    `mjxrow.crops.names()` and `mjxrow.crops.get(name).preset`."""
    if name == "CROPS":
        return _crops.names()
    if name == "PRESETS":
        return {n: c.preset for n, c in _crops.CROPS.items()}
    raise AttributeError(f"module {__name__!r} has no attribute {name!r}")


__all__ = ["BRANCH", "HEADLAND", "LANE_CLEARANCE", "PARAM_NAMES", "ROBOT_WIDTH", "STONE",
           "Field", "FieldParams", "FieldShape", "array_namespace", "checks", "fit_shape",
           "generate", "make_params", "preset_shape", "robot_lane", "stack_leaves", "stack_params",
           "terrain_axes", "terrain_height", "validate"]
