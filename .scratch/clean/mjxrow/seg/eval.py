"""Evaluation of a segmenter on a dataset folder (default: its test split) or on renders.

CLI: `python -m mjxrow.seg.eval --crop zucchini [--data DIR] [--ckpt PATH]` prints pixel accuracy
and IoU (both in [0, 1]; IoU of the crop class, prediction sigmoid(logit) > 0.7) per crop and per
sky condition, pooled over the images of each group: IoU = Σ|M ∩ Y| / Σ|M ∪ Y|. Weeds are not
crop; where the class images are known, it also prints the number of weedy images (with weed
pixels), the IoU pooled over them and the share of weed pixels predicted crop (weed_as_crop).
Without `--data` it evaluates on a fixed set of renders of the crop (seed 20,000 + `--seed`;
`--variety`: the fields' variety, curved rows, gaps and weeds by default).
"""

from __future__ import annotations

import argparse
import sys

from mjxrow import commands
from mjxrow.seg.synth import VARIETIES

# the command's light half (mjxrow.commands): the parser and the hand-over to the heavy module
RUN = "mjxrow.seg.evaluation"  # the heavy module: its cli(argv) evaluates
THRESHOLD = 0.7  # the paper's threshold on sigmoid(logit) (evaluation.THRESHOLD)


def parser() -> argparse.ArgumentParser:
    p = argparse.ArgumentParser(prog="python -m mjxrow.seg.eval", description=__doc__,
                                formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--crop", default="zucchini", metavar="CROP",
                   help="crop to evaluate on, a registered crop or all (and shipped model to load "
                   "without --ckpt)")
    p.add_argument("--data", help="dataset folder written by python -m mjxrow.seg.synth")
    p.add_argument("--ckpt", help="checkpoint folder (default: the shipped model of --crop)")
    p.add_argument("--split", default="test", help="split of the folder ('all' for every row)")
    p.add_argument("--size", type=int, help="resize images to this side (default: model's)")
    p.add_argument("--batch", type=int, default=32)
    p.add_argument("--threshold", type=float, default=THRESHOLD,
                   help="plant where sigmoid(logit) exceeds it (default %(default)s, the paper's)")
    p.add_argument("--n", type=int, default=512, help="renders to evaluate without --data")
    p.add_argument("--seed", type=int, default=0)
    p.add_argument("--variety", default="fields", choices=VARIETIES,
                   help="fields of the renders without --data: fields (curved rows, gaps and "
                   "weeds in a share of them, default) or none")
    p.add_argument("--csv", help="also write the summary table here")
    return p


def cli(argv: list[str] | None = None) -> int:
    """The command: 0, or 2 with a one-line error (see `mjxrow.seg.evaluation.cli`)."""
    parser().parse_args(argv)
    return commands.run_command(RUN, argv, "cli")


if __name__ == "__main__":
    sys.exit(cli())
