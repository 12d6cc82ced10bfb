"""The oracle: pure pursuit on the ground-truth lane centre line (an upper bound for the
perception controllers; it sees the true lane, not the camera)."""

from __future__ import annotations

import dataclasses
from typing import ClassVar

import jax
import jax.numpy as jnp
import numpy as np
from flax import struct

from mjxrow.control.base import Controller, Obs, register
from mjxrow.field import lanes as field_lanes
from mjxrow.field.lanes import Lane


@struct.dataclass
class OracleParams:
    lookahead: jax.Array  # pure-pursuit lookahead distance [m]
    v_max: jax.Array  # forward speed [m/s]
    omega_max: jax.Array  # |ω| limit [rad/s]


def oracle_params(lookahead: float = 1.0, v_max: float = 0.5, omega_max: float = 1.0
                  ) -> OracleParams:
    if lookahead <= 0:
        raise ValueError(f"lookahead: must be positive, got {lookahead}")
    f = lambda x: np.asarray(x, np.float32)  # noqa: E731 (host: stacked per batch on the host)
    return OracleParams(lookahead=f(lookahead), v_max=f(v_max), omega_max=f(omega_max))


def oracle_init(params: OracleParams) -> tuple:
    return ()


def pursuit_command(params: OracleParams, pose: jax.Array, lane: Lane) -> jax.Array:
    """(v, ω) [2] of pure pursuit on the lane's centre line (straight or curved), driven
    towards +s.

    The target is the point of the line `ahead` = √(lookahead² − e²) along it from the robot's
    projection, e the robot's offset from the line (the point at `lookahead` from the robot on
    a straight line; when the robot is farther than that from the line, 0.1·lookahead ahead of
    its projection); curvature κ = 2·y_r / (x_r² + y_r²) with the target at (x_r, y_r) in the
    robot frame; ω = v_max·κ clipped to ±omega_max, v = v_max."""
    yaw = pose[2]
    s, e, _ = field_lanes.project(lane, pose[:2])
    L = params.lookahead
    ahead = jnp.sqrt(jnp.maximum(L * L - e * e, (0.1 * L) ** 2))
    target = field_lanes.point(lane, s + ahead)
    dx, dy = target[0] - pose[0], target[1] - pose[1]
    c, s = jnp.cos(yaw), jnp.sin(yaw)
    xr, yr = c * dx + s * dy, -s * dx + c * dy
    kappa = 2.0 * yr / jnp.maximum(xr * xr + yr * yr, 1e-9)
    omega = jnp.clip(params.v_max * kappa, -params.omega_max, params.omega_max)
    return jnp.stack([params.v_max, omega]).astype(jnp.float32)


def oracle_act(params: OracleParams, state: tuple, obs: Obs) -> tuple[tuple, jax.Array]:
    return state, pursuit_command(params, obs.pose, obs.lane)



@dataclasses.dataclass(frozen=True)
class OracleConfig:
    """The oracle's settings (YAML section `controller` with `name: oracle`); every number is
    traced (sweepable without recompiling)."""

    lookahead: float = 1.0  # m, pure-pursuit look-ahead distance
    v_max: float = 0.5  # m/s, forward speed
    omega_max: float = 1.0  # rad/s, |ω| limit

    TRACED: ClassVar[tuple[str, ...]] = ("lookahead", "v_max", "omega_max")

    def __post_init__(self):
        for name in ("lookahead", "v_max", "omega_max"):
            if not getattr(self, name) > 0:
                raise ValueError(f"controller.{name}: must be positive, got {getattr(self, name)}")


def make_oracle_params(cfg: OracleConfig, image_hw: tuple[int, int] | None = None
                       ) -> OracleParams:
    """Traced params of an OracleConfig (the image size is not used)."""
    return oracle_params(cfg.lookahead, cfg.v_max, cfg.omega_max)


ORACLE = register(Controller("oracle", OracleConfig, make_oracle_params, oracle_init, oracle_act,
                             needs_mask=False))
