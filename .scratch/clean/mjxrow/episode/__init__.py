"""`python -m mjxrow.episode`: one batch of episodes of one configuration → DIR/episodes.csv.

    python -m mjxrow.episode --preset vineyard --controller oracle --n 8 --seed 0 --out DIR
        [--config SWEEP.yaml] [--set KEY=VALUE ...] [--overwrite]

Any key of the sweep YAML's sections can be set (`--set field.d_rr=3.0 --set
episode.max_time=30 --set camera.width=112`; docs/sweep.md lists them); the same seed and
settings give the same episodes as a sweep cell with those settings. An `episodes.csv` already
in DIR (an earlier run's) is kept: the command refuses before any work unless `--overwrite`.

This module is the command's light half (mjxrow.commands): the parser and the hand-over to
`mjxrow.episode.run`, which does the work.
"""

from __future__ import annotations

import argparse

from mjxrow import commands

RUN = "mjxrow.episode.run"  # the heavy module: its main(argv) runs the episodes


def parser() -> argparse.ArgumentParser:
    p = argparse.ArgumentParser(prog="python -m mjxrow.episode", description=__doc__.split(
        "\n")[0].split(": ", 1)[1], formatter_class=argparse.RawDescriptionHelpFormatter,
        epilog="Exit codes: 0 done, 2 invalid configuration or output folder (the key or option "
        "is named), 130 interrupted (Ctrl-C or SIGTERM; nothing written).")
    p.add_argument("--preset", metavar="P", help="crop preset, a registered crop (default: "
                   "vineyard, or the config's)")
    p.add_argument("--controller", metavar="C", help="controller.name, a registered controller: "
                   "oracle, segzeros, segmin, policy, ... (default: oracle, or the config's)")
    p.add_argument("--perception", choices=("ground_truth", "learned"),
                   help="perception.source of the mask controllers (default: ground_truth, or "
                   "the config's)")
    p.add_argument("--n", type=int, default=8, help="episodes (one field each)")
    p.add_argument("--seed", type=int, default=0, help="base seed; episode i uses "
                   "fold_in(key(seed), i), as a sweep cell")
    p.add_argument("--out", required=True, help="output directory (episodes.csv)")
    p.add_argument("--overwrite", action="store_true",
                   help="replace an episodes.csv that --out already holds (default: refuse)")
    p.add_argument("--config", help="a sweep YAML whose settings to start from (its axes "
                   "must be fixed with --set)")
    p.add_argument("--set", action="append", default=[], metavar="KEY=VALUE",
                   help="set a dotted config key, e.g. --set field.d_rr=3.0 (repeatable)")
    p.add_argument("--no-progress", action="store_true", help="no progress lines")
    commands.runtime_args(p)
    p.add_argument("--force", action="store_true",
                   help="run even when the memory estimate exceeds this machine's memory")
    return p


def main(argv: list[str] | None = None) -> int:
    """The command: 0 done, 2 invalid input (one line naming the key or option), 130
    interrupted."""
    parser().parse_args(argv)
    return commands.run_command(RUN, argv)
