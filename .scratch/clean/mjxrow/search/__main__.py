"""`python -m mjxrow.search SEARCH.yaml [--out DIR] [--smoke] [--set KEY=VALUE ...]`."""

import sys

from mjxrow.search import cli

if __name__ == "__main__":
    sys.exit(cli.main())
