"""The synthetic segmentation dataset: RGB images and binary plant masks rendered by `render.py`.

CLI:
    python -m mjxrow.seg.synth --crop zucchini --n 19456 --out DIR [--seed S] [--size 224]
        [--test-frac F] [--batch B] [--workers W] [--variety fields|none]
    python -m mjxrow.seg.synth --crop zucchini --contact-sheet docs/contact_zucchini.png

Layout of DIR: `index.csv` (columns rgb, mask, classes, crop, condition, x, y, z, yaw, pitch,
lateral, row_amplitude, row_curvature, gap_rate, weed_density, split; paths relative to DIR),
images `<condition>/rgb/<crop>_<i:06d>.png` (RGB, 8-bit), `<condition>/mask/<crop>_<i:06d>.png`
(the crop plants: 8-bit, 0 or 255; weeds are not crop) and `<condition>/class/<crop>_<i:06d>.png`
(8-bit class ids of `mjxrow.render`: sky, soil, plant, obstacle, weed), four sub-datasets by
sky and lighting (`render.CONDITIONS`), sample i in condition i mod 4.

Every sample is a function of (crop, seed, variety, i) only: its own field (the crop's preset
with geometry, terrain and obstacles varied; with `--variety fields`, the default, also curved
rows, gap runs and weeds in a share of the fields; `--variety none`: straight rows without gaps
or weeds), a camera pose in that field and randomised lighting. Hence a re-run with the same
arguments resumes: finished samples are skipped, never rewritten (files appear through temp
file + rename), and the index is rebuilt identically; a folder holding samples of another seed
or variety is refused. The test split is an exact fraction of each condition, drawn with the
seed.

The samples (fields, camera poses, lighting) are `mjxrow.seg.synthesis`'s.
"""

from __future__ import annotations

import argparse
import sys

from mjxrow import commands, limits

# the command's light half (mjxrow.commands): the parser, the checks of the flags, and the
# hand-over to the heavy module
RUN = "mjxrow.seg.synthesis"  # the heavy module: its main(argv) writes the dataset
VARIETIES = ("fields", "none")  # = seg.scenes.VARIETIES: with curved rows, gaps, weeds or not


def parser() -> argparse.ArgumentParser:
    ap = argparse.ArgumentParser(prog="python -m mjxrow.seg.synth",
                                 description=__doc__.split("\n")[0])
    ap.add_argument("--crop", required=True, metavar="CROP", help="a registered crop")
    ap.add_argument("--n", type=int, help="number of samples (the paper's: the crop's dataset_n, "
                    "e.g. zucchini 19456)")
    ap.add_argument("--out", help="output folder")
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--size", type=int, default=224, help="image side [px]")
    ap.add_argument("--test-frac", type=float, default=None,
                    help="test fraction per condition (default: the crop's test_frac)")
    ap.add_argument("--batch", type=int, default=64, help="images rendered per call")
    ap.add_argument("--workers", type=int, default=4, help="PNG-encoding threads")
    ap.add_argument("--contact-sheet", metavar="PNG",
                    help="write a contact sheet (a few samples per condition) and exit")
    ap.add_argument("--per-condition", type=int, default=3)
    ap.add_argument("--variety", default="fields", choices=VARIETIES,
                    help="fields: curved rows, gap runs and weeds in a share of the fields "
                    "(default); none: straight rows without gaps or weeds")
    return ap


def parse(argv: list[str] | None = None) -> argparse.Namespace:
    """The arguments, parsed and checked (argparse's error and exit 2)."""
    ap = parser()
    args = ap.parse_args(argv)
    if args.contact_sheet:
        return args
    if args.n is None or args.out is None:
        ap.error("--n and --out are required (or give --contact-sheet)")
    if args.n <= 0:
        ap.error(f"--n: must be a positive number of samples, got {args.n}")
    if args.size < 8:
        ap.error(f"--size: images need at least 8 pixels a side, got {args.size}")
    if args.test_frac is not None and not 0.0 <= args.test_frac < 1.0:
        ap.error(f"--test-frac: must lie in [0, 1), got {args.test_frac}")
    if args.batch < 1 or args.workers < 1:
        ap.error("--batch and --workers must be at least 1")
    if args.n > limits.EPISODES or args.size > limits.VALUES["camera.width"][0]:
        ap.error(f"--n {args.n} / --size {args.size}: beyond the bounds of "
                 f"{limits.EPISODES:,} samples and {limits.VALUES['camera.width'][0]} px")
    return args


def main(argv: list[str] | None = None) -> int:
    """The command: 0 done, 2 invalid input, 130 interrupted (a re-run resumes)."""
    parse(argv)
    return commands.run_command(RUN, argv)


if __name__ == "__main__":
    sys.exit(main())
