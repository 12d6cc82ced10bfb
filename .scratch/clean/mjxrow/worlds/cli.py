"""`python -m mjxrow.worlds`: export fields as MuJoCo MJCF (with the robot), Gazebo Sim / Gazebo
Classic worlds and ground-truth CSVs (mjxrow.worlds.export).

    python -m mjxrow.worlds --preset zucchini [--seed 0] [--episode 0] [--set field.d_rr=2.0]
        [--lane 3] [--gazebo sim|classic|both|none] --out DIR
    python -m mjxrow.worlds --all --gazebo both --out worlds
    python -m mjxrow.worlds --from-run runs/sweep --cell 3 --episode 5 --gazebo classic --out DIR
    python -m mjxrow.worlds --from-search runs/search --rank 1 --gazebo both --out DIR

The world of `--preset P --seed S --episode E --set K=V` is episode E of `python -m
mjxrow.episode --preset P --seed S --set K=V` (same field, lane and start pose); `--from-run`
exports an episode of a finished sweep (its cell and episode numbers as in results.csv),
`--from-search` the episode in which a search's failure of rank K (failures.csv) failed.
`--set` takes the dotted keys of every command (docs/sweep.md): `field.*` shape the field,
`robot.*`, `camera.*` and `sim.*` the exported robot and its start.

This module is the command's light half (mjxrow.commands): the parser, the checks of the flags
against each other, and the hand-over to `mjxrow.worlds.run`, which exports.
"""

from __future__ import annotations

import argparse

from mjxrow import commands

RUN = "mjxrow.worlds.run"  # the heavy module: its main(argv) exports
GAZEBO = ("sim", "classic", "both", "none")  # = worlds.export.GAZEBO
SDF_COLLISIONS = ("footprint", "primitives", "none")  # = worlds.sdf.SDF_COLLISIONS


def parser() -> argparse.ArgumentParser:
    ap = argparse.ArgumentParser(prog="python -m mjxrow.worlds",
                                 description=__doc__.split("\n")[0].split(": ", 1)[1],
                                 formatter_class=argparse.RawDescriptionHelpFormatter,
                                 epilog="Exit codes: 0 done, 2 invalid input (the flag or key "
                                 "is named).")
    ap.add_argument("--preset", metavar="P", help="the preset (a registered crop) to export (one "
                    "of --preset, --all, --from-run and --from-search is required; with "
                    "--from-run or --from-search the run's own)")
    ap.add_argument("--all", action="store_true", help="export every preset")
    ap.add_argument("--seed", type=int, default=0, help="run seed, as `mjxrow.episode --seed`")
    ap.add_argument("--episode", type=int, help="episode index (default 0); with --from-run "
                    "the episode of results.csv")
    ap.add_argument("--out", default="runs/worlds", help="output folder (default %(default)s)")
    ap.add_argument("--set", action="append", default=[], metavar="KEY=VALUE", dest="sets",
                    help="set a dotted config key, e.g. --set field.d_rr=2.0 (repeatable)")
    ap.add_argument("--lane", type=int, help="start the robot in this lane (0..n-1 across the "
                    "rows, as in <name>_lanes.csv) without pose noise; default: the episode's "
                    "lane and start")
    ap.add_argument("--gazebo", choices=GAZEBO, default="sim",
                    help="Gazebo flavour(s) to write (default: sim)")
    ap.add_argument("--sdf-collisions", choices=SDF_COLLISIONS, default="footprint",
                    help="plant collisions in the Gazebo worlds (see field.sdf.field_sdf)")
    ap.add_argument("--from-run", metavar="RUN_DIR", help="export one episode of a finished "
                    "sweep run (with --cell and --episode)")
    ap.add_argument("--cell", type=int, help="cell number in the run's results.csv")
    ap.add_argument("--from-search", metavar="RUN_DIR", help="export the episode of a failure "
                    "found by `python -m mjxrow.search` (with --rank)")
    ap.add_argument("--rank", type=int, help="rank of the failure in the search's failures.csv "
                    "(1 = the worst)")
    ap.add_argument("--picture", metavar="PNG", help="also render the `eye` view (one world)")
    return ap


def parse(argv: list[str] | None = None) -> argparse.Namespace:
    """The arguments, parsed and checked against each other (argparse's error and exit 2)."""
    ap = parser()
    args = ap.parse_args(argv)
    if args.preset is None and not args.all and args.from_run is None and \
            args.from_search is None:
        ap.error("say what to export: --preset P, --all, --from-run RUN_DIR or "
                 "--from-search RUN_DIR")
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
    if args.from_search and args.rank is None:
        ap.error("--from-search needs --rank")
    if args.from_search and (args.from_run or args.preset or args.all or args.sets
                             or args.lane is not None or args.episode is not None):
        ap.error("--from-search exports the search's own episode: no --preset, --all, "
                 "--from-run, --episode, --set or --lane")
    if args.rank is not None and not args.from_search:
        ap.error("--rank needs --from-search")
    return args


def main(argv: list[str] | None = None) -> int:
    """The command: 0 done, 2 invalid input (one line naming the flag or key)."""
    parse(argv)
    return commands.run_command(RUN, argv)
