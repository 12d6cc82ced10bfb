"""The searched box: traced keys with their bounds, the normalised coordinates u ∈ [0, 1]^d in
which every method searches, the candidates' run configs, which candidates give valid fields,
and the one static field shape that holds every field of the box.

A numeric key maps u linearly onto [low, high] (an integer key, `field.rows_per_group`, is
rounded); a key of named values (`perception.condition`) splits [0, 1] into equal parts, one per
listed name. A candidate is the scenario's values with the box's keys set to the candidate's
values: `rollout.config.build_run` makes its RunConfig, as `sweep.grid` does for a cell.

Validity: each bound was checked alone at load time (`search.config`); a combination of bounds
may still describe an impossible field (rows that cross, a lane too narrow for the robot,
weeds wider than the lane, ...). Such a candidate is **scored as invalid**: it is listed in
candidates.csv with its reason, runs no episode, costs nothing of the budget, and CMA-ES ranks
it below every valid candidate. Candidates are never clipped to validity.
"""

from __future__ import annotations

import dataclasses
import itertools
import warnings
from collections.abc import Sequence
from typing import Any

import numpy as np
from scipy.stats import qmc

from mjxrow import field as mjxrow_field
from mjxrow import limits
from mjxrow.physics import sim
from mjxrow.rollout.config import ConfigError, RunConfig, build_run
from mjxrow.sweep import config as sweep_config

MAX_CORNERS = 2**14  # corners of the field keys over which the shape is fitted (beyond: sampled)


@dataclasses.dataclass(frozen=True)
class Dim:
    """One searched key: a numeric range [low, high] (`integer`: rounded), or named `choices`."""

    key: str  # dotted key, e.g. field.row_curvature
    low: float = 0.0
    high: float = 1.0
    choices: tuple[str, ...] = ()
    integer: bool = False

    def value(self, u: float) -> Any:
        """The key's value at the normalised coordinate u ∈ [0, 1]."""
        if self.choices:
            return self.choices[min(int(u * len(self.choices)), len(self.choices) - 1)]
        v = self.low + float(u) * (self.high - self.low)
        return int(round(v)) if self.integer else float(v)

    def bounds(self) -> list:
        """As the YAML gives it: [low, high], or the list of names."""
        if self.choices:
            return list(self.choices)
        return [int(self.low), int(self.high)] if self.integer else [self.low, self.high]

    @property
    def is_field(self) -> bool:
        return self.key.startswith("field.")


Box = tuple[Dim, ...]


def values(box: Box, u: Sequence[float]) -> dict[str, Any]:
    """Dotted key → value of the candidate at u [d]."""
    return {d.key: d.value(x) for d, x in zip(box, u, strict=True)}


def normalise(box: Box, vals: dict[str, Any]) -> np.ndarray:
    """u [d] of the given values (a name: the centre of its part of [0, 1])."""
    out = []
    for d in box:
        v = vals[d.key]
        if d.choices:
            out.append((d.choices.index(v) + 0.5) / len(d.choices))
        else:
            out.append((float(v) - d.low) / (d.high - d.low))
    return np.asarray(out, np.float64)


# ---------------------------------------------------------------------------------------------
# Candidates


def run_of(scenario: sweep_config.SweepConfig, box: Box, u: Sequence[float]) -> RunConfig:
    """The RunConfig of the candidate at u: the scenario's values with the box's set.
    ConfigError (the domain classes' checks) when a value is impossible for its key."""
    vals = {**dict(scenario.values), **values(box, u)}
    return build_run(vals, scenario.seed, scenario.base_dir)


def candidates(scenario: sweep_config.SweepConfig, box: Box, U: np.ndarray,
               shape: mjxrow_field.FieldShape) -> list[tuple[RunConfig | None, str]]:
    """(run, '') of every valid candidate of U [N, d]; (None, reason) for an invalid one: a
    value its domain class refuses, an impossible field (`field.checks` against `shape`), a
    lane or terrain relief the physics cannot take (`physics.sim.check_params`), a path longer
    than the rows."""
    out: list[tuple[RunConfig | None, str]] = []
    for u in U:
        try:
            out.append((run_of(scenario, box, u), ""))
        except ConfigError as e:
            out.append((None, str(e)))
    ok = [i for i, (r, _) in enumerate(out) if r is not None]
    if not ok:
        return out
    params = mjxrow_field.stack_params([out[i][0].field_params(host=True) for i in ok])
    bad = field_problems(params, shape)
    for j, i in enumerate(ok):
        run = out[i][0]
        reason = bad[j]
        if not reason:
            try:
                sim.check_params(run.field_params(host=True), run.sim)
            except ValueError as e:
                reason = str(e)
        if not reason:
            fv = run.field_values()
            if fv["row_length"] * fv["scale"] < run.sim.path_length:
                reason = (f"sim.path_length: {run.sim.path_length} m is longer than the rows "
                          f"({fv['row_length'] * fv['scale']:.3g} m)")
        if reason:
            out[i] = (None, reason)
    return out


def field_problems(params: mjxrow_field.FieldParams, shape: mjxrow_field.FieldShape
                   ) -> list[str]:
    """Per field of a batch of params [N] (host): '' when valid, else the first failed
    check as `field.NAME: reason`."""
    n = int(np.asarray(params.d_rr).reshape(-1).shape[0])
    out = [""] * n
    for name, (ok, reason) in mjxrow_field.checks(params, shape).items():
        ok = np.broadcast_to(np.asarray(ok).reshape(-1), (n,))
        key = f"field.{name}" if name in mjxrow_field.PARAM_NAMES else name
        for i in np.flatnonzero(~ok):
            out[i] = out[i] or f"{key}: {reason}"
    return out


def spread(d: int, n: int, seed: int = 0) -> np.ndarray:
    """n points spread over [0, 1]^d (scrambled Sobol, seeded): the load-time look at which
    share of the box gives valid fields."""
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", UserWarning)  # n need not be a power of two
        return qmc.Sobol(d, scramble=True, seed=np.random.default_rng(seed)).random(n)


# ---------------------------------------------------------------------------------------------
# The static shape


def _field_grid(scenario: sweep_config.SweepConfig, box: Box, points: np.ndarray
                ) -> mjxrow_field.FieldParams:
    """FieldParams [N] (host) of the scenario's field with the box's field keys at `points`
    ([N, d] values, not normalised, in the order of the box's dims)."""
    base = sweep_config.field_values(scenario)
    over = {k: np.full(len(points), float(v), np.float32) for k, v in base.items()}
    for j, d in enumerate(box):
        if d.is_field:
            over[d.key.split(".", 1)[1]] = points[:, j].astype(np.float32)
    return mjxrow_field.make_params(scenario.preset, host=True, **over)


def corner_points(box: Box, seed: int = 0) -> np.ndarray:
    """Values [N, d] at the corners of the box's field keys (other keys at their low bound):
    all of them up to MAX_CORNERS, else that many drawn at random (seeded)."""
    lows = np.asarray([d.low if not d.choices else 0.0 for d in box], np.float64)
    highs = np.asarray([d.high if not d.choices else 0.0 for d in box], np.float64)
    fields = [j for j, d in enumerate(box) if d.is_field]
    if 2 ** len(fields) <= MAX_CORNERS:
        picks = np.asarray(list(itertools.product((0, 1), repeat=len(fields))), bool)
    else:
        picks = np.random.default_rng(seed).random((MAX_CORNERS, len(fields))) < 0.5
    pts = np.tile(lows, (len(picks), 1))
    for c, j in enumerate(fields):
        pts[:, j] = np.where(picks[:, c], highs[j], lows[j])
    return pts


def fit_shape(scenario: sweep_config.SweepConfig, box: Box) -> mjxrow_field.FieldShape:
    """The static FieldShape that holds every field of the box: `field.fit_shape` over the
    corners of its field keys (every count of the layout grows or shrinks monotonically with
    each field key, so its extremes lie at corners). ConfigError naming the box key when the
    shape exceeds the bounds of mjxrow.limits."""
    params = _field_grid(scenario, box, corner_points(box))
    shape = mjxrow_field.fit_shape(params, scenario.preset)
    keys = {d.key for d in box}
    for size, bound, what, names in (
            (shape.max_rows, limits.ROWS, "rows", ("d_rr", "d_RR", "terrain_width")),
            (shape.max_plants_per_row, limits.PLANTS_PER_ROW, "plants per row",
             ("d_pp", "row_length")),
            (shape.obstacle_slots, limits.OBSTACLES, "obstacles",
             ("stone_density", "branch_density", "row_length"))):
        if size > bound:
            key = next((f"field.{k}" for k in names if f"field.{k}" in keys), f"field.{names[0]}")
            raise ConfigError(f"box.{key}: the box gives {size:,} {what} in a field, beyond the "
                              f"bound of {bound:,} (mjxrow/limits.py)")
    return shape


def valid_share(scenario: sweep_config.SweepConfig, box: Box, shape: mjxrow_field.FieldShape,
                n: int = 1024) -> tuple[float, str]:
    """(share of `n` points spread over the box whose fields pass `field.checks`, the first
    reason of an invalid one or '')."""
    U = spread(len(box), n)
    pts = np.stack([[d.value(x) if not d.choices else 0.0 for d, x in zip(box, u, strict=True)]
                    for u in U])
    problems = field_problems(_field_grid(scenario, box, pts), shape)
    bad = [p for p in problems if p]
    return 1.0 - len(bad) / n, (bad[0] if bad else "")
