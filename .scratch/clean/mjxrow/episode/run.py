"""The work of `python -m mjxrow.episode` (its parser and docs: `mjxrow.episode`): the settings
checked, then one batch of episodes → DIR/episodes.csv (`rollout.cli.run_episodes`)."""

from __future__ import annotations

import sys
from pathlib import Path

from mjxrow import episode as command
from mjxrow import files, interrupt, limits, runtime
from mjxrow.rollout import cli
from mjxrow.sweep import config as sweep_config
from mjxrow.sweep import estimate
from mjxrow.sweep import grid as sweep_grid


def main(argv: list[str] | None = None) -> int:
    """The command (`mjxrow.episode.main` hands over here): 0 done, 2 invalid input, 130
    interrupted."""
    args = command.parser().parse_args(argv)
    defaults = {"preset": "vineyard", "controller": "oracle", "perception": "ground_truth"}
    keys = {"preset": "preset", "controller": "controller.name",
            "perception": "perception.source"}
    sets = [f"{keys[k]}={getattr(args, k) or d}" for k, d in defaults.items()
            if getattr(args, k) or not args.config]
    sets += [f"seed={args.seed}", *args.set]
    try:
        runtime.setup(args)
        cfg = (
            sweep_config.load(args.config, sets)
            if args.config
            else sweep_config.from_dict({}, ".", sets)
        )
        if cfg.axis_order:
            raise sweep_config.ConfigError(
                f"{cfg.axis_order[0]}: one run needs one value, got an axis"
            )
        if args.n < 1:
            raise sweep_config.ConfigError(f"--n: must be at least 1, got {args.n}")
        limits.check_count("--n", "episodes", args.n, limits.EPISODES)
        run = sweep_grid.expand(cfg)[0].cfg
        estimate.check_episodes(run, args.n, args.force)
        files.check_out_dir(args.out, "--out")
        csv = Path(args.out) / cli.CSV
        if not args.overwrite:  # the writing process's folder decides
            files.check_new_file(csv, "--out", "--overwrite", runtime.agree(csv.exists()))
        with interrupt.HardStop():
            cli.run_episodes(run, args.n, args.out, not args.no_progress)
    except ValueError as e:
        print(f"error: {e}", file=sys.stderr)
        return 2
    except KeyboardInterrupt:
        return 130
    return 0
