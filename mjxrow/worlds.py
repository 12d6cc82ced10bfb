"""`python -m mjxrow.worlds`: export fields as MuJoCo MJCF (with the robot), Gazebo Sim / Gazebo
Classic worlds and ground-truth CSVs (mjxrow.field.export).

    python -m mjxrow.worlds --preset zucchini [--seed 0] [--set d_rr=2.0] [--lane 3] --out DIR
    python -m mjxrow.worlds --all --gazebo both --out worlds
    python -m mjxrow.worlds --from-run runs/sweep --cell 3 --episode 5 --gazebo classic --out DIR
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path


def _parser() -> argparse.ArgumentParser:
    from mjxrow import crops
    from mjxrow.field import export as X

    ap = argparse.ArgumentParser(prog="python -m mjxrow.worlds",
                                 description=__doc__.split("\n")[0].split(": ", 1)[1],
                                 formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--preset", choices=crops.names(), default="zucchini")
    ap.add_argument("--all", action="store_true", help="export every preset")
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--out", default="worlds", help="output folder")
    ap.add_argument("--set", action="append", metavar="KEY=VALUE", dest="sets",
                    help="override a field parameter (repeatable), e.g. --set d_rr=2.0")
    ap.add_argument("--lane", type=int, help="lane of the robot's start (0..n-1 by y, as in "
                    "<name>_lanes.csv; default: the field's default lane)")
    ap.add_argument("--gazebo", choices=X.GAZEBO, default="sim",
                    help="Gazebo flavour(s) to write (default: sim)")
    ap.add_argument("--sdf-collisions", choices=X.SDF_COLLISIONS, default="footprint",
                    help="plant collisions in the Gazebo worlds (see field.sdf.field_sdf)")
    ap.add_argument("--from-run", metavar="RUN_DIR", help="export the field of one episode of "
                    "a sweep run (with --cell and --episode)")
    ap.add_argument("--cell", type=int, help="cell number in the run's results.csv")
    ap.add_argument("--episode", type=int, help="episode number in the run's results.csv")
    ap.add_argument("--picture", metavar="PNG", help="also render the `eye` view (one world)")
    return ap


def main(argv: list[str] | None = None) -> int:
    ap = _parser()
    args = ap.parse_args(argv)
    if args.picture and args.all:
        ap.error("--picture takes one preset, not --all")
    if args.from_run and (args.cell is None or args.episode is None):
        ap.error("--from-run needs --cell and --episode")
    if args.from_run and (args.all or args.sets or args.lane is not None):
        ap.error("--from-run exports the run's own field: no --all, --set or --lane")
    import jax
    from tqdm import tqdm

    from mjxrow import crops
    from mjxrow import field as F
    from mjxrow.field import export as X
    from mjxrow.field import replay
    from mjxrow.field import scene as S
    from mjxrow.overrides import parse_sets

    try:
        if args.from_run:
            ep = replay.episode_field(args.from_run, args.cell, args.episode)
            jobs = [(ep.name, lambda ep=ep: (ep.field, ep.shape, ep.robot, ep.start))]
        else:
            sets = parse_sets(args.sets)
            presets = crops.names() if args.all else (args.preset,)
            resolved = {p: X.resolve(p, sets) for p in presets}
            gen = jax.jit(F.generate, static_argnums=1)

            def make(params, shape):
                fld = S.host(gen(params, shape, jax.random.key(args.seed)))
                robot = S.robot_for(fld)
                return fld, shape, robot, S.default_start(fld, shape, robot, args.lane)

            jobs = [(p, lambda ps=ps: make(*ps)) for p, ps in resolved.items()]
        for name, job in tqdm(jobs, desc="export", disable=len(jobs) < 2):
            fld, shape, robot, start = job()
            paths = X.export(fld, shape, args.out, name, robot, start, args.gazebo,
                             args.sdf_collisions)
            kb = sum(p.stat().st_size for p in set(paths.values())) / 1024
            tqdm.write(f"{name}: {int(fld.plant_active.sum())} plants in {int(fld.n_rows)} rows, "
                       f"robot in lane {start.lane}, {kb:.0f} KiB → {Path(args.out) / name}.*")
            if args.picture:
                X.snapshot(paths["xml"], args.picture)
    except ValueError as e:
        print(f"error: {e}", file=sys.stderr)
        return 2
    return 0


if __name__ == "__main__":
    sys.exit(main())
