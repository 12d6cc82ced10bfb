"""The work of `python -m mjxrow.bench STAGE` (the stage list: `mjxrow.bench.cli`): the
stage's own flags parsed, the stage measured, its rows appended to benchmarks.jsonl and
printed."""

from __future__ import annotations

import argparse
import importlib

from mjxrow import runtime
from mjxrow.bench import STAGES
from mjxrow.bench import cli as command
from mjxrow.bench.timing import print_table, record
from mjxrow.files import check_out_file


def main(argv: list[str] | None = None) -> None:
    """The command (`mjxrow.bench.cli.main` hands over here)."""
    parser = argparse.ArgumentParser(prog=command.PROG,
                                     description=command.__doc__.split("\n\n")[0])
    sub = parser.add_subparsers(dest="stage", required=True)
    modules = {}
    for stage in STAGES:
        try:
            modules[stage] = importlib.import_module(f"mjxrow.bench.{stage}")
        except ModuleNotFoundError as e:
            if e.name != f"mjxrow.bench.{stage}":
                raise
            continue
        p = sub.add_parser(stage, help=command.first_sentence(modules[stage].__doc__))
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
