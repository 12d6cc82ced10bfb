"""`python -m mjxrow.sweep SWEEP.yaml [--out DIR] [--smoke] [--set KEY=VALUE ...]`."""

import sys

from mjxrow.sweep import cli

if __name__ == "__main__":
    sys.exit(cli.main())
