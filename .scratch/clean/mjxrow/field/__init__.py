"""Parametric row-crop fields: `FieldParams` (traced), `FieldShape` (static) and the traced
generator `generate`. The crops themselves (presets, plants) live in `mjxrow.crops`; the
exports to MuJoCo / Gazebo in `mjxrow.worlds`."""

from mjxrow.field import lanes
from mjxrow.field.generate import gap_runs, generate, robot_lane, terrain_axes, terrain_height
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

__all__ = ["BRANCH", "HEADLAND", "LANE_CLEARANCE", "PARAM_NAMES", "ROBOT_WIDTH", "STONE",
           "Field", "FieldParams", "FieldShape", "array_namespace", "checks", "fit_shape",
           "gap_runs", "generate", "lanes", "make_params", "preset_shape", "robot_lane",
           "stack_leaves", "stack_params",
           "terrain_axes", "terrain_height", "validate"]
