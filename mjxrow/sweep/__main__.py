"""`python -m mjxrow.sweep SWEEP.yaml [--out DIR] [--smoke] [--set KEY=VALUE ...]`."""

import sys

from mjxrow.sweep.run import main

if __name__ == "__main__":
    sys.exit(main())
