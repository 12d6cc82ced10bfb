"""The light half of `python -m mjxrow.search` (mjxrow.commands): its parser, the parse, and
the hand-over to `mjxrow.search.run.main`."""

from __future__ import annotations

import argparse
import textwrap

from mjxrow import commands

RUN = "mjxrow.search.run"  # the heavy module: its main(argv) runs the search


def parser() -> argparse.ArgumentParser:
    p = argparse.ArgumentParser(
        prog="python -m mjxrow.search", description=commands.module_doc(RUN).split("\n\n")[1],
        formatter_class=argparse.RawDescriptionHelpFormatter,
        epilog=textwrap.fill(
            "Exit codes: 0 done, 2 invalid configuration or output folder (the key or option is "
            "named), 130 interrupted (every finished generation is kept; run the same command "
            "again to resume). Reference: docs/search.md.", 88))
    p.add_argument("config", help="search YAML file (searches/*.yaml are examples)")
    p.add_argument("--out", help="output directory (default: the YAML's `out`)")
    p.add_argument("--smoke", action="store_true",
                   help="generations of 8 candidates × 1 episode, 16 episodes, short episodes, "
                   "tiny images (a learned policy keeps its own): a quick check")
    p.add_argument("--set", action="append", default=[], metavar="KEY=VALUE",
                   help="override a dotted key, e.g. --set budget.episodes=2000 or "
                   "--set box.field.d_rr=[1.2,2.4] (repeatable)")
    p.add_argument("--confirm", type=int, default=0, metavar="N",
                   help="re-run the top distinct failures with N new seeds each and report how "
                   "often each fails again (confirm.csv)")
    p.add_argument("--confirm-top", type=int, default=20, metavar="K",
                   help="how many of the ranked failures --confirm re-runs (default %(default)s)")
    p.add_argument("--record", metavar="JSONL",
                   help="append the search's figures to this benchmarks file (e.g. "
                   "benchmarks.jsonl)")
    p.add_argument("--no-progress", action="store_true", help="no progress bar")
    commands.runtime_args(p)
    return p


def parse(argv: list[str] | None = None) -> argparse.Namespace:
    ap = parser()
    args = ap.parse_args(argv)
    if args.confirm < 0:
        ap.error("--confirm: N must be 0 (off) or more")
    if args.confirm_top < 1:
        ap.error("--confirm-top: K must be at least 1")
    return args


def main(argv: list[str] | None = None) -> int:
    parse(argv)
    return commands.run_command(RUN, argv)
