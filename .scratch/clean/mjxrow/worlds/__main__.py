import sys

from mjxrow.worlds import cli

if __name__ == "__main__":
    sys.exit(cli.main())
