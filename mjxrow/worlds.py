"""`python -m mjxrow.worlds`: export fields as MJCF + SDF + CSV (mjxrow.field.export)."""

import sys

from mjxrow.field.export import main

if __name__ == "__main__":
    sys.exit(main())
