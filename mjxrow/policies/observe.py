"""What a learned policy sees and how its action becomes a command: one implementation for the
training environment (`env.core`) and the `policy` controller (`control.policy`), so that a
trained network meets the same numbers in a sweep as in training.

Observation (a dict pytree, one world; add [B] / [T, B] axes for batches):

- `image`: `kind` "rgb": the camera image, uint8 [H, W, 3]; "chroma": its chromaticity
  (`chromaticity`: each pixel's colour divided by its brightness, so that a cast shadow, which
  mostly darkens, changes it less), uint8 [H, W, 3]; "mask": the plant mask, uint8
  [H, W, 1] in {0, 1} (the segmenter's, or the renderer's ground truth when
  `perception.source` is "ground_truth"); "features": the frozen MobileNetV3 encoder's last
  feature map of the RGB image, float32 [ceil(H/16), ceil(W/16), C].
- `proprio` (with `proprio=True`): float32 [4] = (v / v_max, ω / ω_max) measured by odometry
  over the last control period, and the previous action (2, in [-1, 1]).

Action: float32 [2] in [-1, 1] (clipped), scaled to (v [m/s], ω [rad/s]) by the robot's limits.
"""

from __future__ import annotations

import dataclasses
import functools
from typing import Any, ClassVar

import jax
import jax.numpy as jnp
from flax import struct

from mjxrow.control.base import wrap_angle
from mjxrow.policies import perception
from mjxrow.seg import model as seg_model

KINDS = ("rgb", "chroma", "mask", "features")
PROPRIO_DIM = 4  # (v / v_max, ω / ω_max, previous action v, previous action ω)


@dataclasses.dataclass(frozen=True)
class ObsSpec:
    """The observation a policy network was trained on (static; saved with its checkpoint)."""

    kind: str = "rgb"  # what the network sees: camera RGB, plant mask, or segmenter features
    height: int = 64  # px, camera image height (camera.height)
    width: int = 64  # px, camera image width (camera.width)
    proprio: bool = True  # odometry (v, ω) and the previous action appended

    CHOICES: ClassVar[dict[str, tuple[str, ...]]] = {"kind": KINDS}

    def __post_init__(self):
        if self.kind not in KINDS:
            raise ValueError(f"observation.kind: {self.kind!r} is not one of {', '.join(KINDS)}")
        if int(self.height) < 1 or int(self.width) < 1:
            raise ValueError(f"observation: image size must be positive, got "
                             f"{self.height}x{self.width}")

    @property
    def needs_segmenter(self) -> bool:
        return self.kind in ("mask", "features")

    def to_dict(self) -> dict[str, Any]:
        return {f.name: getattr(self, f.name) for f in dataclasses.fields(self)}

    def describe(self) -> str:
        return (f"{self.kind} {self.height}x{self.width}"
                f"{' + proprioception' if self.proprio else ''}")


@struct.dataclass
class Segmenter:
    """The segmenter an observation of kind "mask" or "features" runs (None for "rgb", or
    for "mask" from the renderer's ground truth). `module` is static; `variables` traced."""

    variables: Any  # {'params', 'batch_stats'} of a seg.model.SegNet
    threshold: jax.Array  # float32 [], plant where sigmoid(logit) > threshold
    module: Any = struct.field(pytree_node=False, default=None)  # seg.model.SegNet


def odometry(prev_pose: jax.Array, pose: jax.Array, dt: float) -> jax.Array:
    """Measured (v [m/s], ω [rad/s]) [2] from two poses [3] (x, y, yaw) one control period
    `dt` [s] apart: displacement along the previous heading / dt and wrapped Δyaw / dt."""
    c, s = jnp.cos(prev_pose[2]), jnp.sin(prev_pose[2])
    d = pose[:2] - prev_pose[:2]
    return jnp.stack([c * d[0] + s * d[1], wrap_angle(pose[2] - prev_pose[2])]) / dt


# the sign each entry takes in the left-right mirror image of a world: the proprioception's
# (v, ω measured; v, ω of the previous action: `observe`) and an action's (v, ω); an image
# mirrors along its width (axis -2)
PROPRIO_MIRROR = (1.0, -1.0, 1.0, -1.0)
ACTION_MIRROR = (1.0, -1.0)


def scale_action(action: jax.Array, limits: jax.Array) -> jax.Array:
    """Action [..., 2] → command (v [m/s], ω [rad/s]): clipped to [-1, 1] times `limits`
    [2] = (v_max, ω_max)."""
    return (jnp.clip(action, -1.0, 1.0) * limits).astype(jnp.float32)


def normalise_command(cmd: jax.Array, limits: jax.Array) -> jax.Array:
    """The inverse of `scale_action`: (v, ω) [..., 2] → action in [-1, 1]."""
    return jnp.clip(cmd / limits, -1.0, 1.0).astype(jnp.float32)


def _encoder(module):

    return seg_model.MobileNetV3(module.resolved(), dw_impl=module.dw_impl,
                                 pw_impl=module.pw_impl,
                                 momentum=module.momentum, dtype=jnp.dtype(module.dtype))


@functools.lru_cache(maxsize=8)
def _encoder_cached(module):
    return _encoder(module)


def features(seg: Segmenter, rgb: jax.Array) -> jax.Array:
    """The segmenter backbone's last feature map of `rgb` uint8 [H, W, 3]: float32
    [ceil(H/16), ceil(W/16), C] (frozen: no gradient)."""

    x = (rgb[None].astype(jnp.float32) / 255.0 - jnp.array(seg_model.MEAN)) / jnp.array(
        seg_model.STD)
    v = seg.variables
    sub = {"params": v["params"]["backbone"]}
    if "batch_stats" in v:
        sub["batch_stats"] = v["batch_stats"]["backbone"]
    _, high = _encoder_cached(seg.module).apply(sub, x.astype(jnp.dtype(seg.module.dtype)),
                                                False)
    return jax.lax.stop_gradient(high[0].astype(jnp.float32))


def chromaticity(rgb: jax.Array) -> jax.Array:
    """uint8 [..., 3] → uint8 [..., 3]: each pixel's (r, g, b) / (r + g + b) (with 1 added to
    each channel, so black is grey), times 255. Multiplying a pixel's colour by a factor, as a
    shadow or the exposure does, changes it by at most 5 levels in 255 while the darkened
    pixel's r + g + b is at least 96 (the rounding of dark pixels bounds it)."""
    x = rgb.astype(jnp.float32) + 1.0
    c = x / jnp.sum(x, axis=-1, keepdims=True)
    return jnp.round(c * 255.0).astype(jnp.uint8)


def image(spec: ObsSpec, frame, seg: Segmenter | None) -> jax.Array:
    """The image part of an observation from a rendered `render.Frame` (one world)."""
    if spec.kind == "rgb":
        return frame.rgb
    if spec.kind == "chroma":
        return chromaticity(frame.rgb)
    if spec.kind == "mask":
        if seg is None or seg.module is None:
            mask = frame.mask
        else:

            mask = seg_model.predict_mask(seg.module, seg.variables, frame.rgb[None],
                                          seg.threshold)[0]
        return mask[..., None].astype(jnp.uint8)
    if seg is None or seg.module is None:
        raise ValueError("observation.kind: 'features' needs a segmenter checkpoint")
    return features(seg, frame.rgb)


def observe(spec: ObsSpec, frame, seg: Segmenter | None, vel: jax.Array,
            prev_action: jax.Array, limits: jax.Array) -> dict[str, jax.Array]:
    """The observation dict of one world: image from `frame`, and with `spec.proprio`
    (vel [2] measured (v, ω) / limits, prev_action [2])."""
    out = {"image": image(spec, frame, seg)}
    if spec.proprio:
        out["proprio"] = jnp.concatenate([jnp.clip(vel / limits, -3.0, 3.0),
                                          prev_action]).astype(jnp.float32)
    return out


def camera_jitter(cam_pos: jax.Array, cam_rot: jax.Array, jitter: jax.Array
                  ) -> tuple[jax.Array, jax.Array]:
    """The camera moved by `jitter` [3] = (height offset [m] along world z, pitch [rad] about
    the camera's right axis, roll [rad] about its optical axis). cam_rot columns: right, up,
    backward (MuJoCo)."""
    dz, pitch, roll = jitter[0], jitter[1], jitter[2]
    cp, sp, cr, sr = jnp.cos(pitch), jnp.sin(pitch), jnp.cos(roll), jnp.sin(roll)
    rx = jnp.array([[1.0, 0.0, 0.0], [0.0, 1.0, 0.0], [0.0, 0.0, 1.0]])
    rx = rx.at[1, 1].set(cp).at[1, 2].set(-sp).at[2, 1].set(sp).at[2, 2].set(cp)
    rz = jnp.eye(3).at[0, 0].set(cr).at[0, 1].set(-sr).at[1, 0].set(sr).at[1, 1].set(cr)
    return cam_pos + jnp.stack([0.0, 0.0, dz]), cam_rot @ rx @ rz


def segmenter_for(run, spec: ObsSpec) -> Segmenter | None:
    """The segmenter an observation of `spec` needs under `run`'s perception section: None for
    "rgb", and for "mask" with `perception.source` "ground_truth" (the renderer's mask); else
    the checkpoint `perception.checkpoint` ('shipped': the crop's or the all-crop model) with
    `perception.threshold`. ValueError naming `perception.checkpoint` when it is missing."""
    if not spec.needs_segmenter or (spec.kind == "mask"
                                    and run.perception.source == "ground_truth"):
        return None
    from pathlib import Path


    ck = run.perception.checkpoint
    if ck == "shipped":
        ck = run.preset
    elif not Path(ck).expanduser().is_absolute() and not Path(ck).exists():
        ck = str(Path(run.base_dir) / ck)
    try:
        module, variables = perception.load_segmenter(ck, run.preset)
    except ValueError as e:
        raise ValueError(f"perception.checkpoint: {e}") from None
    return Segmenter(variables=variables, threshold=jnp.float32(run.perception.threshold),
                     module=module)
