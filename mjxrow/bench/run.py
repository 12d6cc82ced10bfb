"""python -m mjxrow.bench STAGE [options]: measure one stage and append to benchmarks.jsonl."""

from __future__ import annotations

import argparse
import importlib
import re

from mjxrow import runtime
from mjxrow.bench import STAGES, print_table, record
from mjxrow.files import check_out_file


def _first_sentence(doc: str) -> str:
    """The first sentence of a docstring's first paragraph, whole (for --help lines)."""
    para = " ".join(doc.strip().split("\n\n")[0].split())
    return re.split(r"(?<=\.)\s", para, maxsplit=1)[0]


def main(argv: list[str] | None = None) -> None:
    parser = argparse.ArgumentParser(prog="python -m mjxrow.bench", description=__doc__)
    sub = parser.add_subparsers(dest="stage", required=True)
    modules = {}
    for stage in STAGES:
        try:
            modules[stage] = importlib.import_module(f"mjxrow.bench.{stage}")
        except ModuleNotFoundError as e:
            if e.name != f"mjxrow.bench.{stage}":
                raise
            continue
        p = sub.add_parser(stage, help=_first_sentence(modules[stage].__doc__))
        modules[stage].add_args(p)
        p.add_argument("--out", default="benchmarks.jsonl", help="JSON-lines file to append to")
        p.add_argument("--no-record", action="store_true", help="print only")
        runtime.add_args(p)
    args = parser.parse_args(argv)
    try:  # the closed loop runs as the sweep does: on a CPU, one device per core
        runtime.setup(args, cpu_split=args.stage == "closed_loop")
        if not args.no_record:  # the record file must be writable before any measurement

            check_out_file(args.out, "--out")
    except ValueError as e:
        parser.error(str(e))
    rows = modules[args.stage].run(args)
    if not runtime.writer():
        return
    if not args.no_record:
        record(rows, args.out)
    print_table(rows)


if __name__ == "__main__":
    main()
