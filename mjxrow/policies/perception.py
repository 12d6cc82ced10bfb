"""Perception in the loop: render → (segment) → mask controller, as one `control.Policy`.

The one implementation of the closed perception loop; `episode`'s CLI, `sweep` and the
experiments build their policies here. Each control step the policy renders the robot's camera
image of its field (`render.render`), takes the renderer's ground-truth plant mask
(`source="ground_truth"`) or the learned segmenter's mask of the RGB image (`"learned"`:
sigmoid(logit) > threshold), and hands mask and depth to SegZeros / SegMin.

Static (part of the policy, so of the compile key): the controller, the field shape, the camera
intrinsics, the source, the segmenter's architecture (its Flax module), the render config.
Traced (the policy's params, so no recompile): the sky/lighting conditions, the threshold, the
segmenter's WEIGHTS and the controller's gains. The params are the pair
`(PerceptionParams, controller params)`; `PARAMS_AXES` vmaps them with the weights shared and
everything else per episode, so a new checkpoint of the same architecture reuses the compiled
rollout and the weights are never baked into the program.
"""

from __future__ import annotations

import dataclasses
import functools
import math
from typing import Any, ClassVar

import jax
import jax.numpy as jnp
import numpy as np
from flax import struct

from mjxrow import control, render
from mjxrow import field as mjxrow_field
from mjxrow.seg import checkpoint as seg_checkpoint
from mjxrow.seg import model as seg_model

SOURCES = ("ground_truth", "learned")
CONDITION_NAMES = ("sunny", "cloudy", "crepuscular", "long_shadows")


@dataclasses.dataclass(frozen=True)
class PerceptionConfig:
    """Where a mask controller's mask comes from (YAML section `perception`)."""

    source: str = "learned"  # mask from the learned segmenter or the renderer's ground truth
    checkpoint: str = "shipped"  # 'shipped' (mjxrow/checkpoints/<crop>/) or a checkpoint
    # directory (relative to the working directory or the YAML file); one group per checkpoint,
    # but the weights are traced, so checkpoints of one architecture share one compile
    threshold: float = 0.7  # -, a pixel is a plant where the segmenter's sigmoid exceeds this
    condition: str = "sunny"  # sky / lighting condition of the rendered images
    sun_azimuth: float = render.SUN_AZIMUTH_DEG  # degrees, the sun's direction from +x
    # (along the rows) toward +y; shadows fall the opposite way

    TRACED: ClassVar[tuple[str, ...]] = ("threshold", "condition", "sun_azimuth")
    CHOICES: ClassVar[dict[str, tuple[str, ...]]] = {"source": SOURCES,
                                                     "condition": CONDITION_NAMES}

    def __post_init__(self):
        if self.source not in SOURCES:
            raise ValueError(f"perception.source: {self.source!r} is not one of "
                             f"{', '.join(SOURCES)}")
        if self.condition not in CONDITION_NAMES:
            raise ValueError(f"perception.condition: {self.condition!r} is not one of "
                             f"{', '.join(CONDITION_NAMES)}")
        if not 0.0 <= self.threshold <= 1.0:
            raise ValueError(f"perception.threshold: must be in [0, 1], got {self.threshold}")
        if not math.isfinite(self.sun_azimuth):
            raise ValueError(f"perception.sun_azimuth: must be a finite angle in degrees, got "
                             f"{self.sun_azimuth}")

    def conditions(self) -> render.Conditions:
        """The rendered images' sky and lighting: `condition` with the sun at `sun_azimuth`."""
        return render.conditions(self.condition, azimuth_deg=self.sun_azimuth)


@struct.dataclass
class PerceptionParams:
    """Traced params of the perception stage (one episode; add a [B] axis where batched)."""

    cond: Any  # render.Conditions: sky / lighting of the rendered images
    threshold: jax.Array  # float32 [], a pixel is a plant where sigmoid(logit) > threshold [-]
    variables: Any = None  # the segmenter's variables {'params', 'batch_stats'}; None: no model


# vmap axes of `(PerceptionParams, controller params)`: segmenter weights shared by the batch,
# conditions, threshold and controller params per episode (a prefix pytree for episode.rollout).
PARAMS_AXES = (PerceptionParams(cond=0, threshold=0, variables=None), 0)


def perception_params(condition: Any = "sunny", threshold: float = 0.7,
                      variables: Any = None) -> PerceptionParams:
    """PerceptionParams of one episode. condition: a `render.CONDITIONS` name or a
    `render.Conditions`; threshold in [0, 1]; variables: the segmenter's (learned source)."""

    if isinstance(condition, str):
        condition = render.conditions(condition)
    if not 0.0 <= float(threshold) <= 1.0:
        raise ValueError(f"threshold: must lie in [0, 1], got {threshold}")
    return PerceptionParams(cond=condition, threshold=np.float32(threshold),
                            variables=variables)


def perception_policy(
    controller: str,
    shape: mjxrow_field.FieldShape,
    intr,
    source: str = "ground_truth",
    segmenter=None,
    render_cfg=None,
    sensor_noise: bool = False,
) -> control.Policy:
    """A mask controller ("segzeros", "segmin") fed by the renderer (pure policy; not jitted).

    shape: the fields' static shape; intr: render.Intrinsics; source: "ground_truth" (the
    renderer's plant mask) or "learned" (`segmenter`, a `seg.model.SegNet` module, segments
    the rendered RGB; its variables come in the params); render_cfg: render.RenderConfig (None:
    the default); sensor_noise: render with the step's PRNG key (sensor noise and exposure
    jitter) instead of a deterministic image.

    The policy's params are `(PerceptionParams, controller params)`. Cached: equal arguments
    (a SegNet compares by its architecture) give the same Policy object, so `episode.rollout`
    reuses its compiled function across calls and checkpoints."""

    if source not in SOURCES:
        raise ValueError(f"source: unknown {source!r}; expected one of {SOURCES}")
    if not control.get(controller).needs_mask:
        raise ValueError(f"controller: {controller!r} takes no mask")
    if (segmenter is None) != (source == "ground_truth"):
        raise ValueError(f"segmenter: source {source!r} needs "
                         f"{'a segmenter module' if source == 'learned' else 'none'}")
    return _policy(controller, shape, intr, segmenter, render_cfg or render.RenderConfig(),
                   bool(sensor_noise))


@functools.lru_cache(maxsize=32)
def _policy(controller: str, shape: mjxrow_field.FieldShape, intr, segmenter, rcfg,
            sensor_noise: bool) -> control.Policy:

    c = control.get(controller)

    def prepare(p: PerceptionParams, field: mjxrow_field.Field):
        return render.plant_table(field, shape)  # the field's plants, once per episode

    def perceive(p: PerceptionParams, obs: control.Obs, key: jax.Array):
        frame, mask = _look(p, obs, key, shape, intr, segmenter, rcfg, sensor_noise)
        return (frame.mask if mask is None else mask), frame.depth

    return control.with_perception(c, perceive, prepare)


def _look(p: PerceptionParams, obs: control.Obs, key: jax.Array, shape, intr, segmenter, rcfg,
          sensor_noise: bool):
    """One step's camera frame of the robot's field, and the segmenter's mask of it (None
    without a segmenter)."""

    with jax.named_scope("cl_render"):  # the scopes name the stages in profiles
        frame = render.render(obs.field, shape, obs.cam_pos, obs.cam_rot, intr, p.cond,
                              key if sensor_noise else None, rcfg, table=obs.aux)
    if segmenter is None:
        return frame, None
    with jax.named_scope("cl_segment"):
        return frame, seg_model.predict_mask(segmenter, p.variables, frame.rgb[None],
                                             p.threshold)[0]


@struct.dataclass
class MixParams:
    """Params of one episode of a `mixed_policy` (add a [B] axis where batched)."""

    index: jax.Array  # int32 [], the variant whose command drives this episode
    perception: PerceptionParams | None  # None when no variant reads a mask
    controllers: tuple  # every variant's controller params (only `index`'s is used)


def mix_axes(n: int, sees: bool) -> MixParams:
    """vmap axes of a `mixed_policy`'s params with `n` variants (`sees`: one reads a mask):
    the segmenter's weights shared, everything else per episode."""
    return MixParams(index=0, perception=PARAMS_AXES[0] if sees else None,
                     controllers=(0,) * n)


def mixed_policy(variants: tuple[tuple[str, str | None], ...], shape: mjxrow_field.FieldShape, intr,
                 segmenter=None, render_cfg=None, sensor_noise: bool = False
                 ) -> control.Policy:
    """One policy for episodes of several controllers: `variants` is a tuple of (controller
    name, mask source or None for a controller that reads no mask); each episode's
    `MixParams.index` says whose command drives it. Every step renders the frame once (if
    any variant reads a mask), segments it once (if any reads the learned mask), and runs
    every variant's controller; the episode's own command is selected. So episodes of
    several controllers share one compiled program, each paying for all of their stages.
    `segmenter`: the SegNet module of the "learned" variants (their weights are traced, in
    `MixParams.perception.variables`). Cached like `perception_policy`."""

    variants = tuple((str(n), s) for n, s in variants)
    for name, source in variants:
        c = control.get(name)
        if c.needs_mask != (source is not None):
            why = "reads a mask: give its source" if c.needs_mask else \
                "reads no mask: give None as its source"
            raise ValueError(f"mixed_policy: controller {name!r} {why}")
        if source is not None and source not in SOURCES:
            raise ValueError(f"mixed_policy: unknown source {source!r}; expected one of "
                             f"{SOURCES}")
    if (segmenter is None) == any(s == "learned" for _, s in variants):
        raise ValueError("mixed_policy: a segmenter module is needed exactly when a variant "
                         "reads the learned mask")
    return _mixed(variants, shape, intr, segmenter, render_cfg or render.RenderConfig(),
                  bool(sensor_noise))


@functools.lru_cache(maxsize=32)
def _mixed(variants, shape, intr, segmenter, rcfg, sensor_noise) -> control.Policy:

    cs = [control.get(n) for n, _ in variants]
    sees = any(s is not None for _, s in variants)

    def init(p: MixParams):
        return tuple(c.init(cp) for c, cp in zip(cs, p.controllers, strict=True))

    def prepare(p: MixParams, field: mjxrow_field.Field):
        return render.plant_table(field, shape)

    def act(p: MixParams, state, obs: control.Obs, key: jax.Array):
        masks, depth = {}, None
        if sees:
            frame, learned = _look(p.perception, obs, key, shape, intr, segmenter, rcfg,
                                   sensor_noise)
            masks, depth = {"ground_truth": frame.mask, "learned": learned}, frame.depth
        new, cmds = [], []
        for c, (_, source), cp, st in zip(cs, variants, p.controllers, state, strict=True):
            o = obs if source is None else obs.replace(mask=masks[source], depth=depth)
            st, cmd = c.act(cp, st, o)
            new.append(st)
            cmds.append(jnp.asarray(cmd, jnp.float32))
        return tuple(new), jnp.stack(cmds)[p.index]

    return control.Policy(init, act, prepare if sees else None)


def load_segmenter(checkpoint: str, crop: str):
    """(module, variables) of a checkpoint (seg.checkpoint.load): a crop name or directory;
    '' means the crop's shipped one."""

    return seg_checkpoint.load(checkpoint or crop)


def make(controller: str, shape: mjxrow_field.FieldShape, intr, source: str = "ground_truth",
         checkpoint: str = "", condition: Any = "sunny", threshold: float = 0.7,
         render_cfg=None, sensor_noise: bool = False
         ) -> tuple[control.Policy, PerceptionParams]:
    """(policy, perception params) of a mask controller on `source`; for "learned" the
    segmenter is loaded from `checkpoint` (a crop name or checkpoint directory; '' = the
    shape's crop). Pair the params with the controller's: `(perc_params, seg_params)`."""
    module = variables = None
    if source == "learned":
        module, variables = load_segmenter(checkpoint, shape.crop)
    policy = perception_policy(controller, shape, intr, source, module, render_cfg,
                               sensor_noise)
    return policy, perception_params(condition, threshold, variables)
