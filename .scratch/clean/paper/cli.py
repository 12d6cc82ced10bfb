"""The light half of the paper's table commands (mjxrow.commands): `experiments/table1.py`,
`table2_segmentation.py` and `table3_navigation.py` parse their arguments here (so `--help` and a
bad flag answer before JAX is imported), then hand over to `paper.table1`, `paper.table2` and
`paper.table3`, whose entries parse again with the same parser.

Every table is printed; it is written to a file only where the command is told to (`--out FILE`
for Tables 1 and 2, `--doc FILE` for Table 3, e.g. `docs/table3.md`): no default run rewrites a
page of docs/.
"""

from __future__ import annotations

import argparse
import importlib.resources
from pathlib import Path

from mjxrow import commands

# the scenario of Table 3 (package data; paper.table3 reads it)
BASE_YAML = Path(str(importlib.resources.files("mjxrow.sweep").joinpath("presets.yaml")))
CONTROLLERS = ("oracle", "segzeros_gt", "segzeros_learned", "policy")  # = paper.table3.CONTROLLERS
DEFAULT_CONTROLLERS = ("oracle", "segzeros_gt", "segzeros_learned")  # `policy` on request


def table1() -> argparse.ArgumentParser:
    doc = commands.module_doc("paper.table1")
    ap = argparse.ArgumentParser(prog="python experiments/table1.py",
                                 description=doc.split("\n")[0])
    ap.add_argument("--seeds", type=int, default=5, help="fields per preset (seeds 0..N-1)")
    ap.add_argument("--out", metavar="FILE", help="also write the page (markdown) here, e.g. "
                    "docs/table1.md (default: print only)")
    return ap


def table2() -> argparse.ArgumentParser:
    p = argparse.ArgumentParser(prog="python experiments/table2_segmentation.py",
                                description=commands.module_doc("paper.table2"),
                                formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--ckpt-root", metavar="DIR",
                   help="checkpoint folders <DIR>/<crop>/ (default: the shipped "
                   "mjxrow/checkpoints/)")
    p.add_argument("--data-root", help="dataset folder(s) written by python -m mjxrow.seg.synth")
    p.add_argument("--n", type=int, default=512, help="renders per crop without --data-root")
    p.add_argument("--batch", type=int, default=32)
    p.add_argument("--seed", type=int, default=0)
    p.add_argument("--crops", nargs="+", metavar="CROP",
                   help="registered crops to test on (default: every one)")
    p.add_argument("--also-sizes", type=int, nargs="*", default=[],
                   help="input sizes [px] at which each crop's model is also evaluated, beside "
                        "its own (e.g. 64: the closed loop's camera)")
    p.add_argument("--out", metavar="FILE", help="also write the markdown tables here, e.g. "
                   "docs/table2.md (default: print only)")
    return p


def table3() -> argparse.ArgumentParser:
    doc = commands.module_doc("paper.table3")
    p = argparse.ArgumentParser(prog="python experiments/table3_navigation.py",
                                description=doc.split("\n\n")[0],
                                formatter_class=argparse.RawDescriptionHelpFormatter,
                                epilog=doc.split("\n\n", 1)[1])
    p.add_argument("--episodes", type=int, default=100, help="episodes per block (default 100)")
    p.add_argument("--presets", nargs="+", metavar="P",
                   help="registered crops (default: every one)")
    p.add_argument("--controllers", nargs="+", default=list(DEFAULT_CONTROLLERS),
                   choices=CONTROLLERS)
    p.add_argument("--out", default="runs/table3", help="run folder (with --smoke: OUT_smoke)")
    p.add_argument("--image", type=int, default=None,
                   help="camera side in pixels (default: the base YAML's, 64)")
    p.add_argument("--batch-size", type=int, default=256, help="episodes per jitted call")
    p.add_argument("--seed", type=int, default=0)
    p.add_argument("--base", default=str(BASE_YAML), help="scenario YAML (default %(default)s)")
    p.add_argument("--doc", metavar="FILE", default=None,
                   help="also write the page here, e.g. docs/table3.md (default: only "
                   "OUT/table3.md)")
    p.add_argument("--smoke", action="store_true",
                   help="tiny check: 2 episodes, 16 × 16 images, 1.5 m paths in 6 m rows")
    p.add_argument("--separate", action="store_true",
                   help="one program per block (default: the controllers of a preset share "
                   "one program, every episode running all their stages)")
    p.add_argument("--no-progress", action="store_true")
    commands.runtime_args(p)  # --cache-dir, --no-cache, --coordinator, ...
    return p


PARSERS = {"paper.table1": table1, "paper.table2": table2, "paper.table3": table3}


def main(module: str, argv: list[str] | None = None, entry: str = "main"):
    """Parse `argv` with the parser of `module` (one of PARSERS), then hand over to
    `module.entry(argv)`; returns what that returns (an exit code)."""
    PARSERS[module]().parse_args(argv)
    return commands.run_command(module, argv, entry)
