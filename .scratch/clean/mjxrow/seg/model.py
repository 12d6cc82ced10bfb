"""MobileNetV3 (Howard et al., "Searching for MobileNetV3", 2019) + LR-ASPP head in Flax linen.

The network maps `rgb: uint8 [B, H, W, 3]` to one plant logit per pixel, `float32 [B, H, W]`
(normalisation inside). Backbones follow the published stage tables (Large: 15 bottlenecks, Small:
11) with inverted residual blocks, squeeze-and-excite (hard-sigmoid gate) and ReLU / hard-swish;
the width multiplier rounds channels as the reference implementations do (`make_divisible`).
As in the paper's segmentation set-up, the last stage is dilated (output stride 16) and can be
halved in channels (`reduced_tail`). The LR-ASPP head (torchvision's `LRASPPHead`): 1/16 features
→ 1×1 conv + BN + ReLU, gated by global average pool → 1×1 conv → sigmoid; upsampled ×2 and added
to a 1×1 classifier of the 1/8 features; bilinear upsampling to the input size.

Padding is explicit and symmetric ((k − 1)/2 · dilation, as in the published models), so the
exported ONNX graph (`mjxrow.seg.onnx_export`) reproduces it exactly.
"""

from __future__ import annotations

import dataclasses
from typing import Any

import flax.linen as nn
import jax
import jax.numpy as jnp
import numpy as np

from mjxrow.seg.convs import DepthwiseConv, Pointwise

ARCHS = ("large", "small", "tiny")
BN_EPS = 1e-3
MEAN = (0.485, 0.456, 0.406)  # ImageNet statistics of RGB in [0, 1]
STD = (0.229, 0.224, 0.225)


@dataclasses.dataclass(frozen=True)
class Bneck:
    """One row of a published stage table."""

    kernel: int
    exp: int  # expansion size (channels of the depthwise conv)
    out: int  # output channels
    se: bool  # squeeze-and-excite
    act: str  # "RE" (ReLU) or "HS" (hard-swish)
    stride: int


# Howard et al. 2019, Table 1 (Large) and Table 2 (Small); stem 16 channels, hard-swish.
LARGE = (
    Bneck(3, 16, 16, False, "RE", 1), Bneck(3, 64, 24, False, "RE", 2),
    Bneck(3, 72, 24, False, "RE", 1), Bneck(5, 72, 40, True, "RE", 2),
    Bneck(5, 120, 40, True, "RE", 1), Bneck(5, 120, 40, True, "RE", 1),
    Bneck(3, 240, 80, False, "HS", 2), Bneck(3, 200, 80, False, "HS", 1),
    Bneck(3, 184, 80, False, "HS", 1), Bneck(3, 184, 80, False, "HS", 1),
    Bneck(3, 480, 112, True, "HS", 1), Bneck(3, 672, 112, True, "HS", 1),
    Bneck(5, 672, 160, True, "HS", 2), Bneck(5, 960, 160, True, "HS", 1),
    Bneck(5, 960, 160, True, "HS", 1),
)
SMALL = (
    Bneck(3, 16, 16, True, "RE", 2), Bneck(3, 72, 24, False, "RE", 2),
    Bneck(3, 88, 24, False, "RE", 1), Bneck(5, 96, 40, True, "HS", 2),
    Bneck(5, 240, 40, True, "HS", 1), Bneck(5, 240, 40, True, "HS", 1),
    Bneck(5, 120, 48, True, "HS", 1), Bneck(5, 144, 48, True, "HS", 1),
    Bneck(5, 288, 96, True, "HS", 2), Bneck(5, 576, 96, True, "HS", 1),
    Bneck(5, 576, 96, True, "HS", 1),
)
# A few-channel variant for tests: same block types, strides 2/4/8/16.
TINY = (
    Bneck(3, 16, 8, True, "RE", 2), Bneck(3, 24, 16, False, "HS", 2),
    Bneck(3, 32, 16, True, "HS", 2),
)
# arch → (stem channels, table, last conv channels as a multiple of the last block's output)
TABLES = {"large": (16, LARGE, 6), "small": (16, SMALL, 6), "tiny": (8, TINY, 2)}


def make_divisible(v: float, divisor: int = 8, min_value: int | None = None) -> int:
    """Round channels to a multiple of `divisor`, never 10 % or more below `v` (reference rule)."""
    min_value = divisor if min_value is None else min_value
    new_v = max(min_value, int(v + divisor / 2) // divisor * divisor)
    if new_v < 0.9 * v:
        new_v += divisor
    return int(new_v)


@dataclasses.dataclass(frozen=True)
class Layer:
    """A resolved bottleneck: channels after the width multiplier, stride and dilation."""

    cin: int
    exp: int
    out: int
    kernel: int
    stride: int
    dilation: int
    se: int  # squeeze channels, 0 without SE
    act: str

    @property
    def residual(self) -> bool:
        return self.stride == 1 and self.cin == self.out


@dataclasses.dataclass(frozen=True)
class Plan:
    """The whole resolved network: stem channels, blocks, last conv, which block feeds 1/8."""

    stem: int
    layers: tuple[Layer, ...]
    last: int
    low_index: int  # index of the block whose output is the 1/8 feature map
    low_channels: int


def plan(arch: str, width: float = 1.0, output_stride: int = 16,
         reduced_tail: bool = False) -> Plan:
    """Resolve a stage table: width multiplier, dilation beyond `output_stride`, reduced tail."""
    if arch not in TABLES:
        raise ValueError(f"arch: unknown architecture {arch!r}; expected one of {ARCHS}")
    if not width > 0:
        raise ValueError(f"width: must be positive, got {width}")
    if output_stride not in (8, 16, 32):
        raise ValueError(f"output_stride: expected 8, 16 or 32, got {output_stride}")
    stem_c, table, last_mult = TABLES[arch]
    ch = lambda c: make_divisible(c * width)  # noqa: E731
    rows = list(table)
    if reduced_tail:  # the last stage (from the last stride-2 row) halves its channels
        start = max(i for i, r in enumerate(rows) if r.stride == 2)
        rows = rows[:start] + [dataclasses.replace(r, exp=r.exp // 2 if i > start else r.exp,
                                                   out=r.out // 2)
                               for i, r in enumerate(rows[start:], start)]
    layers, cin, stride, dilation, low = [], ch(stem_c), 2, 1, -1
    for i, r in enumerate(rows):
        s = r.stride
        if s > 1 and stride * s > output_stride:
            dilation, s = dilation * s, 1
        else:
            stride *= s
        exp, out = ch(r.exp), ch(r.out)
        layers.append(Layer(cin, exp, out, r.kernel, s, dilation,
                            make_divisible(exp // 4) if r.se else 0, r.act))
        if stride == 8:
            low = i
        cin = out
    if low < 0:
        raise ValueError(f"arch {arch!r}: no block at stride 8 for the LR-ASPP head")
    return Plan(ch(stem_c), tuple(layers), ch(last_mult * rows[-1].out), low, layers[low].out)


def _act(name: str, x: jax.Array) -> jax.Array:
    return jax.nn.relu(x) if name == "RE" else jax.nn.hard_swish(x)


class ConvBN(nn.Module):
    """k×k conv (no bias) + BatchNorm + optional activation ("RE", "HS" or None).

    `depthwise=True` makes the conv depthwise (one k×k filter per channel)."""

    features: int
    kernel: int = 1
    stride: int = 1
    dilation: int = 1
    depthwise: bool = False
    act: str | None = None
    momentum: float = 0.9
    dtype: Any = jnp.float32
    dw_impl: str = "auto"
    pw_impl: str = "auto"

    @nn.compact
    def __call__(self, x: jax.Array, train: bool) -> jax.Array:
        if self.depthwise:
            x = DepthwiseConv(self.kernel, self.stride, self.dilation, self.dw_impl, self.dtype,
                              name="conv")(x)
        elif self.kernel == 1 and self.stride == 1:
            x = Pointwise(self.features, impl=self.pw_impl, dtype=self.dtype, name="conv")(x)
        else:
            p = (self.kernel - 1) // 2 * self.dilation
            x = nn.Conv(self.features, (self.kernel, self.kernel), (self.stride, self.stride),
                        padding=((p, p), (p, p)),
                        kernel_dilation=(self.dilation, self.dilation), use_bias=False,
                        dtype=self.dtype, name="conv")(x)
        x = nn.BatchNorm(use_running_average=not train, momentum=self.momentum, epsilon=BN_EPS,
                         dtype=self.dtype, name="bn")(x)
        return x if self.act is None else _act(self.act, x)


class Block(nn.Module):
    """Inverted residual: [1×1 expand] → k×k depthwise → [SE] → 1×1 project (+ identity)."""

    layer: Layer
    momentum: float = 0.9
    dtype: Any = jnp.float32
    dw_impl: str = "auto"
    pw_impl: str = "auto"

    @nn.compact
    def __call__(self, x: jax.Array, train: bool) -> jax.Array:
        ly = self.layer
        kw = dict(momentum=self.momentum, dtype=self.dtype, pw_impl=self.pw_impl)
        y = x
        if ly.exp != ly.cin:
            y = ConvBN(ly.exp, act=ly.act, name="expand", **kw)(y, train)
        y = ConvBN(ly.exp, ly.kernel, ly.stride, ly.dilation, depthwise=True, act=ly.act,
                   dw_impl=self.dw_impl, name="dw", **kw)(y, train)
        if ly.se:
            s = jnp.mean(y, axis=(1, 2), keepdims=True)
            pw = dict(use_bias=True, impl=self.pw_impl, dtype=self.dtype)
            s = jax.nn.relu(Pointwise(ly.se, name="se_reduce", **pw)(s))
            s = jax.nn.hard_sigmoid(Pointwise(ly.exp, name="se_expand", **pw)(s))
            y = y * s
        y = ConvBN(ly.out, name="project", **kw)(y, train)
        return x + y if ly.residual else y


class MobileNetV3(nn.Module):
    """Backbone: x float [B, H, W, 3] (normalised) → (1/8 features, last conv features)."""

    plan: Plan
    momentum: float = 0.9
    dtype: Any = jnp.float32
    dw_impl: str = "auto"
    pw_impl: str = "auto"

    @nn.compact
    def __call__(self, x: jax.Array, train: bool) -> tuple[jax.Array, jax.Array]:
        kw = dict(momentum=self.momentum, dtype=self.dtype, pw_impl=self.pw_impl)
        x = ConvBN(self.plan.stem, 3, 2, act="HS", name="stem", **kw)(x, train)
        low = x
        for i, layer in enumerate(self.plan.layers):
            x = Block(layer, name=f"block{i}", dw_impl=self.dw_impl, **kw)(x, train)
            if i == self.plan.low_index:
                low = x
        x = ConvBN(self.plan.last, act="HS", name="last", **kw)(x, train)
        return low, x


class LRASPP(nn.Module):
    """Lite R-ASPP head: (low [B, h8, w8, Cl], high [B, h16, w16, Ch]) → logits [B, h8, w8, 1]."""

    channels: int = 128
    momentum: float = 0.9
    dtype: Any = jnp.float32
    pw_impl: str = "auto"

    @nn.compact
    def __call__(self, low: jax.Array, high: jax.Array, train: bool) -> jax.Array:
        x = ConvBN(self.channels, act="RE", momentum=self.momentum, dtype=self.dtype,
                   pw_impl=self.pw_impl, name="cbr")(high, train)
        g = jnp.mean(high, axis=(1, 2), keepdims=True)
        pw = dict(impl=self.pw_impl, dtype=self.dtype)
        g = jax.nn.sigmoid(Pointwise(self.channels, name="scale", **pw)(g))
        x = x * g
        b, h, w, _ = low.shape
        x = jax.image.resize(x, (b, h, w, x.shape[-1]), "bilinear")
        return (Pointwise(1, use_bias=True, name="low_cls", **pw)(low)
                + Pointwise(1, use_bias=True, name="high_cls", **pw)(x))


class SegNet(nn.Module):
    """MobileNetV3 + LR-ASPP plant segmenter.

    `__call__(rgb: uint8 [B, H, W, 3], train=False) -> logits float32 [B, H, W]`; H and W should be
    multiples of 16 (the output is resized to the input size in any case). BatchNorm statistics
    live in the `batch_stats` collection (mutable when `train=True`).
    """

    arch: str = "small"
    width: float = 1.0
    output_stride: int = 16
    reduced_tail: bool = False
    head_channels: int = 128
    momentum: float = 0.9
    dtype: str = "float32"  # compute dtype ("float32" or "bfloat16"); parameters stay float32
    dw_impl: str = "auto"  # depthwise conv: "auto" (shift on CPU, phases elsewhere), convs.DW_IMPLS
    pw_impl: str = "auto"  # 1×1 conv: "auto" (dot), convs.PW_IMPLS

    def config(self) -> dict[str, Any]:
        """JSON-friendly attributes (`SegNet(**module.config())` rebuilds the module)."""
        return {f.name: getattr(self, f.name) for f in dataclasses.fields(self)
                if f.name not in ("parent", "name")}

    def resolved(self) -> Plan:
        return plan(self.arch, self.width, self.output_stride, self.reduced_tail)

    @nn.compact
    def __call__(self, rgb: jax.Array, train: bool = False) -> jax.Array:
        if rgb.ndim != 4 or rgb.shape[-1] != 3:
            raise ValueError(f"rgb: expected uint8 [B, H, W, 3], got shape {rgb.shape}")
        dt = jnp.dtype(self.dtype)
        x = (rgb.astype(jnp.float32) / 255.0 - jnp.array(MEAN)) / jnp.array(STD)
        kw = dict(momentum=self.momentum, dtype=dt)
        low, high = MobileNetV3(self.resolved(), dw_impl=self.dw_impl, pw_impl=self.pw_impl,
                                name="backbone", **kw)(x.astype(dt), train)
        y = LRASPP(self.head_channels, pw_impl=self.pw_impl, name="head", **kw)(low, high, train)
        b, h, w, _ = rgb.shape
        y = jax.image.resize(y.astype(jnp.float32), (b, h, w, 1), "bilinear")
        return y[..., 0]


def create(arch: str = "small", width: float = 1.0, key: jax.Array | int | None = None,
           image_size: int | tuple[int, int] = 224, **options: Any) -> tuple[SegNet, dict]:
    """A SegNet and its initial variables {'params', 'batch_stats'} (float32 pytrees).

    key: jax key or int seed. The variables are drawn on the host (`init_host`: shapes from
    `jax.eval_shape`, values from numpy), which costs no XLA compile. `image_size`: side (or (H, W))
    of the dummy input; the net itself is fully convolutional. `options`: further SegNet
    attributes (output_stride, reduced_tail, dtype, dw_impl, ...)."""
    module = SegNet(arch=arch, width=float(width), **options)
    module.resolved()  # validates arch / width / output_stride
    if key is None:
        seed = [0]
    elif isinstance(key, int):
        seed = [key]
    else:
        data = key if jnp.issubdtype(key.dtype, jnp.unsignedinteger) else jax.random.key_data(key)
        seed = [int(v) for v in np.asarray(data).ravel()]
    return module, init_host(abstract_variables(module, image_size), seed)


def init_host(abstract: dict, seed: int | list[int] = 0) -> dict:
    """Initial values for the variables described by `abstract` (ShapeDtypeStructs), as flax's
    defaults: conv kernels lecun-normal (truncated at ±2σ, fan-in = all axes but the last),
    biases 0, BatchNorm scale 1 / bias 0, running mean 0 / var 1. Host numpy, deterministic."""
    rng = np.random.default_rng(seed)

    def leaf(path, s):
        name = getattr(path[-1], "key", str(path[-1]))
        if name == "kernel":
            fan_in = int(np.prod(s.shape[:-1]))
            z = rng.standard_normal(s.shape)
            bad = np.abs(z) > 2
            while bad.any():
                z[bad] = rng.standard_normal(int(bad.sum()))
                bad = np.abs(z) > 2
            return jnp.asarray(z / 0.87962566103423978 / np.sqrt(fan_in), s.dtype)
        one = name in ("scale", "var")
        return jnp.ones(s.shape, s.dtype) if one else jnp.zeros(s.shape, s.dtype)

    return dict(jax.tree_util.tree_map_with_path(leaf, dict(abstract)))


def apply(module: SegNet, variables: dict, rgb: jax.Array) -> jax.Array:
    """Inference logits: `rgb uint8 [B, H, W, 3]` → `float32 [B, H, W]` (running BN statistics)."""
    return module.apply(variables, rgb, train=False)


def predict_mask(module: SegNet, variables: dict, rgb: jax.Array,
                 threshold: float = 0.7) -> jax.Array:
    """Plant mask `bool [B, H, W]`: sigmoid(logit) > threshold (0.7 as the paper)."""
    return jax.nn.sigmoid(apply(module, variables, rgb)) > threshold


def param_count(tree: Any) -> int:
    """Number of scalars in a pytree of arrays or ShapeDtypeStructs."""
    return int(sum(x.size for x in jax.tree.leaves(tree)))


def abstract_variables(module: SegNet, image_size: int | tuple[int, int] = 64) -> dict:
    """Shapes and dtypes of a module's variables, computed without allocating (eval_shape)."""
    h, w = (image_size, image_size) if isinstance(image_size, int) else image_size
    x = jax.ShapeDtypeStruct((1, h, w, 3), jnp.uint8)
    return jax.eval_shape(lambda k, x: module.init(k, x), jax.random.key(0), x)
