"""mjxrow: batch evaluation of autonomous navigation in row-based crop fields with JAX and MJX.

One module per stage of the data flow: `field` → `worlds` (exports) / `sim` (physics) →
`render` → `seg` → `control` → `episode` → `metrics` → `sweep` (+ `plots`).
"""

import os as _os
import time as _time

STARTED = _time.time()  # when a command first imported the package: the start of its start-up

# XLA's C++ warnings (on GPUs, the autotuner's "Delay kernel timed out" timer lines) are not the
# user's business; errors still show. An explicit TF_CPP_MIN_LOG_LEVEL wins.
_os.environ.setdefault("TF_CPP_MIN_LOG_LEVEL", "2")

__version__ = "0.1.0"
