"""What a policy sees as the sun turns about the rows: the first camera frame of one episode of
`sweeps/sun.yaml` (pear, 64 x 64) at each azimuth, with the renderer's cast shadows (top row),
without them (middle row), and the shadowed frame's chromaticity (bottom row: what a policy
with `env.observation=chroma` sees), in one PNG:

    python experiments/sun_frames.py [--config sweeps/sun.yaml] [--azimuths 35 80 125 260]
        [--episode 0] [--set KEY=VALUE ...] [--out docs/sun_frames_pear.png]
        [--checkpoint shipped --episodes 32 --offset-std 0.5 --yaw-std 5]

It prints, per azimuth, how much the cast shadows change the frame, in RGB and in
chromaticity: the mean absolute change of a pixel's channels over the spread (standard
deviation) of the frame without shadows (`shadow_change`).

With --checkpoint (a policy folder or 'shipped') it also prints how that policy steers back to
the lane's centre line, and where the shadows move its idea of that line. The first frames of
--episodes episodes are drawn with the robot started off the line (lateral offset std
--offset-std m, heading std --yaw-std degrees), with the cast shadows and without them. The
policy's turn command on each (its observation kind, as while it drives straight on at full
speed) is fitted as a plane, turn = a + b · offset + c · heading (`centre`). Printed per
azimuth, without and with the shadows: b (per m) and c (per 10°), its turn as a share of ω_max
(negative: it steers back), and −a / b, the offset it steers toward when aligned (m, + left of
the line). Last, the same fit of the oracle's command (pure pursuit: the teacher the policies
were cloned from) on the same starts.

The frames are the ones the controller's first step gets (the reset pose of episode
`--episode` of the sweep's seed; the same field at every azimuth), drawn pixel for pixel. An
existing --out is replaced only when this script wrote it (the PNG's `Software` entry names
it). Exit codes: 0 done, 2 bad input (the key or file named).
"""

from __future__ import annotations

import argparse
import math
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
    p.add_argument("--checkpoint", default=None, metavar="CK",
                   help="a policy checkpoint folder or 'shipped': print how it steers back to "
                        "the lane's line, with and without the shadows, beside the oracle")
    p.add_argument("--episodes", type=int, default=32, metavar="N",
                   help="episodes whose first frames --checkpoint is measured on")
    p.add_argument("--offset-std", type=float, default=0.5, metavar="M",
                   help="std of their starts' lateral offset (m) for --checkpoint")
    p.add_argument("--yaw-std", type=float, default=5.0, metavar="DEG",
                   help="std of their starts' heading about the lane's line for --checkpoint")
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
    run, rgb, _, _ = episode_frames(cfg_path, azimuths, [episode], sets, shadows)
    return run, [x[0] for x in rgb]


def episode_frames(cfg_path: str, azimuths: list[float], episodes: list[int], sets: list[str],
                   shadows: bool):
    """(the first run, rgb uint8 [A, N, H, W, 3], ground-truth mask bool [A, N, H, W], start
    (lateral offset [m], heading error [rad]) [A, N, 2]): the first frames of the episodes at
    each azimuth."""
    import numpy as np

    from mjxrow.rollout import build as rollout_build
    from mjxrow.search import evaluate as search_evaluate
    from mjxrow.sweep import grid as sweep_grid

    runs = [c.cfg for c in sweep_grid.expand(config(cfg_path, azimuths, sets, shadows))]
    built = rollout_build.build(runs)
    each = [r for r in runs for _ in episodes]
    batch = built.batch([(r, e) for r in runs for e in episodes], len(each))
    out = search_evaluate.first_frames(built, batch, each)
    shape = (len(runs), len(episodes))
    return (runs[0], np.stack([rgb for rgb, _ in out]).reshape(*shape, *out[0][0].shape),
            np.stack([m for _, m in out]).reshape(*shape, *out[0][1].shape),
            search_evaluate.first_poses(built, batch, len(each)).reshape(*shape, 2))


def turns(checkpoint: str, run, rgb, mask):
    """The policy's turn-rate command in [-1, 1] (a share of ω_max) on each frame (rgb uint8
    [..., H, W, 3], mask bool [..., H, W]) as its observation kind sees it while it drives
    straight on at v_max (odometry (v_max, 0), previous action (1, 0)); shape [...]."""
    import types

    import jax
    import jax.numpy as jnp
    import numpy as np

    from mjxrow.policies import checkpoint as policies_checkpoint
    from mjxrow.policies import observe

    ck = policies_checkpoint.load(checkpoint, {"height": rgb.shape[-3], "width": rgb.shape[-2]},
                                  key="--checkpoint")
    seg = observe.segmenter_for(run, ck.spec)
    lim = jnp.asarray(ck.limits, jnp.float32)

    def one(x, m):
        o = observe.observe(ck.spec, types.SimpleNamespace(rgb=x, mask=m), seg,
                            lim * jnp.array([1.0, 0.0]), jnp.array([1.0, 0.0]), lim)
        mean, _, _ = ck.net.apply(ck.variables, o)
        return jnp.clip(mean, -1.0, 1.0)[1]

    lead = rgb.shape[:-3]
    flat = jax.jit(jax.vmap(one))(rgb.reshape(-1, *rgb.shape[-3:]),
                                  mask.reshape(-1, *mask.shape[-2:]))
    return np.asarray(flat).reshape(lead)


def teacher_turns(offset, heading, limits: tuple[float, float]):
    """The oracle's turn command in [-1, 1] (pure pursuit with its default lookahead, the
    policies' teacher; a share of ω_max) from starts at these lateral offsets [N] (m) and
    heading errors [N] (rad) on a straight lane, under the policy's limits (v_max, ω_max)."""
    import jax
    import jax.numpy as jnp
    import numpy as np

    from mjxrow.control import oracle
    from mjxrow.field import lanes as field_lanes

    params = oracle.oracle_params(oracle.OracleConfig().lookahead, *limits)
    lane = field_lanes.straight_lane(jnp.float32(0.0), jnp.float32(1e3))

    def one(e, h):
        return oracle.pursuit_command(params, jnp.stack([0.0, e, h]), lane)[1] / limits[1]

    return np.asarray(jax.vmap(one)(jnp.asarray(offset, jnp.float32),
                                    jnp.asarray(heading, jnp.float32)))


def centre(turn, offset, heading) -> tuple[float, float, float]:
    """The plane turn = a + b · offset + c · heading fitted (least squares) to a policy's turns
    ([N], shares of ω_max) at the starts' lateral offsets ([N], m) and heading errors ([N],
    rad): (b, c, −a / b), the turn per metre and per radian off the line, and the offset it
    steers toward when aligned with the lane (NaN where b is 0)."""
    import numpy as np

    x = np.stack([np.ones(len(turn)), np.asarray(offset, np.float64),
                  np.asarray(heading, np.float64)], -1)
    a, b, c = np.linalg.lstsq(x, np.asarray(turn, np.float64), rcond=None)[0]
    return float(b), float(c), float(-a / b) if b != 0 else float("nan")


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
        if args.episodes < 2:
            raise ValueError(f"--episodes: must be at least 2 (a line is fitted), got "
                             f"{args.episodes}")
        if not args.offset_std > 0:
            raise ValueError(f"--offset-std: must be positive, got {args.offset_std}")
        if not args.yaw_std > 0:
            raise ValueError(f"--yaw-std: must be positive, got {args.yaw_std}")
        if args.checkpoint is not None:
            from mjxrow.policies import checkpoint as policies_checkpoint

            policies_checkpoint.resolve(args.checkpoint, key="--checkpoint")
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
    if args.checkpoint is not None:
        try:
            print_steering(args)
        except ValueError as e:  # a checkpoint that does not fit the camera
            print(f"error: {e}", file=sys.stderr)
            return 2
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


def print_steering(args: argparse.Namespace) -> None:
    """The --checkpoint table: per azimuth, the policy's turn per metre and per degree off the
    lane's centre line and the offset it steers toward, without and with the cast shadows; the
    oracle's on the same starts."""
    from mjxrow.policies import checkpoint as policies_checkpoint

    eps = list(range(args.episodes))
    sets = [*args.set, f"episode.start_offset_std={args.offset_std}",
            f"episode.start_yaw_std={args.yaw_std}"]
    fits = []
    for shadows in (False, True):
        run, rgb, mask, pose = episode_frames(args.config, args.azimuths, eps, sets, shadows)
        turn = turns(args.checkpoint, run, rgb, mask)
        fits.append([centre(t, o[:, 0], o[:, 1]) for t, o in zip(turn, pose, strict=True)])
    print(f"where {args.checkpoint} steers, from the first frames of {len(eps)} episodes started "
          f"across the lane (offset std {args.offset_std:g} m, heading std {args.yaw_std:g}°): "
          "azimuth; its turn (share of ω_max) per m and per 10° off the line, and the offset it "
          "steers toward (m, + left), each without | with the cast shadows")
    for az, (b0, h0, c0), (b1, h1, c1) in zip(args.azimuths, *fits, strict=True):
        print(f"  {az:6.1f}°  {b0:+.3f} | {b1:+.3f}  {h0 * D10:+.3f} | {h1 * D10:+.3f}  "
              f"{c0:+.2f} | {c1:+.2f}")
    limits = policies_checkpoint.load(args.checkpoint, key="--checkpoint").limits
    b, h, c = centre(teacher_turns(pose[0, :, 0], pose[0, :, 1], limits), pose[0, :, 0],
                     pose[0, :, 1])
    print(f"  the oracle (pure pursuit, the policies' teacher) on the same starts: {b:+.3f} per m,"
          f" {h * D10:+.3f} per 10°, toward {c:+.2f} m")


D10 = math.radians(10.0)  # the heading slope is printed per 10°


if __name__ == "__main__":
    sys.exit(main())
