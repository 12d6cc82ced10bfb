import sys

from mjxrow.worlds.cli import main

if __name__ == "__main__":
    sys.exit(main())
