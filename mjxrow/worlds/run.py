"""`python -m mjxrow.worlds`: export fields as MuJoCo MJCF (with the robot), Gazebo Sim / Gazebo
Classic worlds and ground-truth CSVs (mjxrow.worlds.export).

    python -m mjxrow.worlds --preset zucchini [--seed 0] [--episode 0] [--set field.d_rr=2.0]
        [--lane 3] [--gazebo sim|classic|both|none] --out DIR
    python -m mjxrow.worlds --all --gazebo both --out worlds
    python -m mjxrow.worlds --from-run runs/sweep --cell 3 --episode 5 --gazebo classic --out DIR

The world of `--preset P --seed S --episode E --set K=V` is episode E of `python -m
mjxrow.episode --preset P --seed S --set K=V` (same field, lane and start pose); `--from-run`
exports an episode of a finished sweep (its cell and episode numbers as in results.csv).
`--set` takes the dotted keys of every command (docs/sweep.md): `field.*` shape the field,
`robot.*`, `camera.*` and `sim.*` the exported robot and its start.
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

from mjxrow import crops
from mjxrow.files import check_out_dir, check_out_file
from mjxrow.rollout import build as rollout_build
from mjxrow.sweep import config as sweep_config
from mjxrow.sweep import grid as sweep_grid
from mjxrow.worlds import export as worlds_export
from mjxrow.worlds import replay


def _parser() -> argparse.ArgumentParser:

    ap = argparse.ArgumentParser(prog="python -m mjxrow.worlds",
                                 description=__doc__.split("\n")[0].split(": ", 1)[1],
                                 formatter_class=argparse.RawDescriptionHelpFormatter,
                                 epilog="Exit codes: 0 done, 2 invalid input (the flag or key "
                                 "is named).")
    ap.add_argument("--preset", choices=crops.names(), help="the preset to export (one of "
                    "--preset, --all and --from-run is required; with --from-run the run's own)")
    ap.add_argument("--all", action="store_true", help="export every preset")
    ap.add_argument("--seed", type=int, default=0, help="run seed, as `mjxrow.episode --seed`")
    ap.add_argument("--episode", type=int, help="episode index (default 0); with --from-run "
                    "the episode of results.csv")
    ap.add_argument("--out", default="worlds", help="output folder")
    ap.add_argument("--set", action="append", default=[], metavar="KEY=VALUE", dest="sets",
                    help="set a dotted config key, e.g. --set field.d_rr=2.0 (repeatable)")
    ap.add_argument("--lane", type=int, help="start the robot in this lane (0..n-1 by y, as in "
                    "<name>_lanes.csv) without pose noise; default: the episode's lane and start")
    ap.add_argument("--gazebo", choices=worlds_export.GAZEBO, default="sim",
                    help="Gazebo flavour(s) to write (default: sim)")
    ap.add_argument("--sdf-collisions", choices=worlds_export.SDF_COLLISIONS, default="footprint",
                    help="plant collisions in the Gazebo worlds (see field.sdf.field_sdf)")
    ap.add_argument("--from-run", metavar="RUN_DIR", help="export one episode of a finished "
                    "sweep run (with --cell and --episode)")
    ap.add_argument("--cell", type=int, help="cell number in the run's results.csv")
    ap.add_argument("--picture", metavar="PNG", help="also render the `eye` view (one world)")
    return ap


def resolve_run(preset: str, seed: int = 0, sets: list[str] | tuple[str, ...] = ()):
    """(RunConfig, FieldShape) of one preset with `--set` items (the sweep's grammar and
    checks; the controller defaults to `oracle` with ground-truth perception, which need no
    checkpoint). ConfigError (a ValueError) naming the key."""

    base = [f"preset={preset}", f"seed={seed}", "controller.name=oracle",
            "perception.source=ground_truth"]
    cfg = sweep_config.from_dict({}, ".", [*base, *sets])
    if cfg.axis_order:
        raise sweep_config.ConfigError(
            f"{cfg.axis_order[0]}: one world needs one value, got a list"
        )
    run = sweep_grid.expand(cfg)[0].cfg
    return run, rollout_build.fit_shape([run])


def main(argv: list[str] | None = None) -> int:
    ap = _parser()
    args = ap.parse_args(argv)
    if args.preset is None and not args.all and args.from_run is None:
        ap.error("say what to export: --preset P, --all or --from-run RUN_DIR")
    if args.preset is not None and args.all:
        ap.error("--preset and --all: one of them")
    if args.picture and args.all:
        ap.error("--picture takes one world, not --all")
    if args.from_run and (args.cell is None or args.episode is None):
        ap.error("--from-run needs --cell and --episode")
    if args.from_run and (args.all or args.sets or args.lane is not None):
        ap.error("--from-run exports the run's own episode: no --all, --set or --lane")
    if args.cell is not None and not args.from_run:
        ap.error("--cell needs --from-run")
    from tqdm import tqdm


    try:
        check_out_dir(args.out, "--out")
        if args.picture:
            check_out_file(args.picture, "--picture")
        if args.from_run:
            jobs = [lambda: replay.from_run(args.from_run, args.cell, args.episode)]
        else:
            presets = crops.names() if args.all else (args.preset,)
            resolved = [resolve_run(p, args.seed, args.sets) for p in presets]
            jobs = [lambda r=r: replay.episode_world(*r, args.episode or 0, args.lane)
                    for r in resolved]
        for job in tqdm(jobs, desc="export", disable=len(jobs) < 2):
            ep = job()
            paths = worlds_export.export(ep.field, ep.shape, args.out, ep.name, ep.robot, ep.start,
                                         args.gazebo, args.sdf_collisions)
            kb = sum(p.stat().st_size for p in set(paths.values())) / 1024
            tqdm.write(f"{ep.name}: {int(ep.field.plant_active.sum())} plants in "
                       f"{int(ep.field.n_rows)} rows, robot in lane {ep.start.lane}, "
                       f"{kb:.0f} KiB → {Path(args.out) / ep.name}.*")
            if args.picture:
                worlds_export.snapshot(paths["xml"], args.picture)
    except ValueError as e:
        msg = str(e).splitlines()[0] if str(e) else type(e).__name__
        print(f"error: {msg}", file=sys.stderr)
        return 2
    return 0


if __name__ == "__main__":
    sys.exit(main())
