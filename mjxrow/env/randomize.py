"""Domain randomisation over the whole generator: every reset draws FieldParams from ranges,
a sky / lighting condition (with its colour, sun and exposure jitter), a camera-mount jitter
and a start pose.

`Randomize` is static (hashable); `sample(rz, base, key)` is pure and jittable. Ranges are
uniform and independent, (lo, hi) per FieldParams name; the static field shape is fitted to
the corners of the box (`corner_params`), and every corner must be a valid field
(`check_ranges`), so that every draw fits the compiled shapes.
"""

from __future__ import annotations

import dataclasses
import itertools
import math
from typing import ClassVar

import jax
import jax.numpy as jnp
import numpy as np
from flax import struct

from mjxrow import field
from mjxrow.render import shade

# Default ranges per preset (metres, slopes dz/dx, densities per 100 m², weeds per m²,
# curvature 1/m): wide enough to cover the default sweep (d_rr 1.5-2.5 m, |ΔH| 0-0.5 m),
# sweeps/slope_roughness.yaml (lateral slope 0-0.25, |ΔH| 0-0.5 m), the gap lengths of
# sweeps/curvature_gaps.yaml (0.7-3.5 m), weeds up to 4 per m² and 0.25 m wide (the size of
# sweeps/weeds.yaml's) and the box of
# searches/*_variety.yaml (curved rows, gap runs, weeds, plant width 0.6-1.0 m) for zucchini,
# and the same spirit around the other presets' defaults (one row per group in vineyard and
# pear: their rows are d_RR apart).
_COMMON = {"terrain_dh": (0.0, 0.5), "slope_y": (-0.25, 0.25), "slope_x": (-0.05, 0.05),
           "p_missing": (0.0, 0.15), "stone_density": (0.0, 3.0), "branch_density": (0.0, 1.0),
           "plant_size_var": (0.03, 0.15), "plant_jitter": (0.0, 0.06),
           "terrain_scale": (2.0, 6.0), "row_curvature": (0.0, 0.012),
           "gap_rate": (0.0, 1.5), "gap_length": (0.7, 3.5), "weed_density": (0.0, 4.0),
           "weed_size": (0.05, 0.25)}
RANGES: dict[str, dict[str, tuple[float, float]]] = {
    "zucchini": {**_COMMON, "d_rr": (1.5, 2.5), "d_pp": (0.55, 0.9),
                 "plant_height": (0.45, 0.75), "plant_width": (0.6, 1.0)},
    "vineyard": {**_COMMON, "d_RR": (2.2, 3.2), "d_pp": (0.8, 1.3),
                 "plant_height": (1.6, 2.2), "plant_width": (0.4, 0.7)},
    "pear": {**_COMMON, "d_RR": (4.0, 6.0), "d_pp": (1.8, 2.6)},
    "lettuce": {**_COMMON, "terrain_dh": (0.0, 0.35), "d_RR": (1.2, 1.8), "d_pp": (0.3, 0.5)},
    "chard": {**_COMMON, "terrain_dh": (0.0, 0.35), "d_RR": (1.2, 1.8), "d_pp": (0.25, 0.4)},
}


def default_ranges(preset: str) -> tuple[tuple[str, float, float], ...]:
    """The default ranges of a preset as `Randomize.ranges`."""
    return tuple((k, float(lo), float(hi)) for k, (lo, hi) in RANGES[preset].items())


@dataclasses.dataclass(frozen=True)
class Randomize:
    """What every reset draws (static). `ranges` of None: the preset's `RANGES`."""

    ranges: tuple[tuple[str, float, float], ...] | None = None  # (FieldParams name, lo, hi)
    # uniform draws; () for the run's fixed field
    conditions: tuple[str, ...] = shade.CONDITIONS  # sky / lighting conditions drawn from
    condition_jitter: bool = True  # sun, colours, haze and exposure jittered around each
    sensor_noise: bool = True  # sensor noise and exposure jitter on every frame
    cam_height: float = 0.03  # m, half range of the camera height jitter (uniform)
    cam_pitch_deg: float = 3.0  # degrees, half range of the camera pitch jitter
    cam_roll_deg: float = 1.5  # degrees, half range of the camera roll jitter
    start_offset_std: float = 0.10  # m, std of the start's lateral offset from the lane centre
    start_yaw_std_deg: float = 6.0  # degrees, std of the start heading
    start_progress: float = 0.6  # the start is drawn in [0, start_progress] · path_length
    # ahead of the sweep's start (so the row's end is seen often)
    shadow_strength: tuple[float, float] = (1.0, 1.0)  # strength of the cast shadows, uniform
    # in (lo, hi) (1: full, 0: none; e.g. (0, 1) so that a policy cannot steer by them)

    CHOICES: ClassVar[dict[str, tuple[str, ...]]] = {"conditions": shade.CONDITIONS}

    def __post_init__(self):
        for c in self.conditions:
            if c not in shade.CONDITIONS:
                raise ValueError(f"env.randomize.conditions: {c!r} is not one of "
                                 f"{', '.join(shade.CONDITIONS)}")
        if not self.conditions:
            raise ValueError("env.randomize.conditions: at least one condition")
        for name, lo, hi in self.ranges or ():
            if name not in field.PARAM_NAMES:
                raise ValueError(f"env.randomize.ranges: {name!r} is not a field parameter")
            if not (math.isfinite(lo) and math.isfinite(hi) and lo <= hi):
                raise ValueError(f"env.randomize.ranges.{name}: need lo <= hi, got "
                                 f"({lo}, {hi})")
        for name in ("cam_height", "cam_pitch_deg", "cam_roll_deg", "start_offset_std",
                     "start_yaw_std_deg"):
            if not getattr(self, name) >= 0:
                raise ValueError(f"env.randomize.{name}: must be non-negative, got "
                                 f"{getattr(self, name)}")
        s = tuple(self.shadow_strength)
        if len(s) != 2 or not 0.0 <= s[0] <= s[1] <= 1.0:
            raise ValueError(f"env.randomize.shadow_strength: need [lo, hi] with 0 <= lo <= hi "
                             f"<= 1, got {list(self.shadow_strength)}")
        if not 0.0 <= self.start_progress < 1.0:
            raise ValueError(f"env.randomize.start_progress: must lie in [0, 1), got "
                             f"{self.start_progress}")

    def resolved(self, preset: str) -> tuple[tuple[str, float, float], ...]:
        return default_ranges(preset) if self.ranges is None else self.ranges

    @classmethod
    def off(cls) -> Randomize:
        """No randomisation: the run's field, its perception condition, no jitter or noise."""
        return cls(ranges=(), conditions=("sunny",), condition_jitter=False,
                   sensor_noise=False, cam_height=0.0, cam_pitch_deg=0.0, cam_roll_deg=0.0,
                   start_offset_std=0.0, start_yaw_std_deg=0.0, start_progress=0.0)


def corner_params(base: field.FieldParams, ranges) -> field.FieldParams:
    """FieldParams [2^k] at every corner of the k ranges (host), other values from `base`."""
    if not ranges:
        return jax.tree.map(lambda x: jnp.asarray(x)[None], base)
    corners = list(itertools.product(*[(lo, hi) for _, lo, hi in ranges]))
    values = np.asarray(corners, np.float32)
    out = jax.tree.map(lambda x: jnp.broadcast_to(jnp.asarray(x), (len(corners),)), base)
    return out.replace(**{name: jnp.asarray(values[:, i]) for i, (name, _, _) in
                          enumerate(ranges)})


def check_ranges(base: field.FieldParams, ranges, shape: field.FieldShape) -> None:
    """ValueError naming the parameter and the corner of the ranges that gives an impossible
    field (or one larger than `shape`)."""
    corners = corner_params(base, ranges)
    for name, (ok, reason) in field.checks(corners, shape).items():
        ok = np.asarray(ok).reshape(-1)
        if not ok.all():
            i = int(np.argmin(ok))
            at = ", ".join(f"{n}={float(getattr(corners, n)[i]):g}" for n, _, _ in ranges)
            raise ValueError(f"env.randomize.ranges: {name}: {reason} (at {at})")


def sample_params(base: field.FieldParams, ranges, key: jax.Array,
                  given: jax.Array | None = None) -> field.FieldParams:
    """FieldParams of one world: each ranged parameter uniform in (lo, hi), the rest `base`.
    `given` float32 [len(ranges)]: values to take instead of the draw where they are not NaN
    (a searched field of the adversarial curriculum), clipped to the ranges so that the field
    fits the compiled shape."""
    if not ranges:
        return base
    u = jax.random.uniform(key, (len(ranges),))
    lo = jnp.asarray([r[1] for r in ranges], jnp.float32)
    hi = jnp.asarray([r[2] for r in ranges], jnp.float32)
    x = lo + u * (hi - lo)
    if given is not None:
        x = jnp.where(jnp.isnan(given), x, jnp.clip(given, lo, hi))
    return base.replace(**{name: x[i] for i, (name, _, _) in enumerate(ranges)})


def sample_condition(rz: Randomize, key: jax.Array,
                     azimuth: jax.Array | None = None) -> shade.Conditions:
    """Sky / lighting of one episode: one of `rz.conditions`, jittered with
    `rz.condition_jitter`, its cast shadows' strength drawn in `rz.shadow_strength`; `azimuth`
    float32 [] (degrees; NaN: as drawn): the sun turned there (a searched sun of the
    adversarial curriculum)."""
    ki, kj = jax.random.split(key)
    jk = kj if rz.condition_jitter else None
    if len(rz.conditions) == 1:
        c = shade.conditions(rz.conditions[0], jk)
    else:
        all_c = [shade.conditions(n, jk) for n in rz.conditions]
        i = jax.random.randint(ki, (), 0, len(rz.conditions))
        c = jax.tree.map(lambda *xs: jnp.stack(xs)[i], *all_c)
    lo, hi = rz.shadow_strength  # a key of its own: the other draws stay as they were
    u = jax.random.uniform(jax.random.fold_in(key, 0x5AD0))
    c = c.replace(shadow=jnp.float32(lo) + (hi - lo) * u)  # (1, 1): exactly 1, full shadows
    return c if azimuth is None else shade.turn_sun(c, azimuth)


# a pool's columns after the ranged field values: run keys that a searched failure may set for
# a reset besides its field (the sun's azimuth in degrees: where the learned policies break on
# pear, docs/training.md)
POOL_EXTRA = ("perception.sun_azimuth",)


def pool_keys(ranges) -> tuple[str, ...]:
    """The dotted run keys of the columns of a pool (and of a reset's `given` values) for an
    environment of `ranges`: its ranged field values in order, then POOL_EXTRA."""
    return tuple(f"field.{n}" for n, _, _ in ranges) + POOL_EXTRA


def sample_jitter(rz: Randomize, key: jax.Array) -> jax.Array:
    """Camera jitter [3] (height [m], pitch [rad], roll [rad]), uniform in ± the half ranges."""
    half = jnp.asarray([rz.cam_height, math.radians(rz.cam_pitch_deg),
                        math.radians(rz.cam_roll_deg)], jnp.float32)
    return half * jax.random.uniform(key, (3,), minval=-1.0, maxval=1.0)


@struct.dataclass
class Pool:
    """Fields that resets take besides the uniform draws (the adversarial curriculum's
    searched failures): `values` float32 [P, k] in the order of `pool_keys` (NaN: that value
    is drawn), its first `count` rows valid; a `share` of every batch of resets
    takes a random valid row. Traced: a new pool runs in the same compiled program."""

    values: jax.Array  # float32 [P, k]
    count: jax.Array  # int32 []
    share: jax.Array  # float32 [], in [0, 1]


def make_pool(rows: np.ndarray, size: int, share: float) -> Pool:
    """A pool of `size` rows holding `rows` [n, k] (the first `size` of them; NaN: drawn);
    no rows: an empty pool (every reset draws)."""
    rows = np.asarray(rows, np.float32)[:size]  # [n, k]
    if not 0.0 <= share <= 1.0:
        raise ValueError(f"share: must lie in [0, 1], got {share}")
    values = np.full((size, rows.shape[1]), np.nan, np.float32)
    values[:len(rows)] = rows
    return Pool(values=jnp.asarray(values), count=jnp.int32(len(rows)),
                share=jnp.float32(share if len(rows) else 0.0))


def pool_draws(pool: Pool, keys: jax.Array, real: jax.Array) -> jax.Array:
    """The `given` rows (float32 [K, k]; NaN: drawn) of a batch of K reset slots, of which
    `real` (bool [K]) are resets that happen: the first m real ones take a random valid pool
    row, m = ⌊share · n + u⌋ for n real slots and u uniform (so m is share · n rounded, exactly
    so in expectation)."""
    real = jnp.asarray(real, bool)
    n = jnp.sum(real)
    u = jax.random.uniform(jax.random.fold_in(keys[0], 0x5EED))
    m = jnp.floor(pool.share * n + u).astype(jnp.int32)
    pos = jnp.cumsum(real) - 1
    take = real & (pos < m) & (pool.count > 0)
    rows = jax.vmap(lambda k: jax.random.randint(jax.random.fold_in(k, 0x9001), (), 0,
                                                 jnp.maximum(pool.count, 1)))(keys)
    return jnp.where(take[:, None], pool.values[rows], jnp.nan)
