"""The light half of `python -m mjxrow.sweep` (mjxrow.commands): its parser, the parse, and the
hand-over to `mjxrow.sweep.run.main`."""

from __future__ import annotations

import argparse
import textwrap

from mjxrow import commands

RUN = "mjxrow.sweep.run"  # the heavy module: its main(argv) runs the sweep


def parser() -> argparse.ArgumentParser:
    p = argparse.ArgumentParser(
        prog="python -m mjxrow.sweep", description=commands.module_doc(RUN).split("\n\n")[1],
        formatter_class=argparse.RawDescriptionHelpFormatter,
        epilog=textwrap.fill(
            "Exit codes: 0 done, 2 invalid configuration, output folder or resources (the key or "
            "option is named), 130 interrupted (the finished cells are kept; run the same "
            "command again to resume).", 88))
    p.add_argument("config", help="sweep YAML file")
    p.add_argument("--out", help="output directory (default: the YAML's `out`)")
    p.add_argument("--smoke", action="store_true",
                   help="2 × 2 cells, 2 seeds, short episodes, tiny images (a learned policy keeps "
                   "its own): a quick check")
    p.add_argument("--set", action="append", default=[], metavar="KEY=VALUE",
                   help="override a dotted key, e.g. --set field.d_rr=[1.2,1.8] (repeatable)")
    p.add_argument("--no-progress", action="store_true", help="no progress bar")
    commands.runtime_args(p)
    p.add_argument("--force", action="store_true",
                   help="run even when the memory estimate exceeds this machine's memory")
    return p


def main(argv: list[str] | None = None) -> int:
    parser().parse_args(argv)
    return commands.run_command(RUN, argv)
