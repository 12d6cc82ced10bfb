"""Parametric row-crop fields: `FieldParams` (traced), `FieldShape` (static), `generate`, and
the exports to MuJoCo / Gazebo (`mjxrow.field.export`)."""

from mjxrow.field.generate import generate, robot_lane, terrain_axes, terrain_height
from mjxrow.field.params import (
    BRANCH,
    CROPS,
    HEADLAND,
    LANE_CLEARANCE,
    PARAM_NAMES,
    PRESETS,
    ROBOT_WIDTH,
    STONE,
    Field,
    FieldParams,
    FieldShape,
    checks,
    fit_shape,
    make_params,
    preset_shape,
    stack_params,
    validate,
)

__all__ = ["BRANCH", "CROPS", "HEADLAND", "LANE_CLEARANCE", "PARAM_NAMES", "PRESETS",
           "ROBOT_WIDTH", "STONE", "Field", "FieldParams", "FieldShape", "checks", "fit_shape",
           "generate", "make_params", "preset_shape", "robot_lane", "stack_params",
           "terrain_axes", "terrain_height", "validate"]
