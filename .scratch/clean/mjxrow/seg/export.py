"""`python -m mjxrow.seg.export (--crop C | --ckpt PATH) --out model.onnx [--size 224]`: ONNX
export of a trained segmenter, for robots (onnxruntime, TensorRT, OpenVINO, ...).

The graph is written directly with `onnx.helper` from the resolved architecture (`model.plan`) and
the variables, BatchNorm folded into the convolutions: input `rgb uint8 [N, H, W, 3]` (N fixed or
dynamic, H and W fixed), output `logits float32 [N, H, W]` (sigmoid > 0.7 is the plant mask), the
same numbers as `model.apply` (checked to 1e-3 by the tests). Needs the optional packages `onnx`
(and `onnxruntime` to run or check it).
"""

from __future__ import annotations

import argparse
import sys

from mjxrow import commands

# the command's light half (mjxrow.commands): the parser and the hand-over to the heavy module
RUN = "mjxrow.seg.onnx_export"  # the heavy module: its cli(argv) exports


def parser() -> argparse.ArgumentParser:
    p = argparse.ArgumentParser(prog="python -m mjxrow.seg.export", description=__doc__,
                                formatter_class=argparse.RawDescriptionHelpFormatter)
    src = p.add_mutually_exclusive_group(required=True)
    src.add_argument("--crop", help="shipped checkpoint of this crop")
    src.add_argument("--ckpt", help="checkpoint folder")
    p.add_argument("--out", required=True, help="ONNX file to write")
    p.add_argument("--size", type=int, default=224, help="square input side [px]")
    p.add_argument("--dynamic-batch", action="store_true", help="batch axis of any length")
    p.add_argument("--check", type=int, default=4, help="random images compared with Flax")
    return p


def cli(argv: list[str] | None = None) -> int:
    """The command: 0, or 2 with a one-line error (see `mjxrow.seg.onnx_export.cli`)."""
    parser().parse_args(argv)
    return commands.run_command(RUN, argv, "cli")


if __name__ == "__main__":
    sys.exit(cli())
