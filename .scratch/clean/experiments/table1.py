"""Table 1 (field geometry) beside the paper's; the logic is `paper.table1`.

    python experiments/table1.py [--seeds 5]                  # print the table
    python experiments/table1.py --out docs/table1.md         # and write the docs page

The arguments are parsed before JAX is imported (`paper.cli`); no default run writes a file.
"""

import sys
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))  # run from a checkout, uninstalled
from paper import cli  # noqa: E402

if __name__ == "__main__":
    sys.exit(cli.main("paper.table1"))
