"""ONNX export of a trained segmenter (the work of `python -m mjxrow.seg.export`; its parser and
the graph's description: `mjxrow.seg.export`): `to_onnx` writes the graph with `onnx.helper` from
the resolved architecture (`model.plan`) and the variables, BatchNorm folded into the
convolutions; `run_onnx` runs it with onnxruntime.
"""

from __future__ import annotations

import sys
from pathlib import Path
from typing import Any

import jax
import numpy as np

from mjxrow import files
from mjxrow.seg import checkpoint
from mjxrow.seg import export as command
from mjxrow.seg.model import BN_EPS, MEAN, STD, SegNet, apply

OPSET = 17


class _Graph:
    """Accumulates ONNX nodes and initializers with unique names."""

    def __init__(self):
        import onnx
        from onnx import helper, numpy_helper
        self.onnx, self.helper, self.numpy_helper = onnx, helper, numpy_helper
        self.nodes, self.inits, self.n = [], [], 0

    def name(self, base: str) -> str:
        self.n += 1
        return f"{base}_{self.n}"

    def const(self, base: str, value: np.ndarray) -> str:
        name = self.name(base)
        self.inits.append(self.numpy_helper.from_array(np.asarray(value), name))
        return name

    def op(self, op_type: str, inputs: list[str], base: str | None = None, **attrs: Any) -> str:
        out = self.name(base or op_type.lower())
        self.nodes.append(self.helper.make_node(op_type, inputs, [out], **attrs))
        return out


def _f32(x) -> np.ndarray:
    return np.asarray(x, np.float32)


def _conv(g: _Graph, x: str, kernel, bias=None, bn=None, stats=None, stride: int = 1,
          dilation: int = 1, groups: int = 1, base: str = "conv") -> str:
    """Conv from a flax HWIO kernel; `bn`/`stats` (BatchNorm scale/bias, mean/var) folded in."""
    w = _f32(kernel).transpose(3, 2, 0, 1)  # HWIO → OIHW ([C, 1, k, k] when depthwise)
    b = np.zeros(w.shape[0], np.float32) if bias is None else _f32(bias)
    if bn is not None:
        s = _f32(bn["scale"]) / np.sqrt(_f32(stats["var"]) + BN_EPS)
        w = w * s[:, None, None, None]
        b = (b - _f32(stats["mean"])) * s + _f32(bn["bias"])
    k = w.shape[-1]
    p = (k - 1) // 2 * dilation
    return g.op("Conv", [x, g.const(base + "_w", w), g.const(base + "_b", b)], base,
                kernel_shape=[k, k], strides=[stride, stride], dilations=[dilation, dilation],
                pads=[p, p, p, p], group=groups)


def _act(g: _Graph, x: str, act: str | None) -> str:
    if act is None:
        return x
    return g.op("Relu", [x]) if act == "RE" else g.op("HardSwish", [x])


def _convbn(g: _Graph, x: str, p: dict, s: dict, act: str | None, stride: int = 1,
            dilation: int = 1, groups: int = 1, base: str = "conv") -> str:
    return _act(g, _conv(g, x, p["conv"]["kernel"], None, p["bn"], s["bn"], stride, dilation,
                         groups, base), act)


def _resize(g: _Graph, x: str, sizes: str) -> str:
    return g.op("Resize", [x, "", "", sizes], "resize", mode="linear",
                coordinate_transformation_mode="half_pixel")


def to_onnx(module: SegNet, variables: dict, image_size: int | tuple[int, int] = 224,
            batch: int | None = 1):
    """ONNX ModelProto of `module` with `variables` for images of `image_size` (side or (H, W));
    batch None makes the batch axis dynamic."""
    g = _Graph()
    helper, tp = g.helper, g.onnx.TensorProto
    h, w = (image_size, image_size) if isinstance(image_size, int) else image_size
    plan = module.resolved()
    P, S = variables["params"], variables["batch_stats"]
    pb, sb = P["backbone"], S["backbone"]

    x = g.op("Cast", ["rgb"], "float", to=tp.FLOAT)
    x = g.op("Transpose", [x], "nchw", perm=[0, 3, 1, 2])
    scale = (1.0 / (255.0 * _f32(STD))).reshape(1, 3, 1, 1)
    shift = (-_f32(MEAN) / _f32(STD)).reshape(1, 3, 1, 1)
    x = g.op("Add", [g.op("Mul", [x, g.const("norm_scale", scale)]), g.const("norm_shift", shift)])

    x = _convbn(g, x, pb["stem"], sb["stem"], "HS", 2, base="stem")
    low = x
    for i, ly in enumerate(plan.layers):
        p, s = pb[f"block{i}"], sb[f"block{i}"]
        y = x
        if ly.exp != ly.cin:
            y = _convbn(g, y, p["expand"], s["expand"], ly.act, base=f"b{i}_expand")
        y = _convbn(g, y, p["dw"], s["dw"], ly.act, ly.stride, ly.dilation, ly.exp, f"b{i}_dw")
        if ly.se:
            z = g.op("GlobalAveragePool", [y])
            z = g.op("Relu", [_conv(g, z, p["se_reduce"]["kernel"], p["se_reduce"]["bias"],
                                    base=f"b{i}_se1")])
            z = _conv(g, z, p["se_expand"]["kernel"], p["se_expand"]["bias"], base=f"b{i}_se2")
            y = g.op("Mul", [y, g.op("HardSigmoid", [z], alpha=1.0 / 6.0, beta=0.5)])
        y = _convbn(g, y, p["project"], s["project"], None, base=f"b{i}_project")
        x = g.op("Add", [x, y]) if ly.residual else y
        if i == plan.low_index:
            low = x
    high = _convbn(g, x, pb["last"], sb["last"], "HS", base="last")

    ph, sh = P["head"], S["head"]
    y = _convbn(g, high, ph["cbr"], sh["cbr"], "RE", base="cbr")
    gate = _conv(g, g.op("GlobalAveragePool", [high]), ph["scale"]["kernel"], base="scale")
    y = g.op("Mul", [y, g.op("Sigmoid", [gate])])
    low_shape = g.op("Shape", [low])
    y = _resize(g, y, g.op("Concat", [g.op("Slice", [g.op("Shape", [y]),
                                                     g.const("i0", np.array([0], np.int64)),
                                                     g.const("i2", np.array([2], np.int64))]),
                                      g.op("Slice", [low_shape,
                                                     g.const("i2", np.array([2], np.int64)),
                                                     g.const("i4", np.array([4], np.int64))])],
                                axis=0))
    y = g.op("Add", [_conv(g, low, ph["low_cls"]["kernel"], ph["low_cls"]["bias"], base="low"),
                     _conv(g, y, ph["high_cls"]["kernel"], ph["high_cls"]["bias"], base="high")])
    in_shape = g.op("Shape", ["rgb"])
    sizes = g.op("Concat", [g.op("Slice", [in_shape, g.const("i0", np.array([0], np.int64)),
                                           g.const("i1", np.array([1], np.int64))]),
                            g.const("one", np.array([1], np.int64)),
                            g.op("Slice", [in_shape, g.const("i1", np.array([1], np.int64)),
                                           g.const("i3", np.array([3], np.int64))])], axis=0)
    y = _resize(g, y, sizes)
    g.nodes.append(helper.make_node("Squeeze", [y, g.const("ax1", np.array([1], np.int64))],
                                    ["logits"]))
    n = "N" if batch is None else batch
    graph = helper.make_graph(
        g.nodes, "mjxrow_segnet",
        [helper.make_tensor_value_info("rgb", tp.UINT8, [n, h, w, 3])],
        [helper.make_tensor_value_info("logits", tp.FLOAT, [n, h, w])], g.inits)
    model = helper.make_model(graph, opset_imports=[helper.make_opsetid("", OPSET)],
                              producer_name="mjxrow")
    model.ir_version = min(model.ir_version, 9)
    g.onnx.checker.check_model(model)
    return model


def save_onnx(module: SegNet, variables: dict, path: str | Path,
              image_size: int | tuple[int, int] = 224, batch: int | None = 1) -> Path:
    """Write the ONNX model to `path`; returns the path."""
    import onnx
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    onnx.save(to_onnx(module, variables, image_size, batch), str(path))
    return path


def run_onnx(model_or_path, rgb: np.ndarray) -> np.ndarray:
    """Logits float32 [N, H, W] of `rgb uint8 [N, H, W, 3]` through onnxruntime (CPU)."""
    import onnxruntime as ort
    src = str(model_or_path) if isinstance(model_or_path, (str, Path)) else \
        model_or_path.SerializeToString()
    sess = ort.InferenceSession(src, providers=["CPUExecutionProvider"])
    return sess.run(["logits"], {"rgb": np.asarray(rgb, np.uint8)})[0]


def require_onnx() -> None:
    """ValueError naming the `[export]` extra when onnx or onnxruntime is not installed."""
    import importlib.util

    missing = [m for m in ("onnx", "onnxruntime") if importlib.util.find_spec(m) is None]
    if missing:
        raise ValueError(f"ONNX export needs {' and '.join(missing)}: install them with "
                         "pip install -e '.[export]' (or pip install onnx onnxruntime)")


MAX_SIZE = 2048  # px, the largest input side (limits.VALUES["camera.width"])


def cli(argv: list[str] | None = None) -> int:
    """`main` as a command: 0, or 2 with a one-line error (onnx missing, a missing or damaged
    checkpoint, an output file that cannot be written)."""
    try:
        main(argv)
    except (ValueError, OSError) as e:
        print(f"error: {e}", file=sys.stderr)
        return 2
    return 0


def main(argv: list[str] | None = None) -> None:
    """`python -m mjxrow.seg.export ARGS` as a function (raises ValueError or OSError)."""
    args = command.parser().parse_args(argv)
    if not 16 <= args.size <= MAX_SIZE:  # 16: the model's output stride
        raise ValueError(f"--size: {args.size} px is not an image side in [16, {MAX_SIZE}] px")
    if not 0 <= args.check <= 1000:
        raise ValueError(f"--check: {args.check} images; give 0 (no check) to 1000")
    require_onnx()
    files.check_out_file(args.out, "--out")
    module, variables = checkpoint.load(args.crop or args.ckpt)
    path = save_onnx(module, variables, args.out, args.size,
                     None if args.dynamic_batch else 1)
    print(f"wrote {path} ({path.stat().st_size / 1e6:.2f} MB)")
    if args.check > 0:
        rgb = np.random.default_rng(0).integers(0, 256, (args.check, args.size, args.size, 3),
                                                dtype=np.uint8)
        if args.dynamic_batch:
            ref, got = np.asarray(jax.jit(lambda x: apply(module, variables, x))(rgb)), \
                run_onnx(path, rgb)
        else:
            f = jax.jit(lambda x: apply(module, variables, x))
            ref = np.concatenate([np.asarray(f(rgb[i:i + 1])) for i in range(len(rgb))])
            got = np.concatenate([run_onnx(path, rgb[i:i + 1]) for i in range(len(rgb))])
        err = float(np.abs(ref - got).max())
        print(f"max |onnx − flax| over {args.check} images: {err:.2e}")
        if err > 1e-3:
            raise SystemExit(f"ONNX output differs from Flax by {err:.2e} > 1e-3")
