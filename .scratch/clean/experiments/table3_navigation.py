"""Table 3 (navigation) beside the paper's; the logic is `paper.table3`.

    python experiments/table3_navigation.py [--episodes 100] [--out runs/table3]   # print
    python experiments/table3_navigation.py --episodes 100 --doc docs/table3.md    # and write

The runs and OUT/table3.md go to `--out` (a run folder: an interrupted run resumes); the page
goes to docs/ only with `--doc`. The arguments are parsed before JAX is imported (`paper.cli`).
"""

import sys
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))  # run from a checkout, uninstalled
from paper import cli  # noqa: E402

if __name__ == "__main__":
    sys.exit(cli.main("paper.table3"))
