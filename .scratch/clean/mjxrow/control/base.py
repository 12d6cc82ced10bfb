"""Controllers: ground-truth pure pursuit (`oracle`), SegZeros and SegMin on a plant mask.

A controller is a pair of pure, jittable functions over pytrees:

    init(params) -> state
    act(params, state, obs) -> (state, cmd)        cmd = float32 [2] = (v [m/s], ω [rad/s])

`params` are pytrees whose numbers are `jax.Array`s (gains are sweepable without recompiling);
the few fields that fix the structure (law, mask buffer size, image size) are static. A
`Policy` adds a PRNG key to `act` so that perception (render → segment) plugs in in front of a
mask controller: see `with_perception`.

Signs: ω > 0 turns left (counter-clockwise, yaw increasing). Image column 0 is the LEFT edge of
the image, so a free lane left of the image centre (x_c < w/2, d < 0) gives ω > 0.
"""

from __future__ import annotations

import dataclasses
from collections.abc import Callable
from typing import Any, NamedTuple

import jax
import jax.numpy as jnp
from flax import struct

from mjxrow.field import Field
from mjxrow.field.lanes import Lane


@struct.dataclass
class Obs:
    """What a controller sees at one control step (one world; add [B] axes for a batch)."""

    pose: jax.Array  # float32 [3], (x [m], y [m], yaw [rad]), world frame
    lane: Lane  # the driven lane's centre line (`mjxrow.field.lanes`; straight or curved)
    goal: jax.Array  # float32 [2], goal (x, y) [m], the lane's end
    cam_pos: jax.Array  # float32 [3], camera position, world frame [m]
    cam_rot: jax.Array  # float32 [3, 3], columns: camera right, up, backward (MuJoCo)
    field: Field | None = None  # the world (no batch axis)
    mask: jax.Array | None = None  # bool [H, W], plant pixels; column 0 = image left
    depth: jax.Array | None = None  # float32 [H, W], metres along the optical axis
    aux: Any = None  # what the policy's `prepare` computed from the field before the episode

    @property
    def lane_y(self) -> jax.Array:
        """The lane's lateral field coordinate u [m] (its y on a straight field)."""
        return self.lane.u


class Policy(NamedTuple):
    """A policy for `episode.rollout`: `init(params) -> state` and
    `act(params, state, obs, key) -> (state, cmd [2])`; calling the policy calls `act`.
    Optional `prepare(params, field) -> aux`: computed once per episode, before its first step
    (e.g. the renderer's plant table), and handed to every step as `obs.aux`."""

    init: Callable[[Any], Any]
    act: Callable[[Any, Any, Obs, jax.Array], tuple[Any, jax.Array]]
    prepare: Callable[[Any, Field], Any] | None = None

    def __call__(self, params, state, obs, key):
        return self.act(params, state, obs, key)



def wrap_angle(a: jax.Array) -> jax.Array:
    """Angle [rad] wrapped into [−π, π)."""
    return jnp.mod(a + jnp.pi, 2.0 * jnp.pi) - jnp.pi




# ---------------------------------------------------------------------------------------------
# Registry and policies


@dataclasses.dataclass(frozen=True, eq=False)
class Controller:
    """A registered controller. `config` is a frozen dataclass of its settings (the YAML
    section `controller`, same names; class attributes `STATIC` / `TRACED` say which fields
    fix the compiled program, `CHOICES` the allowed strings); `make_params(config, image_hw)`
    turns one into the traced params pytree `init` / `act` take; `needs_mask`: the controller
    reads `obs.mask` (it runs behind the perception loop)."""

    name: str
    config: type
    make_params: Callable[[Any, tuple[int, int] | None], Any]
    init: Callable[[Any], Any]
    act: Callable[[Any, Any, Obs], tuple[Any, jax.Array]]
    needs_mask: bool = False


CONTROLLERS: dict[str, Controller] = {}


def register(controller: Controller) -> Controller:
    """Add a controller to the registry under its name (the YAML's `controller.name`)."""
    CONTROLLERS[controller.name] = controller
    return controller


def names() -> tuple[str, ...]:
    """Registered controller names, in registration order."""
    return tuple(CONTROLLERS)


def get(name: str) -> Controller:
    if name not in CONTROLLERS:
        raise ValueError(f"controller.name: unknown {name!r}; expected one of {names()}")
    return CONTROLLERS[name]


def _act_without_key(act):
    def policy_act(params, state, obs, key):
        del key
        return act(params, state, obs)

    return policy_act


def as_policy(controller: Controller | str) -> Policy:
    """A controller as a Policy (the PRNG key is unused). Same controller → equal Policy, so
    `episode.rollout` reuses its compiled function."""
    c = get(controller) if isinstance(controller, str) else controller
    return _POLICIES.setdefault(c, Policy(c.init, _act_without_key(c.act)))


_POLICIES: dict[Controller, Policy] = {}


def with_perception(controller: Controller | str,
                    perceive: Callable[[Any, Obs, jax.Array], tuple[jax.Array, Any]],
                    prepare: Callable[[Any, Field], Any] | None = None) -> Policy:
    """Closed loop through perception: `perceive(perc_params, obs, key) -> (mask bool [H, W],
    depth float32 [H, W] or None)` (e.g. render → segment) feeds a mask controller.
    The policy's params are the pair (perc_params, controller_params). `prepare(perc_params,
    field) -> aux`, if given, runs once per episode; `perceive` finds its result in obs.aux."""
    c = get(controller) if isinstance(controller, str) else controller

    def init(params):
        return c.init(params[1])

    def act(params, state, obs, key):
        mask, depth = perceive(params[0], obs, key)
        return c.act(params[1], state, obs.replace(mask=mask, depth=depth))

    if prepare is None:
        return Policy(init, act)
    return Policy(init, act, lambda params, field: prepare(params[0], field))
