"""python -m mjxrow.bench STAGE [options]: measure one stage and append to benchmarks.jsonl.

The command's light half (mjxrow.commands): the stage list and the hand-over to
`mjxrow.bench.run`, which parses the stage's own flags and measures."""

from __future__ import annotations

import argparse
import re

from mjxrow import commands
from mjxrow.bench import STAGES

PROG = "python -m mjxrow.bench"
RUN = "mjxrow.bench.run"  # the heavy module: its main(argv) parses the stage's flags and measures


def first_sentence(doc: str) -> str:
    """The first sentence of a docstring's first paragraph, whole (for --help lines)."""
    para = " ".join(doc.strip().split("\n\n")[0].split())
    return re.split(r"(?<=\.)\s", para, maxsplit=1)[0]


def stages() -> dict[str, str]:
    """Stage → its --help line, read from the stage module's docstring without importing it;
    a stage whose module is absent is left out."""
    out = {}
    for stage in STAGES:
        try:
            out[stage] = first_sentence(commands.module_doc(f"mjxrow.bench.{stage}"))
        except ModuleNotFoundError:
            continue
    return out


def parser() -> argparse.ArgumentParser:
    """The stage list; a stage's own flags (and its --help) are parsed by `mjxrow.bench.run`."""
    p = argparse.ArgumentParser(prog=PROG, description=__doc__.split("\n\n")[0],
                                epilog=f"A stage's own options: {PROG} STAGE --help.")
    sub = p.add_subparsers(dest="stage", metavar="STAGE", required=True)
    for stage, line in stages().items():
        sub.add_parser(stage, help=line, add_help=False)  # its flags (--help too): run's
    return p


def main(argv: list[str] | None = None) -> None:
    parser().parse_known_args(argv)  # the stage's own flags are run's to parse
    commands.run_command(RUN, argv)
