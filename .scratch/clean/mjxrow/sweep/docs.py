"""`python -m mjxrow.sweep.docs`: regenerate the key table of docs/sweep.md from the code
(`reference_markdown`: every key of the sweep YAML with its type, default, whether it is
static, and its meaning)."""

from __future__ import annotations

import argparse
import sys

from mjxrow import commands

# the command's light half (mjxrow.commands): the parser and the hand-over to the heavy module
RUN = "mjxrow.sweep.reference"  # the heavy module: its main(argv) regenerates the table


def parser() -> argparse.ArgumentParser:
    ap = argparse.ArgumentParser(prog="python -m mjxrow.sweep.docs", description=__doc__)
    ap.add_argument("path", nargs="?", default="docs/sweep.md",
                    help="markdown file holding the marker line (default: docs/sweep.md)")
    return ap


def main(argv: list[str] | None = None) -> int:
    parser().parse_args(argv)
    return commands.run_command(RUN, argv)


if __name__ == "__main__":
    sys.exit(main())
