"""Table 1 (field geometry) beside the paper's; the logic is `paper.table1`."""

import sys
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))  # run from a checkout, uninstalled
from paper.table1 import main  # noqa: E402

if __name__ == "__main__":
    sys.exit(main())
