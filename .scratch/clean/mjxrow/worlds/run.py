"""The work of `python -m mjxrow.worlds` (its parser and docs: `mjxrow.worlds.cli`): each asked
episode's world exported (`worlds.export`) into `--out`."""

from __future__ import annotations

import sys
from pathlib import Path

from tqdm import tqdm

from mjxrow import crops
from mjxrow.files import check_out_dir, check_out_file
from mjxrow.worlds import cli, replay
from mjxrow.worlds import export as worlds_export


def main(argv: list[str] | None = None) -> int:
    """The command (`mjxrow.worlds.cli.main` hands over here): 0 done, 2 invalid input."""
    args = cli.parse(argv)
    try:
        check_out_dir(args.out, "--out")
        if args.picture:
            check_out_file(args.picture, "--picture")
        if args.from_run:
            jobs = [lambda: replay.from_run(args.from_run, args.cell, args.episode)]
        elif args.from_search:
            jobs = [lambda: replay.from_search(args.from_search, args.rank)]
        else:
            presets = crops.names() if args.all else (args.preset,)
            resolved = [replay.resolve_run(p, args.seed, args.sets) for p in presets]
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
