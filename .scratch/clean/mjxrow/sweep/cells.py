"""The finished cells of a sweep folder: which cell files can be reused on resume.

A cell file `cells/<hash>.csv` is written atomically when a cell's last episode is in; a re-run
reuses it only when it is whole: not empty, ending with a newline (not cut short), with rows, its
identity columns complete, every episode 0 … seeds−1 once, and its own hash inside.
"""

from __future__ import annotations

import re
import sys
from pathlib import Path

import pandas as pd

from mjxrow import files

IDENTITY = ("cell", "episode", "cell_hash")


def cell_file_problem(path: Path, seeds: int | None) -> str | None:
    """Why a cell file cannot be reused (None: it can): empty, cut short (no final newline),
    header only, unreadable, episodes missing or repeated, another cell's hash inside."""
    try:
        data = path.read_bytes()
    except OSError as e:
        return f"unreadable ({e.strerror})"
    if not data.strip():
        return "empty"
    if not data.endswith(b"\n"):
        return "cut short (no final newline)"
    try:
        df = pd.read_csv(path)
    except (pd.errors.ParserError, pd.errors.EmptyDataError, UnicodeDecodeError) as e:
        return f"not a readable table ({str(e).splitlines()[0]})"
    missing = [c for c in IDENTITY if c not in df]
    if missing:
        return f"no {missing[0]} column"
    if df.empty:
        return "header only"
    if df[list(IDENTITY)].isna().any().any():
        return "rows cut short"
    if set(df["cell_hash"].astype(str)) != {path.stem}:
        return "holds another cell's rows"
    if seeds is not None and sorted(df["episode"].tolist()) != list(range(seeds)):
        return f"{len(df)} of {seeds} episodes"
    return None


CELL_NAME = re.compile(r"^[0-9a-f]{16}\.csv$")  # a cell file: its hash (grid.cell_hash)


def finished_cells(cells_dir: Path, seeds: int | None = None, report: bool = False) -> set[str]:
    """Hashes of the finished cells whose file passes `cell_file_problem` (with `seeds`, every
    episode must be there). With `report` (only under the folder's lock): removes the temp
    files a killed run may have left, and each damaged cell file, saying so on stderr, so that
    the cell is recomputed. Only files named as cells (CELL_NAME) and our temp files are
    read or removed: anything else in the folder is the user's."""
    if not cells_dir.is_dir():
        return set()
    for tmp in files.temp_files(cells_dir) if report else ():
        tmp.unlink(missing_ok=True)
    done = set()
    for p in sorted(q for q in cells_dir.glob("*.csv") if CELL_NAME.match(q.name)):
        problem = cell_file_problem(p, seeds)
        if problem is None:
            done.add(p.stem)
        elif report:
            print(f"{p}: {problem}; the cell is run again", file=sys.stderr)
            p.unlink(missing_ok=True)
    return done
