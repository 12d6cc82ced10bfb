"""mjxrow: batch evaluation of autonomous navigation in row-based crop fields with JAX and MJX.

One module per stage of the data flow: `field` → `worlds` (exports) / `sim` (physics) →
`render` → `seg` → `control` → `episode` → `metrics` → `sweep` (+ `plots`).
"""

__version__ = "0.1.0"
