"""Crops: one module per crop and the registry that names them.

A crop is one module that builds a `Crop` (its FieldParams preset, plant primitives, collision
footprint, palette, render depth settings, dataset sizes and the paper's values) and passes it
to `register`, plus one import line at the end of this file, as MuJoCo Playground registers its
environments. Everything that takes a crop name (field generation, `FieldShape`, rendering,
collision footprint, exports, the dataset writer) looks it up here when called, so a crop
registered later, e.g. from a test file, works everywhere.

`prims` holds the primitive builders the crop modules share (it imports no `mjxrow.field`, so
the crop modules can be imported by it).
"""

from __future__ import annotations

import dataclasses
import types
from collections.abc import Callable, Mapping
from typing import Any

import jax
import numpy as np

# FieldParams defaults every crop shares; a crop's preset overrides them.
COMMON_PRESET: Mapping[str, float] = types.MappingProxyType(dict(
    plant_size_var=0.08,
    plant_jitter=0.03,
    p_missing=0.03,
    terrain_scale=4.0,
    slope_x=0.0,
    slope_y=0.0,
    stone_density=1.0,
    branch_density=0.3,
    scale=1.0,
    row_amplitude=0.0,  # straight rows, no gap runs and no weeds unless asked for
    row_wavelength=10.0,
    row_curvature=0.0,
    gap_rate=0.0,
    gap_length=1.0,
    weed_density=0.0,
    weed_size=0.08,
))

# local(L, W, H, yaw, phase) -> (centre [..., K, 3], rot [..., K, 3, 3], size [..., K, 3],
# kind int [K], material int [K]); inputs float32 [...] (plant extents [m], yaw [rad], phase in
# [0, 1)); the frame has its origin at the plant's base.
LocalPrims = Callable[..., tuple[jax.Array, jax.Array, jax.Array, np.ndarray, np.ndarray]]
RGB = tuple[float, float, float]


@dataclasses.dataclass(frozen=True, eq=False)
class Crop:
    """Everything crop-specific, in one value.

    name: the key of the registry and of `FieldShape.crop`.
    preset: FieldParams defaults [m, counts, -]; the names it leaves out take COMMON_PRESET's
        values (stored merged and read-only, the crop's own names first).
    local: the plant as K primitives in its local frame (see `LocalPrims`; builders in `prims`).
    palette: sRGB albedo in [0, 1] per material (LEAF, STEM, TRUNK, CANOPY, FRUIT).
    trunk_radius: collision footprint of a plant: a circle of this radius [m] about its base,
        or None for the axis-aligned ellipse of half the plant's length and width.
    silver_leaf: pale mottled patches on the leaf blades (zucchini).
    deep: the renderer's deep-tile settings (share, row_blocks, block_keep, keep), or None for
        `render.config.DEEP_DEFAULT` (small plants in many rows need more).
    dataset_n: samples of the paper's dataset for this crop; test_frac: its test share.
    paper: the paper's printed values: optional 'table1' (FieldParams names → value),
        'table2' (accuracy, iou) and 'table3' (cha, mae, mse, omega_std).
    """

    name: str
    preset: Mapping[str, float]
    local: LocalPrims
    palette: tuple[RGB, RGB, RGB, RGB, RGB]
    trunk_radius: float | None = None
    silver_leaf: bool = False
    deep: tuple[float, int, int, int] | None = None
    dataset_n: int = 4864
    test_frac: float = 0.25
    paper: Mapping[str, Mapping[str, float]] = dataclasses.field(default_factory=dict)

    def __post_init__(self):
        if not isinstance(self.name, str) or not self.name:
            raise ValueError(f"name: a crop needs a non-empty name, got {self.name!r}")
        if not callable(self.local):
            raise ValueError(f"local: crop {self.name!r} needs a function, got {self.local!r}")
        if len(self.palette) != 5 or any(len(c) != 3 for c in self.palette):
            raise ValueError(f"palette: crop {self.name!r} needs 5 sRGB triples "
                             "(leaf, stem, trunk, canopy, fruit)")
        if self.deep is not None and len(self.deep) != 4:
            raise ValueError(f"deep: crop {self.name!r} needs (share, row_blocks, block_keep, "
                             f"keep) or None, got {self.deep!r}")
        if not 0.0 <= self.test_frac < 1.0:
            raise ValueError(f"test_frac: crop {self.name!r}: must lie in [0, 1), got "
                             f"{self.test_frac}")
        merged = {**self.preset, **{k: v for k, v in COMMON_PRESET.items()
                                    if k not in self.preset}}
        object.__setattr__(self, "preset", types.MappingProxyType(merged))


CROPS: dict[str, Crop] = {}


def register(crop: Crop) -> Crop:
    """Add `crop` to the registry under its name (registration order is `names()`)."""
    if crop.name in CROPS:
        raise ValueError(f"crop: {crop.name!r} is already registered (pop it from "
                         "mjxrow.crops.CROPS to replace it)")
    CROPS[crop.name] = crop
    return crop


def get(name: Any) -> Crop:
    """The registered crop `name`; ValueError naming it otherwise."""
    try:
        return CROPS[name]
    except (KeyError, TypeError):
        raise ValueError(f"crop: unknown crop {name!r}; expected one of {names()}") from None


def names() -> tuple[str, ...]:
    """Names of the registered crops, in registration order."""
    return tuple(CROPS)


# The registry lines of the built-in crops (this order is `names()`'s).
from mjxrow.crops import zucchini  # noqa: E402, F401, I001
from mjxrow.crops import lettuce  # noqa: E402, F401
from mjxrow.crops import chard  # noqa: E402, F401
from mjxrow.crops import pear  # noqa: E402, F401
from mjxrow.crops import vineyard  # noqa: E402, F401
