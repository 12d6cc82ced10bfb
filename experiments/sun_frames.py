"""What a policy sees as the sun turns about the rows: the first camera frame of one episode of
`sweeps/sun.yaml` (pear, 64 x 64) at each azimuth, with the renderer's cast shadows (top row),
without them (middle row), and the shadowed frame's chromaticity (bottom row: what a policy
with `env.observation=chroma` sees), in one PNG:

    python experiments/sun_frames.py [--config sweeps/sun.yaml] [--azimuths 35 80 125 260]
        [--episode 0] [--set KEY=VALUE ...] [--out docs/sun_frames_pear.png]

It prints, per azimuth, how much the cast shadows change the frame, in RGB and in
chromaticity: the mean absolute change of a pixel's channels over the spread (standard
deviation) of the frame without shadows (`shadow_change`).

The frames are the ones the controller's first step gets (the reset pose of episode
`--episode` of the sweep's seed; the same field at every azimuth), drawn pixel for pixel. An
existing --out is replaced only when this script wrote it (the PNG's `Software` entry names
it). Exit codes: 0 done, 2 bad input (the key or file named).
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

import plot_one_command  # experiments/, the folder of this script

ROOT = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(ROOT))  # run from a checkout, uninstalled
TAG = "mjxrow experiments/sun_frames.py"  # the PNG's Software entry


def parser() -> argparse.ArgumentParser:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--config", default=str(ROOT / "sweeps/sun.yaml"), help="a sun sweep YAML")
    p.add_argument("--azimuths", nargs="+", type=float, default=[35.0, 80.0, 125.0, 260.0],
                   metavar="DEG", help="the sun's azimuths (degrees from the rows' direction)")
    p.add_argument("--episode", type=int, default=0, help="the episode of the sweep's seed")
    p.add_argument("--set", action="append", default=[], metavar="KEY=VALUE",
                   help="override a key of the sweep YAML (repeatable)")
    p.add_argument("--out", default=str(ROOT / "docs/sun_frames_pear.png"))
    return p


def config(cfg_path: str, azimuths: list[float], sets: list[str], shadows: bool):
    """The sweep config of the frames: the YAML with `sets`, the azimuths, the cast shadows on
    or off, and the oracle as controller (the camera is every controller's; no checkpoint)."""
    from mjxrow.sweep import config as sweep_config

    return sweep_config.load(cfg_path, [*sets, "perception.sun_azimuth="
                                        + str([float(a) for a in azimuths]),
                                        f"render.shadows={str(shadows).lower()}",
                                        "controller.name=oracle"])


def frames(cfg_path: str, azimuths: list[float], episode: int, sets: list[str],
           shadows: bool):
    """(the first run, [rgb uint8 [H, W, 3] per azimuth]): the first frames."""
    from mjxrow.rollout import build as rollout_build
    from mjxrow.search import evaluate as search_evaluate
    from mjxrow.sweep import grid as sweep_grid

    runs = [c.cfg for c in sweep_grid.expand(config(cfg_path, azimuths, sets, shadows))]
    built = rollout_build.build(runs)
    batch = built.batch([(r, episode) for r in runs], len(runs))
    return runs[0], [rgb for rgb, _ in search_evaluate.first_frames(built, batch, runs)]


def shadow_change(shaded, lit, kind: str = "rgb") -> float:
    """How much the cast shadows change a frame: the mean absolute change of its channels
    (uint8 [H, W, 3] with and without shadows; `kind` "chroma": of their chromaticities, as
    `policies.observe.chromaticity`) over the spread of the frame without them."""
    import numpy as np

    from mjxrow.policies import observe

    if kind == "chroma":
        shaded, lit = (np.asarray(observe.chromaticity(x)) for x in (shaded, lit))
    a, b = (np.asarray(x, np.float64) for x in (shaded, lit))
    return float(np.mean(np.abs(a - b)) / max(float(np.std(b)), 1e-9))


def main(argv: list[str] | None = None) -> int:
    args = parser().parse_args(argv)
    out = Path(args.out)
    try:
        if args.episode < 0:
            raise ValueError(f"--episode: must be at least 0, got {args.episode}")
        if not Path(args.config).is_file():
            raise ValueError(f"--config: {args.config}: no such file")
        if out.exists() and not plot_one_command.written_by(out, TAG):
            raise ValueError(f"--out: {out} exists and was not written by this script; "
                             "choose another path")
        config(args.config, args.azimuths, args.set, True)  # the YAML and --set, checked first
    except ValueError as e:
        print(f"error: {e}", file=sys.stderr)
        return 2
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    from mjxrow.policies import observe

    run, shaded = frames(args.config, args.azimuths, args.episode, args.set, True)
    _, lit = frames(args.config, args.azimuths, args.episode, args.set, False)
    print("the cast shadows' change of the frame (mean |change| / spread): azimuth, RGB, "
          "chromaticity")
    for az, s, u in zip(args.azimuths, shaded, lit, strict=True):
        print(f"  {az:6.1f}°  {shadow_change(s, u):.3f}  {shadow_change(s, u, 'chroma'):.3f}")
    rows = [("cast shadows", shaded), ("no cast shadows", lit),
            ("chromaticity, cast shadows", [observe.chromaticity(x) for x in shaded])]
    n = len(args.azimuths)
    fig, axes = plt.subplots(len(rows), n, figsize=(2.1 * n, 6.7), squeeze=False)
    for r, (label, imgs) in enumerate(rows):
        for c, (az, img) in enumerate(zip(args.azimuths, imgs, strict=True)):
            ax = axes[r][c]
            ax.imshow(img, interpolation="nearest")
            ax.set_xticks([])
            ax.set_yticks([])
            if r == 0:
                ax.set_title(f"sun at {az:g}°", fontsize=10)
            if c == 0:
                ax.set_ylabel(label, fontsize=10)
    h, w = shaded[0].shape[:2]
    fig.suptitle(f"{run.preset}, episode {args.episode}: the first frame ({w} × {h} px), as "
                 "the controller gets it", fontsize=10)
    fig.tight_layout()
    out.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(out, dpi=110, metadata={"Software": TAG})
    plt.close(fig)
    print(f"wrote {out}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
