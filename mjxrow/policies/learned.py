"""The learned policy as a controller (`controller: {name: policy, checkpoint: DIR}`): each
control step renders the robot's camera image, builds the observation the network was trained
on (`env.observe`, the training environment's own function: image, mask or segmenter features,
odometry and the previous action) and drives with the network's mean action, clipped to
[-1, 1] and scaled by the limits it was trained with.

It runs wherever a controller runs (the sweep, `python -m mjxrow.episode`, the experiments)
through `rollout.build`: a controller with a `make_policy(run, shape) -> (Policy, base params)`
puts the renderer in front of itself, as the perception loop does for mask controllers. The
policy's params are the perception pair `(PerceptionParams, ())`: the sky / lighting condition
and threshold per episode, and `variables = {"policy": network, "segmenter": ... or None}`
shared by the batch, so checkpoints of one architecture share one compile.

Errors (one line, naming the key): `controller.checkpoint` missing, or trained on another
image size than `camera.width` × `camera.height`.
"""

from __future__ import annotations

import dataclasses
import functools
from collections.abc import Callable
from typing import Any, ClassVar

import jax
import jax.numpy as jnp
from flax import struct

from mjxrow import render
from mjxrow.control.base import Controller, Obs, Policy, register
from mjxrow.policies import checkpoint as policies_checkpoint
from mjxrow.policies import networks as policies_networks
from mjxrow.policies import observe as policies_observe
from mjxrow.policies import perception


@dataclasses.dataclass(frozen=True)
class PolicyConfig:
    """The learned policy's settings (YAML section `controller` with `name: policy`)."""

    checkpoint: str = "shipped"  # 'shipped' (mjxrow/checkpoints/policy/) or a policy checkpoint
    # folder (absolute or relative to the working directory), written by
    # experiments/train_policy.py; its image size must be the camera's
    symmetric: bool = False  # run the network on the observation and on its mirror image and
    # average (ω antisymmetrically, `networks.NetConfig.symmetric`), so that it keeps no
    # left-right bias of its own; one checkpoint, twice the network's work

    STATIC: ClassVar[tuple[str, ...]] = ("checkpoint", "symmetric")

    def __post_init__(self):
        if not str(self.checkpoint).strip():
            raise ValueError("controller.checkpoint: must name a folder or 'shipped'")
        if not isinstance(self.symmetric, bool):
            raise ValueError(f"controller.symmetric: must be true or false, got "
                             f"{self.symmetric!r}")


@struct.dataclass
class PolicyState:
    prev_pose: jax.Array  # float32 [3], the pose at the previous step (odometry)
    prev_action: jax.Array  # float32 [2], the previous action in [-1, 1]
    started: jax.Array  # bool [], a previous step exists


@functools.lru_cache(maxsize=8)
def _load(path: str, stamp: int, expect: tuple):

    return policies_checkpoint.load(path, dict(expect))


def load(cfg: PolicyConfig, image_hw: tuple[int, int] | None, base_dir: str = "."):
    """The checkpoint of `cfg`, checked against the camera's (height, width) unless None;
    cached until its policy.json changes (a retrained checkpoint in the same folder)."""

    path = policies_checkpoint.resolve(cfg.checkpoint, base_dir)
    stamp = (path / policies_checkpoint.SPEC_FILE).stat().st_mtime_ns
    expect = () if image_hw is None else (("height", int(image_hw[0])),
                                          ("width", int(image_hw[1])))
    return _load(str(path), stamp, expect)


def network(cfg: PolicyConfig, ck) -> policies_networks.PolicyNet:
    """The network the controller runs: the checkpoint's, made left-right symmetric where
    `cfg.symmetric` asks (the same variables fit either)."""
    if not cfg.symmetric or ck.net.cfg.symmetric:
        return ck.net
    return policies_networks.PolicyNet(dataclasses.replace(ck.net.cfg, symmetric=True))


def make_params(cfg: PolicyConfig, image_hw: tuple[int, int] | None = None) -> tuple:
    """No traced controller params (the weights travel as shared perception params); loading
    here checks the checkpoint against the image size, so a sweep's config check reports a
    missing or mismatched checkpoint before anything runs."""
    load(cfg, image_hw)
    return ()


def _unbuilt_act(params, state, obs: Obs):
    raise ValueError("controller.name: 'policy' renders its own camera image; build it with "
                     "rollout.build (make_policy)")


@functools.lru_cache(maxsize=16)
def image_policy(net, spec, seg_module, shape, intr, render_cfg, limits: tuple[float, float],
                 dt: float) -> Policy:
    """The Policy of a network `net` observing `spec` (pure; not jitted). Static arguments
    (cached: equal ones give the same Policy, hence one compile): the network module, the
    observation spec, the segmenter module (None: none), the field shape, the camera
    intrinsics, the render config, the action limits (v_max, ω_max) and the control period."""

    lim = jnp.asarray(limits, jnp.float32)

    def init(params):
        return PolicyState(prev_pose=jnp.zeros(3), prev_action=jnp.zeros(2),
                           started=jnp.zeros((), bool))

    def prepare(params, field):
        return render.plant_table(field, shape)

    def act(params, state: PolicyState, obs: Obs, key):
        p = params[0]
        frame = render.render(obs.field, shape, obs.cam_pos, obs.cam_rot, intr, p.cond, None,
                              render_cfg, table=obs.aux)
        seg = None if seg_module is None else policies_observe.Segmenter(
            variables=p.variables["segmenter"], threshold=p.threshold, module=seg_module)
        vel = jnp.where(
            state.started, policies_observe.odometry(state.prev_pose, obs.pose, dt), 0.0
        )
        o = policies_observe.observe(spec, frame, seg, vel, state.prev_action, lim)
        mean, _, _ = net.apply(p.variables["policy"], o)
        a = jnp.clip(mean, -1.0, 1.0)
        return (PolicyState(prev_pose=obs.pose, prev_action=a, started=jnp.ones((), bool)),
                policies_observe.scale_action(a, lim))

    return Policy(init, act, prepare)


def make_policy(run, shape) -> tuple[Policy, Any]:
    """(Policy, base perception params) of a run whose controller is `policy`: the checkpoint
    loaded and checked, the segmenter its observation needs (env.observe.segmenter_for)."""

    ck = load(run.controller.params, (run.camera.height, run.camera.width), run.base_dir)
    seg = policies_observe.segmenter_for(run, ck.spec)
    policy = image_policy(network(run.controller.params, ck), ck.spec,
                          None if seg is None else seg.module, shape, run.camera, run.render,
                          ck.limits, run.episode.control_dt)
    variables = {"policy": ck.variables, "segmenter": None if seg is None else seg.variables}
    return policy, perception.perception_params(run.perception.conditions(),
                                                run.perception.threshold, variables)


def program_statics(run) -> tuple:
    """The run's static values as they fix its compiled program (`rollout.fingerprint.program_key`):
    the checkpoint's observation, network and action limits in place of its path. The weights
    are traced, so checkpoints of one architecture and limits share a program wherever they
    lie, and a checkpoint replaced by one with other limits is another program."""
    ck = load(run.controller.params, None, run.base_dir)
    net = network(run.controller.params, ck)
    return tuple(x for x in run.static_key()
                 if not (isinstance(x, tuple) and x[0] in ("controller.checkpoint",
                                                           "controller.symmetric"))) + (
        ("controller.checkpoint", f"{ck.spec} {net.cfg} limits {ck.limits}"),)


@dataclasses.dataclass(frozen=True, eq=False)
class ImageController(Controller):
    """A controller that renders its own camera image: `rollout.build` calls
    `make_policy(run, shape) -> (Policy, base perception params)` instead of `as_policy`, and
    `program_statics(run)` for the static values that name its program."""

    make_policy: Callable[[Any, Any], tuple[Policy, Any]] | None = None
    program_statics: Callable[[Any], tuple] | None = None


POLICY = register(ImageController("policy", PolicyConfig, make_params, lambda params: (),
                                  _unbuilt_act, needs_mask=False, make_policy=make_policy,
                                  program_statics=program_statics))
