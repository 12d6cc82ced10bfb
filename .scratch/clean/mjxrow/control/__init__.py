"""Leaf controllers, one module each, registered by name: `oracle` (pure pursuit on the true
lane), `segzeros` (SegZeros and SegMin on a plant mask); `base` holds `Obs`, `Policy` and the
registry. Perception in front of the mask controllers and the learned policy live one layer
up, in `mjxrow.policies` (which registers `policy`).

A new controller is one module that builds a `Controller` and calls `register`, plus its import
line below."""

from mjxrow.control import oracle, segzeros  # noqa: E402,I001  (registry lines)
from mjxrow.control.base import (
    CONTROLLERS,
    Controller,
    Obs,
    Policy,
    as_policy,
    get,
    names,
    register,
    with_perception,
    wrap_angle,
)
from mjxrow.control.oracle import (
    OracleConfig,
    OracleParams,
    oracle_act,
    oracle_params,
    pursuit_command,
)
from mjxrow.control.segzeros import (
    ON_END,
    SegConfig,
    SegParams,
    SegState,
    free_runs,
    lane_command,
    seg_act,
    seg_command,
    seg_init,
    seg_params,
    segmin_target,
    segzeros_target,
    steering_law,
)

__all__ = ["CONTROLLERS", "ON_END", "Controller", "Obs", "OracleConfig", "OracleParams", "Policy",
           "oracle_act",
           "SegConfig", "SegParams", "SegState", "as_policy", "free_runs", "get", "lane_command",
           "names", "oracle", "oracle_params", "pursuit_command", "register", "seg_act",
           "seg_command", "seg_init", "seg_params", "segmin_target", "segzeros", "segzeros_target",
           "steering_law", "with_perception", "wrap_angle"]
