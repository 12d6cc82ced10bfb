"""Do two Table 3 pages agree? Every `ours:` row's 95 % intervals, metric by metric.

    python experiments/compare_table3.py docs/table3.md runs/table3/table3.md

Reads the pipe tables of two pages written by `experiments/table3_navigation.py`, pairs the
rows by (crop, controller) and, for every metric column that holds `mean [lo, hi]` in both,
says whether the two intervals overlap. Prints one line per disjoint pair and a count; exits 1
if some pair is disjoint, 2 if the pages share no row. The check behind "the metrics must not
move beyond their intervals" (a faster build, fewer solver iterations, a shared program).
"""

from __future__ import annotations

import argparse
import re
import sys
from pathlib import Path

CELL = re.compile(r"^\s*(-?[\d.]+)\s*\[\s*(-?[\d.]+),\s*(-?[\d.]+)\s*\]\s*$")


def intervals(page: str) -> dict[tuple[str, str, str], tuple[float, float, float]]:
    """(crop, controller, column) → (mean, lo, hi) of every `ours:` row of a page."""
    out, head = {}, None
    for line in page.splitlines():
        if not line.startswith("|"):
            head = None if not line.strip() else head
            continue
        cells = [c.strip() for c in line.strip().strip("|").split("|")]
        if cells[:2] == ["crop", "controller"]:
            head = cells
            continue
        if head is None or not cells[1].startswith("ours:"):
            continue
        for col, cell in zip(head, cells, strict=False):
            m = CELL.match(cell)
            if m:
                out[(cells[0], cells[1][5:].strip(), col)] = tuple(float(x) for x in m.groups())
    return out


def compare(a: str, b: str) -> tuple[int, list[str]]:
    """(intervals compared, one line per pair that does not overlap)."""
    ia, ib = intervals(a), intervals(b)
    both = sorted(set(ia) & set(ib))
    bad = [", ".join(k) + f": {ia[k][0]:g} [{ia[k][1]:g}, {ia[k][2]:g}] against "
           f"{ib[k][0]:g} [{ib[k][1]:g}, {ib[k][2]:g}]"
           for k in both if ia[k][2] < ib[k][1] or ib[k][2] < ia[k][1]]
    return len(both), bad


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0],
                                formatter_class=argparse.RawDescriptionHelpFormatter,
                                epilog=__doc__.split("\n\n", 1)[1])
    p.add_argument("a", type=Path, help="a Table 3 page (markdown)")
    p.add_argument("b", type=Path, help="another one")
    args = p.parse_args(argv)
    try:
        n, bad = compare(args.a.read_text(), args.b.read_text())
    except OSError as e:
        p.error(f"{e.filename}: {e.strerror}")
    if not n:
        print("the pages share no (crop, controller, metric) interval", file=sys.stderr)
        return 2
    for line in bad:
        print(f"disjoint: {line}")
    print(f"{n - len(bad)} of {n} intervals overlap")
    return 1 if bad else 0


if __name__ == "__main__":
    sys.exit(main())
