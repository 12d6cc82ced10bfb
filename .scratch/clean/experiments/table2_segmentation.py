"""Table 2 (segmentation) beside the paper's; the logic is `paper.table2`.

    python experiments/table2_segmentation.py [--n 512] [--also-sizes 128 64]    # print
    python experiments/table2_segmentation.py --n 512 --out docs/table2.md       # and write

The arguments are parsed before JAX is imported (`paper.cli`); no default run writes a file.
"""

import sys
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))  # run from a checkout, uninstalled
from paper import cli  # noqa: E402

if __name__ == "__main__":
    sys.exit(cli.main("paper.table2", entry="command"))
