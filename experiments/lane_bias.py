"""Where a controller drives across the lane: the signed lateral offset of its closed-loop
episodes (+ left of the lane's centre line, m), per sun azimuth of a sweep config
(`sweeps/sun.yaml`: pear in Table 3's scenario):

    python experiments/lane_bias.py [--config sweeps/sun.yaml] [--azimuths 35 80]
        [--episodes 24] [--controller policy] [--checkpoint shipped] [--set KEY=VALUE ...]

It prints, per azimuth: the mean offset over each episode's second half (the mean over the
episodes, and their least and greatest), the mean offset where the episodes ended, the share
that reached the goal, and how the episodes ended; then where along the path the offset
builds up: its mean over the episodes in each of --parts equal parts of the path, by the
distance left to the goal (the last part ends at the goal, where the row ends in Table 3's
scenario). An episode succeeds within 0.40 m of the goal (`episode.goal_radius`), so a
controller that drives a steady 0.3 m off the line has little room left.
`experiments/sun_frames.py --checkpoint` measures the same policy's pull toward the line on
single frames; this is what the closed loop makes of it.

Episodes are those of the sweep's seed, 0 to --episodes − 1 (the same fields at every
azimuth). Exit codes: 0 done, 2 bad input (the key or value named).
"""

from __future__ import annotations

import argparse
import sys
import warnings
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(ROOT))  # run from a checkout, uninstalled


def parser() -> argparse.ArgumentParser:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--config", default=str(ROOT / "sweeps/sun.yaml"), help="a sweep YAML")
    p.add_argument("--azimuths", nargs="+", type=float, default=[35.0, 80.0], metavar="DEG",
                   help="the sun's azimuths (degrees from the rows' direction)")
    p.add_argument("--episodes", type=int, default=24, metavar="N", help="episodes an azimuth")
    p.add_argument("--controller", default="policy", help="controller.name (default policy)")
    p.add_argument("--checkpoint", default="shipped",
                   help="controller.checkpoint of the policy (default shipped)")
    p.add_argument("--parts", type=int, default=5, metavar="K",
                   help="parts of the path the offset is shown in (default 5)")
    p.add_argument("--set", action="append", default=[], metavar="KEY=VALUE",
                   help="override a key of the sweep YAML (repeatable)")
    return p


def runs(args: argparse.Namespace) -> list:
    """The runs, one per azimuth (ValueError naming a bad key or value)."""
    from mjxrow.sweep import config as sweep_config
    from mjxrow.sweep import grid as sweep_grid

    sets = [*args.set, "perception.sun_azimuth=" + str([float(a) for a in args.azimuths]),
            f"controller.name={args.controller}"]
    if args.controller == "policy":
        sets.append(f"controller.checkpoint={args.checkpoint}")
    return [c.cfg for c in sweep_grid.expand(sweep_config.load(args.config, sets))]


def offsets(log, n: int):
    """Per episode of a Log batch (the first n): (mean signed lateral offset over the second
    half of the steps that ran, the offset at its last step, its end's REASONS code)."""
    import jax.numpy as jnp
    import numpy as np

    from mjxrow.rollout import metrics as rollout_metrics

    off = np.asarray(rollout_metrics.lateral_offset(jnp.asarray(log.pose), log.lane))
    ran = np.asarray(log.alive).sum(-1)
    reason = np.asarray(log.reason)
    return [(float(off[i, ran[i] // 2:ran[i]].mean()), float(off[i, ran[i] - 1]),
             int(reason[i])) for i in range(n)]


def along(log, n: int, path_length: float, parts: int):
    """float [n, parts]: each of the first n episodes' mean signed lateral offset where the
    distance left to the goal (along the lane) lies in each of `parts` equal parts of
    `path_length`, from the start's part to the goal's (NaN where it never was)."""
    import jax
    import jax.numpy as jnp
    import numpy as np

    from mjxrow.field import lanes as field_lanes

    lane = jax.tree.map(lambda x: jnp.asarray(x)[..., None], log.lane)
    s, off, _ = (np.asarray(a) for a in field_lanes.project(lane, jnp.asarray(log.pose)[..., :2]))
    left = np.asarray(lane.s_end) - s
    done = np.nan_to_num(1.0 - left / path_length)  # steps after the end may hold NaN poses
    part = np.clip(np.floor(done * parts), 0, parts - 1).astype(int)
    inside = np.asarray(log.alive)[:n, :, None] & (part[:n, :, None] == np.arange(parts))
    count = inside.sum(1)
    total = np.where(inside, off[:n, :, None], 0.0).sum(1)
    return np.where(count > 0, total / np.maximum(count, 1), np.nan)


def main(argv: list[str] | None = None) -> int:
    args = parser().parse_args(argv)
    try:
        if args.episodes < 1:
            raise ValueError(f"--episodes: must be at least 1, got {args.episodes}")
        if args.parts < 1:
            raise ValueError(f"--parts: must be at least 1, got {args.parts}")
        if not Path(args.config).is_file():
            raise ValueError(f"--config: {args.config}: no such file")
        cells = runs(args)
    except ValueError as e:
        print(f"error: {e}", file=sys.stderr)
        return 2
    import numpy as np

    from mjxrow.rollout import build as rollout_build
    from mjxrow.rollout import metrics as rollout_metrics

    built = rollout_build.build(cells)
    n = args.episodes
    log = built.rollout(built.batch([(r, e) for r in cells for e in range(n)]))
    rows = offsets(log, n * len(cells))
    who = args.controller + (f" ({args.checkpoint})" if args.controller == "policy" else "")
    print(f"where {who} drives on {cells[0].preset}, {n} episodes an azimuth (m, + left of the "
          "lane's line): azimuth; mean offset over the second half (least .. greatest); mean "
          "offset at the end; success; ends")
    for k, az in enumerate(args.azimuths):
        mid, end, why = (np.array(c) for c in zip(*rows[k * n:(k + 1) * n], strict=True))
        ends = ", ".join(f"{rollout_metrics.REASONS[r]} {c}"
                         for r, c in enumerate(np.bincount(why, minlength=len(
                             rollout_metrics.REASONS))) if c)
        print(f"  {az:6.1f}°  {mid.mean():+.2f} ({mid.min():+.2f} .. {mid.max():+.2f})  "
              f"{end.mean():+.2f}  {np.mean(why == rollout_metrics.GOAL):.2f}  {ends}")
    length = float(cells[0].sim.path_length)
    parts = along(log, n * len(cells), length, args.parts)
    print(f"the mean offset along the path, in {args.parts} parts of {length / args.parts:.1f} m "
          "from the start to the goal (m, + left):")
    for k, az in enumerate(args.azimuths):
        with warnings.catch_warnings():  # a part no episode reached: NaN
            warnings.simplefilter("ignore", RuntimeWarning)
            mean = np.nanmean(parts[k * n:(k + 1) * n], axis=0)
        print(f"  {az:6.1f}°  " + "  ".join(f"{v:+.2f}" for v in mean))
    return 0


if __name__ == "__main__":
    sys.exit(main())
