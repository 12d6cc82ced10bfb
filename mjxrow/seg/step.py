"""The segmenter's optimisation step: the losses, the train state, the optimiser and its
schedule, and the jitted step (its batch augmented, or made inside from a key). The loop with
resume is `mjxrow.seg.training`.

The loss default is the paper's IoU loss 1 − Σyp / Σ(y + p − yp) with p = sigmoid(logit), summed
over the pixels of EACH image and averaged over the batch (+1 smoothing in numerator and
denominator, so images without plants still push p → 0).
"""

from __future__ import annotations

from collections.abc import Callable
from typing import Any

import jax
import jax.numpy as jnp
import optax
from flax import struct

from mjxrow.seg.data import augment
from mjxrow.seg.model import SegNet


def iou_loss(logits: jax.Array, mask: jax.Array, weight: jax.Array | None = None,
             smooth: float = 1.0) -> jax.Array:
    """Paper's IoU loss, per image then (weighted) mean over the batch.

    logits float [B, H, W], mask bool [B, H, W], weight [B] (0 drops an image) → scalar."""
    p = jax.nn.sigmoid(logits.astype(jnp.float32))
    y = mask.astype(jnp.float32)
    inter = jnp.sum(y * p, axis=(1, 2))
    union = jnp.sum(y + p - y * p, axis=(1, 2))
    per_image = 1.0 - (inter + smooth) / (union + smooth)
    return _wmean(per_image, weight)


def bce_loss(logits: jax.Array, mask: jax.Array, weight: jax.Array | None = None) -> jax.Array:
    """Binary cross-entropy per pixel, mean per image, (weighted) mean over the batch."""
    per_pixel = optax.sigmoid_binary_cross_entropy(logits.astype(jnp.float32),
                                                   mask.astype(jnp.float32))
    return _wmean(jnp.mean(per_pixel, axis=(1, 2)), weight)


LOSSES: dict[str, Callable[..., jax.Array]] = {"iou": iou_loss, "bce": bce_loss}


def _wmean(x: jax.Array, weight: jax.Array | None) -> jax.Array:
    if weight is None:
        return jnp.mean(x)
    w = weight.astype(jnp.float32)
    return jnp.sum(x * w) / jnp.maximum(jnp.sum(w), 1.0)


@struct.dataclass
class TrainState:
    step: jax.Array  # int32 []
    params: Any
    batch_stats: Any
    opt_state: Any
    rng: jax.Array  # uint32 [2], raw key data of the run's base key
    best_iou: jax.Array  # float32 [], best validation IoU so far (−1 before any)

    def variables(self) -> dict:
        return {"params": self.params, "batch_stats": self.batch_stats}


def make_schedule(lr: float, steps: int, warmup: int = 0) -> optax.Schedule:
    """Linear warmup from 0 over `warmup` steps, then cosine decay to lr/100 at `steps`."""
    if warmup > 0:
        return optax.warmup_cosine_decay_schedule(0.0, lr, warmup, max(steps, warmup + 1),
                                                  lr / 100)
    return optax.cosine_decay_schedule(lr, max(steps, 1), 0.01)


def make_optimizer(lr: float | optax.Schedule, weight_decay: float = 1e-4,
                   clip: float = 1.0) -> optax.GradientTransformation:
    """AdamW (learning rate or schedule) with weight decay on conv kernels only (ndim > 1) and
    global-norm gradient clipping."""
    decay_mask = lambda p: jax.tree.map(lambda x: x.ndim > 1, p)  # noqa: E731
    return optax.chain(optax.clip_by_global_norm(clip),
                       optax.adamw(lr, weight_decay=weight_decay, mask=decay_mask))


def init_state(variables: dict, tx: optax.GradientTransformation, seed: int = 0) -> TrainState:
    params = variables["params"]
    return TrainState(jnp.zeros((), jnp.int32), params, variables.get("batch_stats", {}),
                      tx.init(params), jax.random.key_data(jax.random.key(seed)),
                      jnp.array(-1.0, jnp.float32))


@jax.jit
def batch_key(rng: jax.Array, step: jax.Array) -> jax.Array:
    """The key of step `step`'s batch: fused into the step or made before it, the same data."""
    return jax.random.fold_in(jax.random.fold_in(rng, step), 0)


def make_step(module: SegNet, tx: optax.GradientTransformation, loss: str = "iou",
              flip: float = 0.5, grey: float = 0.2, jitter: float = 0.0,
              batch_fn: Callable[[jax.Array], tuple[jax.Array, jax.Array]] | None = None):
    """One optimisation step (pure; jit it). Without `batch_fn`:
    `step(state, rgb uint8 [B,H,W,3], mask bool [B,H,W]) -> (state, {"loss"})`; with a jittable
    `batch_fn(key) -> (rgb, mask)` the batch is made inside: `step(state) -> (state, metrics)`,
    its key being batch_key(rng, step), so a resumed run sees the same data."""
    if loss not in LOSSES:
        raise ValueError(f"loss: unknown loss {loss!r}; expected one of {tuple(LOSSES)}")
    loss_fn = LOSSES[loss]

    def step(state: TrainState, rgb: jax.Array, mask: jax.Array):
        if flip > 0 or grey > 0 or jitter > 0:
            key = jax.random.fold_in(jax.random.wrap_key_data(state.rng), state.step)
            rgb, mask = augment(jax.random.fold_in(key, 1), rgb, mask, flip=flip, grey=grey,
                                jitter=jitter)

        def objective(params):
            logits, upd = module.apply({"params": params, "batch_stats": state.batch_stats},
                                       rgb, train=True, mutable=["batch_stats"])
            return loss_fn(logits, mask), upd["batch_stats"]

        (value, stats), grads = jax.value_and_grad(objective, has_aux=True)(state.params)
        updates, opt_state = tx.update(grads, state.opt_state, state.params)
        params = optax.apply_updates(state.params, updates)
        new = state.replace(step=state.step + 1, params=params, batch_stats=stats,
                            opt_state=opt_state)
        return new, {"loss": value}

    if batch_fn is None:
        return step

    def fused(state: TrainState):
        rgb, mask = batch_fn(batch_key(jax.random.wrap_key_data(state.rng), state.step))
        return step(state, rgb, mask)

    return fused
