"""The segmenter's convolutions in several implementations, one set of parameters.

The depthwise k×k conv (`DepthwiseConv`) and the 1×1 conv (`Pointwise`) carry exactly the
parameters of `flax.linen.Conv`, so every checkpoint loads into each implementation, and all
compute the same numbers up to float rounding (tests/test_seg.py). "auto" picks one by backend
(`DW_AUTO`, `PW_AUTO`): the fastest measured there (docs/benchmarks-history.md, 2026-11-25
sixth round).

- depthwise: "conv" (grouped convolution), "shift" (`depthwise_shift`: k² strided slices),
  "mixed" (shift for the dilated convs only), "phases" (grouped convolution, the dilated ones
  as `dilated_as_phases`);
- 1×1: "conv" or "dot" (a matrix product over the channel axis).
"""

from __future__ import annotations

from typing import Any

import flax.linen as nn
import jax
import jax.numpy as jnp

# On a GPU the grouped convolutions of the dilated last stage were two thirds of the
# segmenter's time; as phases the whole net runs 2× faster at 224 px. The 1×1 convs as matrix
# products: the same on a GPU, 22 % faster on the CPU.
DW_IMPLS, DW_AUTO = ("conv", "shift", "mixed", "phases"), {"cpu": "shift", "other": "phases"}
PW_IMPLS, PW_AUTO = ("conv", "dot"), {"cpu": "dot", "other": "dot"}


def depthwise_shift(x: jax.Array, kernel: jax.Array, stride: int, dilation: int) -> jax.Array:
    """Depthwise k×k conv as a sum of k² strided slices × per-channel weights.

    x: [B, H, W, C]; kernel: [k, k, 1, C] (HWIO, as `nn.Conv` with feature_group_count=C);
    symmetric padding (k − 1)/2 · dilation. Same numbers as `lax.conv_general_dilated`, but
    XLA:CPU runs it 10-30× faster than its grouped convolution."""
    k = kernel.shape[0]
    p = (k - 1) // 2 * dilation
    b, h, w, c = x.shape
    xp = jnp.pad(x, ((0, 0), (p, p), (p, p), (0, 0)))
    ho = (h + 2 * p - dilation * (k - 1) - 1) // stride + 1
    wo = (w + 2 * p - dilation * (k - 1) - 1) // stride + 1
    out = None
    for i in range(k):
        for j in range(k):
            sl = jax.lax.slice(xp, (0, i * dilation, j * dilation, 0),
                               (b, i * dilation + (ho - 1) * stride + 1,
                                j * dilation + (wo - 1) * stride + 1, c), (1, stride, stride, 1))
            term = sl * kernel[i, j, 0]
            out = term if out is None else out + term
    return out


def dilated_as_phases(x: jax.Array, dilation: int, conv) -> jax.Array:
    """A stride-1 conv of dilation d as d² undilated convs on the input's phases.

    Output pixel (q·d + r) of a dilated conv reads input pixels ≡ r (mod d) only, so the
    input is split into its d × d phase images (padded with zeros to a multiple of d, which
    the conv's own zero padding would have read), stacked on the batch axis, convolved by
    `conv(x)` without dilation, and interleaved back. Same numbers as the dilated conv."""
    d = dilation
    b, h, w, c = x.shape
    hp, wp = -(-h // d) * d, -(-w // d) * d
    x = jnp.pad(x, ((0, 0), (0, hp - h), (0, wp - w), (0, 0)))
    x = x.reshape(b, hp // d, d, wp // d, d, c).transpose(0, 2, 4, 1, 3, 5)
    y = conv(x.reshape(b * d * d, hp // d, wp // d, c))
    y = y.reshape(b, d, d, hp // d, wp // d, c).transpose(0, 3, 1, 4, 2, 5)
    return y.reshape(b, hp, wp, c)[:, :h, :w]


class DepthwiseConv(nn.Module):
    """Depthwise k×k conv without bias; parameter `kernel [k, k, 1, C]` exactly as `nn.Conv`.

    impl: "conv" (grouped convolution), "shift" (`depthwise_shift`), "mixed" (shift for the
    dilated convs, grouped convolution for the others), "phases" (grouped convolution, the
    dilated ones as `dilated_as_phases`) or "auto" (`DW_AUTO` by backend)."""

    kernel_size: int
    stride: int = 1
    dilation: int = 1
    impl: str = "auto"
    dtype: Any = jnp.float32

    @nn.compact
    def __call__(self, x: jax.Array) -> jax.Array:
        k, c = self.kernel_size, x.shape[-1]
        kernel = self.param("kernel", nn.initializers.lecun_normal(), (k, k, 1, c), jnp.float32)
        x, kernel = x.astype(self.dtype), kernel.astype(self.dtype)
        impl = resolve(self.impl, "depthwise")
        dilated = self.dilation > 1
        if impl == "shift" or (impl == "mixed" and dilated):
            return depthwise_shift(x, kernel, self.stride, self.dilation)

        def conv(x, d=1):
            p = (k - 1) // 2 * d
            return jax.lax.conv_general_dilated(
                x, kernel, (self.stride, self.stride), ((p, p), (p, p)), rhs_dilation=(d, d),
                dimension_numbers=("NHWC", "HWIO", "NHWC"), feature_group_count=c)

        if impl == "phases" and dilated and self.stride == 1:
            return dilated_as_phases(x, self.dilation, conv)
        return conv(x, self.dilation)


def auto_rule(what: str) -> str:
    """What "auto" picks for the "depthwise" or "pointwise" conv, in words (for --help)."""
    auto = DW_AUTO if what == "depthwise" else PW_AUTO
    if auto["cpu"] == auto["other"]:
        return f"auto: {auto['cpu']}"
    return f"auto: {auto['cpu']} on CPU, {auto['other']} elsewhere"


def resolve(impl: str, what: str) -> str:
    """The implementation `impl` of the "depthwise" or "pointwise" conv names, "auto"
    resolved by the default backend (`DW_AUTO`, `PW_AUTO`); ValueError for an unknown one."""
    choices, auto = (DW_IMPLS, DW_AUTO) if what == "depthwise" else (PW_IMPLS, PW_AUTO)
    if impl == "auto":
        return auto["cpu" if jax.default_backend() == "cpu" else "other"]
    if impl not in choices:
        raise ValueError(f"{what}: unknown implementation {impl!r}; expected auto, "
                         + " or ".join(choices))
    return impl


class Pointwise(nn.Module):
    """1×1 conv with the parameters of `nn.Conv` (`kernel [1, 1, Cin, Cout]`, optional `bias`).

    impl: "conv" (`lax.conv_general_dilated`), "dot" (a matrix product over the channel axis,
    which XLA can fuse with its neighbours) or "auto"."""

    features: int
    use_bias: bool = False
    impl: str = "auto"
    dtype: Any = jnp.float32

    @nn.compact
    def __call__(self, x: jax.Array) -> jax.Array:
        cin = x.shape[-1]
        kernel = self.param("kernel", nn.initializers.lecun_normal(),
                            (1, 1, cin, self.features), jnp.float32)
        x, kernel = x.astype(self.dtype), kernel.astype(self.dtype)
        if resolve(self.impl, "pointwise") == "dot":
            y = jax.lax.dot_general(x, kernel[0, 0], (((x.ndim - 1,), (0,)), ((), ())))
        else:
            y = jax.lax.conv_general_dilated(x, kernel, (1, 1), ((0, 0), (0, 0)),
                                             dimension_numbers=("NHWC", "HWIO", "NHWC"))
        if self.use_bias:
            y = y + self.param("bias", nn.initializers.zeros, (self.features,),
                               jnp.float32).astype(self.dtype)
        return y
