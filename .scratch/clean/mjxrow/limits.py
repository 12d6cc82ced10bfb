"""Upper bounds on the numbers that size a run: checked on the config, before any folder, array
or compiled program exists, so that a typo (`seeds: 1e9`, `field.d_rr: 1e9`, `camera.width:
100000`) is a one-line error naming its key instead of a run that exhausts memory or hangs.

The bounds are far beyond any field or experiment of the paper (a 60 × 38 m field, 64 px images,
60 s episodes at 15 Hz, 8 seeds); raise one here if a real experiment needs more.
"""

from __future__ import annotations

import math
from typing import Any

# dotted key → (largest value, unit); each value must also be finite
VALUES: dict[str, tuple[float, str]] = {
    "seeds": (100_000, "episodes per cell"),
    "batch_size": (1_000_000, "episodes per call"),
    "seed": (2**32 - 1, ""),
    "sim.control_hz": (1_000.0, "Hz"),
    "sim.path_length": (1_000.0, "m"),
    "sim.patch_back": (100.0, "m"),
    "sim.patch_front": (100.0, "m"),
    "sim.patch_width": (100.0, "m"),
    "sim.patch_z": (1_000.0, "m"),
    "sim.iterations": (100, ""),
    "sim.ls_iterations": (100, ""),
    "sim.obstacle_slots": (1_000, ""),
    "sim.obstacle_candidates": (10_000, ""),
    "episode.max_time": (3_600.0, "s"),
    "episode.stuck_window": (100_000, "steps"),
    "episode.collision_window": (1_000, "plants"),
    "camera.width": (2_048, "px"),
    "camera.height": (2_048, "px"),
    "field.d_rr": (100.0, "m"),
    "field.d_RR": (100.0, "m"),
    "field.d_pp": (100.0, "m"),
    "field.rows_per_group": (1_000, "rows"),
    "field.row_length": (1_000.0, "m"),
    "field.terrain_length": (1_000.0, "m"),
    "field.terrain_width": (1_000.0, "m"),
    "field.plant_length": (50.0, "m"),
    "field.plant_width": (50.0, "m"),
    "field.plant_height": (50.0, "m"),
    "field.plant_jitter": (10.0, "m"),
    "field.terrain_dh": (50.0, "m"),
    "field.terrain_scale": (1_000.0, "m"),
    "field.stone_density": (1_000.0, "per 100 m²"),
    "field.branch_density": (1_000.0, "per 100 m²"),
    "field.scale": (100.0, ""),
}

# derived sizes: name → (largest value, the key to blame, what it counts)
CELLS = 100_000  # grid cells of one sweep
AXIS_VALUES = 10_000  # values of one range axis ({start, stop, num}: num)
EPISODES = 10_000_000  # episodes of one sweep (cells × seeds) or one episode command (--n)
STEPS = 100_000  # control steps of one episode: ceil(episode.max_time · sim.control_hz)
SUBSTEPS = 1_000  # physics steps per control step: ceil(1 / (sim.control_hz · sim.dt))
PIXELS = 2**22  # camera.width · camera.height
PATCH_CELLS = 2**22  # heightfield cells of the simulated terrain patch (sim.patch_cell)
ROWS = 4_096  # rows of one field (blame: field.d_rr)
PLANTS_PER_ROW = 100_000  # plants per row (blame: field.d_pp)
OBSTACLES = 100_000  # stones and branches of one field (blame: field.stone_density)


class LimitError(ValueError):
    """A number beyond its bound; the message starts with the dotted key."""


def _fmt(v: float) -> str:
    return f"{v:,.6g}" if isinstance(v, float) else f"{v:,}"


def check_value(key: str, value: Any) -> None:
    """LimitError if `value` of dotted `key` exceeds its bound in VALUES (None passes)."""
    if value is None or isinstance(value, (bool, str)) or key not in VALUES:
        return
    bound, unit = VALUES[key]
    unit = f" {unit}" if unit else ""
    if not math.isfinite(float(value)):
        raise LimitError(f"{key}: must be finite, got {value}")
    if float(value) > bound:
        raise LimitError(f"{key}: {_fmt(value)}{unit} is beyond the bound of {_fmt(bound)}{unit} "
                         f"(mjxrow/limits.py)")


def check_count(key: str, what: str, n: float, bound: float) -> None:
    """LimitError naming `key` when a derived count `n` (e.g. control steps) exceeds `bound`."""
    if not n <= bound:
        raise LimitError(f"{key}: gives {_fmt(n)} {what}, beyond the bound of {_fmt(bound)} "
                         f"(mjxrow/limits.py)")
