"""`python -m mjxrow.episode`: one batch of episodes of one configuration → DIR/episodes.csv.

    python -m mjxrow.episode --preset vineyard --controller oracle --n 8 --seed 0 --out DIR
        [--config SWEEP.yaml] [--set KEY=VALUE ...]

Any key of the sweep YAML's sections can be set (`--set field.d_rr=3.0 --set
episode.max_time=30 --set camera.width=112`; docs/sweep.md lists them); the same seed and
settings give the same episodes as a sweep cell with those settings.
"""

from __future__ import annotations

import argparse
import sys

from mjxrow import control, crops, files, interrupt, limits, runtime
from mjxrow.rollout import cli
from mjxrow.sweep import config as sweep_config
from mjxrow.sweep import estimate
from mjxrow.sweep import grid as sweep_grid


def parser() -> argparse.ArgumentParser:
    p = argparse.ArgumentParser(prog="python -m mjxrow.episode", description=__doc__.split(
        "\n")[0].split(": ", 1)[1], formatter_class=argparse.RawDescriptionHelpFormatter,
        epilog="Exit codes: 0 done, 2 invalid configuration or output folder (the key or option "
        "is named), 130 interrupted (Ctrl-C or SIGTERM; nothing written).")
    p.add_argument("--preset", choices=crops.names(), help="crop preset (default: vineyard, or the "
                   "config's)")
    p.add_argument("--controller", choices=control.names(),
                   help="controller.name (default: oracle, or the config's)")
    p.add_argument("--perception", choices=("ground_truth", "learned"),
                   help="perception.source of the mask controllers (default: ground_truth, or "
                   "the config's)")
    p.add_argument("--n", type=int, default=8, help="episodes (one field each)")
    p.add_argument("--seed", type=int, default=0, help="base seed; episode i uses "
                   "fold_in(key(seed), i), as a sweep cell")
    p.add_argument("--out", required=True, help="output directory (episodes.csv)")
    p.add_argument("--config", help="a sweep YAML whose settings to start from (its axes "
                   "must be fixed with --set)")
    p.add_argument("--set", action="append", default=[], metavar="KEY=VALUE",
                   help="set a dotted config key, e.g. --set field.d_rr=3.0 (repeatable)")
    p.add_argument("--no-progress", action="store_true", help="no progress lines")
    runtime.add_args(p)
    p.add_argument("--force", action="store_true",
                   help="run even when the memory estimate exceeds this machine's memory")
    return p


def main(argv: list[str] | None = None) -> int:
    args = parser().parse_args(argv)
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
        with interrupt.HardStop():
            cli.run_episodes(run, args.n, args.out, not args.no_progress)
    except ValueError as e:
        print(f"error: {e}", file=sys.stderr)
        return 2
    except KeyboardInterrupt:
        return 130
    return 0


if __name__ == "__main__":
    sys.exit(main())
