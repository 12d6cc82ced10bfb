import sys

from mjxrow.episode import main

if __name__ == "__main__":
    sys.exit(main())
