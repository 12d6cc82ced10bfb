"""The light half of every command: what a command needs before its arguments are known.

A command (`python -m mjxrow.sweep`, `mjxrow.episode`, `mjxrow.worlds`, `mjxrow.bench`,
`mjxrow.seg.synth`, `.train`, `.eval`, `.export`, `mjxrow.sweep.docs`, `experiments/table*.py`)
is two modules: a light one that builds the argument parser and parses (so `--help` and a bad
flag answer at once, before JAX, MuJoCo, Flax, orbax, pandas or matplotlib are imported), and
the heavy one that does the work. The light module imports only the standard library and other
light modules (this one, `limits`); the hand-over is `run_command`, the one place where a
command imports its heavy module inside a function: the documented exception to "mjxrow imports
at the top of the module". tests/test_commands.py runs each `--help` and checks that JAX stays
out.

    def main(argv=None):                       # the light module
        parser().parse_args(argv)              # --help and argument errors exit here
        return commands.run_command("mjxrow.sweep.run", argv)

The heavy module's entry parses `argv` again with the same `parser()` (cheap) and runs.
`module_doc` reads a heavy module's docstring (for a description or help line) without
importing it. The flags every JAX command shares (`runtime_args`: the compilation cache and the
processes of a multi-host run) are defined here too, so that a light parser can offer them;
`mjxrow.runtime` acts on them (and keeps the name `runtime.add_args`).
"""

from __future__ import annotations

import argparse
import ast
import importlib
import importlib.util
from collections.abc import Sequence
from typing import Any

CACHE_ENV = "MJXROW_CACHE_DIR"
CLUSTER_ENV = {"coordinator": "MJXROW_COORDINATOR", "num_processes": "MJXROW_NUM_PROCESSES",
               "process_id": "MJXROW_PROCESS_ID"}


def run_command(module_name: str, argv: Sequence[str] | None = None,
                entry: str = "main") -> Any:
    """`module_name.entry(argv)`: hand a parsed command over to its heavy module (imported
    here, once the arguments are known to be good). Returns what the entry returns (the exit
    code of a command)."""
    module = importlib.import_module(module_name)
    return getattr(module, entry)(None if argv is None else list(argv))


def module_doc(module_name: str) -> str:
    """The docstring of a module, read from its source without importing it (its parent
    packages are imported: they must be light)."""
    spec = importlib.util.find_spec(module_name)
    if spec is None or not spec.origin:
        raise ModuleNotFoundError(f"no module named {module_name!r}", name=module_name)
    with open(spec.origin, encoding="utf-8") as f:
        return ast.get_docstring(ast.parse(f.read()), clean=False) or ""


def runtime_args(p: argparse.ArgumentParser) -> None:
    """--cache-dir, --no-cache and the multi-process flags (`mjxrow.runtime.setup` reads
    them)."""
    g = p.add_argument_group("compilation cache and processes")
    g.add_argument("--cache-dir", metavar="DIR", help="persistent compilation cache (default: "
                   f"${CACHE_ENV}, else $XDG_CACHE_HOME/mjxrow/jax, else ~/.cache/mjxrow/jax)")
    g.add_argument("--no-cache", action="store_true", help="compile everything afresh, store "
                   "nothing")
    g.add_argument("--nondeterministic", action="store_true",
                   help="on a GPU, let XLA use its faster non-deterministic kernels (runs then "
                   "differ by float rounding; the deterministic default costs about a fifth of "
                   "the run time; or $MJXROW_NONDETERMINISTIC=1)")
    g.add_argument("--coordinator", metavar="HOST:PORT", help="address of process 0 for a run "
                   f"over several processes (or ${CLUSTER_ENV['coordinator']})")
    g.add_argument("--num-processes", type=int, metavar="N",
                   help=f"processes taking part (or ${CLUSTER_ENV['num_processes']})")
    g.add_argument("--process-id", type=int, metavar="I",
                   help=f"this process's index, 0..N-1 (or ${CLUSTER_ENV['process_id']})")
