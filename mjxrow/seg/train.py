"""`python -m mjxrow.seg.train`: train the plant segmenter (`mjxrow.seg.training`); an interrupted
run resumes.

    python -m mjxrow.seg.train --crop zucchini (--data DIR | --on-the-fly) [--arch small]
        [--width 1.0] [--size 224] [--steps N] [--batch B] [--loss iou|bce] [--init CKPT]
        [--out DIR] [--export-to DIR]

`--init` fine-tunes a trained model (e.g. the all-crop one on one crop).

The loss default is the paper's IoU loss 1 − Σyp / Σ(y + p − yp) with p = sigmoid(logit), summed
over the pixels of EACH image and averaged over the batch (+1 smoothing in numerator and
denominator, so images without plants still push p → 0). Validation IoU uses a hard mask at
threshold 0.7 (the paper's), pooled over the validation set: Σ|M ∩ Y| / Σ|M ∪ Y|.
"""

from __future__ import annotations

import argparse
import sys

from mjxrow import commands
from mjxrow.seg.synth import VARIETIES

# the command's light half (mjxrow.commands): the parser and the hand-over to the heavy module
RUN = "mjxrow.seg.training"  # the heavy module: its cli(argv) trains
ARCHS = ("large", "small", "tiny")  # = seg.model.ARCHS
LOSSES = ("iou", "bce")  # = seg.step.LOSSES
WEIGHT_DTYPES = ("float32", "float16", "bfloat16")  # = seg.checkpoint.WEIGHT_DTYPES


def parser() -> argparse.ArgumentParser:
    p = argparse.ArgumentParser(prog="python -m mjxrow.seg.train", description=__doc__,
                                formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--crop", default="zucchini", metavar="CROP",
                   help="a registered crop, or all (one model for every crop)")
    src = p.add_mutually_exclusive_group(required=True)
    src.add_argument("--data", help="dataset folder written by python -m mjxrow.seg.synth")
    src.add_argument("--on-the-fly", action="store_true", help="render batches on the device")
    p.add_argument("--arch", default="small", choices=ARCHS)
    p.add_argument("--width", type=float, default=1.0, help="width multiplier")
    p.add_argument("--reduced-tail", action="store_true", help="halve the last stage")
    p.add_argument("--dtype", default="float32", choices=("float32", "bfloat16"))
    p.add_argument("--size", type=int, nargs="+", default=[224],
                   help="square input side(s) [px]; several are trained in turn, step by step "
                        "(e.g. 224 128 64 for a model that serves any camera size)")
    p.add_argument("--steps", type=int, default=20000)
    p.add_argument("--batch", type=int, default=32)
    p.add_argument("--lr", type=float, default=1e-3)
    p.add_argument("--warmup", type=int, default=500, help="warmup steps")
    p.add_argument("--weight-decay", type=float, default=1e-4)
    p.add_argument("--loss", default="iou", choices=LOSSES)
    p.add_argument("--flip", type=float, default=0.5, help="probability of a horizontal flip")
    p.add_argument("--grey", type=float, default=0.2, help="probability of greyscale")
    p.add_argument("--jitter", type=float, default=0.0, help="colour jitter strength (0 = off)")
    p.add_argument("--eval-every", type=int, default=500)
    p.add_argument("--log-every", type=int, default=50)
    p.add_argument("--val-frac", type=float, default=0.1, help="of train split (--data)")
    p.add_argument("--val-n", type=int, default=512, help="validation renders (--on-the-fly)")
    p.add_argument("--variety", default="fields", choices=VARIETIES,
                   help="fields of the renders (--on-the-fly): fields (curved rows, gaps and "
                   "weeds in a share of them, default) or none")
    p.add_argument("--workers", type=int, default=4, help="image decoding threads (--data)")
    p.add_argument("--seed", type=int, default=0)
    p.add_argument("--out", help="run folder (default runs/seg_<crop>_<arch>)")
    p.add_argument("--restart", action="store_true",
                   help="start over: delete the run's state, best model and log in --out first "
                        "(nothing else there)")
    p.add_argument("--no-progress", action="store_true", help="no progress bar (logs)")
    p.add_argument("--init", help="start from this checkpoint's weights (a crop name for a "
                                  "shipped model, or a checkpoint folder) instead of random "
                                  "ones; its architecture replaces --arch/--width")
    p.add_argument("--export-to", help="write the best model here as a shipped checkpoint")
    p.add_argument("--export-dtype", default="float16", choices=WEIGHT_DTYPES)
    return p


def cli(argv: list[str] | None = None) -> int:
    """The command: 0, 2 with a one-line error, 130 interrupted (see
    `mjxrow.seg.training.cli`)."""
    parser().parse_args(argv)
    return commands.run_command(RUN, argv, "cli")


if __name__ == "__main__":
    sys.exit(cli())
