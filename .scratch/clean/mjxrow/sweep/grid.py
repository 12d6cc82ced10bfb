"""A sweep's grid → its cells: the cartesian product of the axes (`expand`), each cell's
`RunConfig` built from the given keys, the identity of a cell's results (`resolved`,
`cell_hash`, `static_key`), and the checks across keys and on every cell (`check_grid`, `check`)
that `config.from_dict` runs before it returns a SweepConfig.

The grid is read through `Grid`, the part of a sweep config this stage uses (config.SweepConfig
is one), so that the config module can run these checks while it validates.
"""

from __future__ import annotations

import dataclasses
import functools
import hashlib
import itertools
import json
import math
from pathlib import Path
from typing import Any, Protocol

import numpy as np

from mjxrow import control, crops, limits
from mjxrow import field as mjxrow_field
from mjxrow.physics import sim
from mjxrow.rollout.config import ConfigError, RunConfig, build_run
from mjxrow.seg import checkpoint as seg_checkpoint


class Grid(Protocol):
    """What the grid stage reads of a sweep config: the given keys (`values`: dotted key →
    scalar, or a tuple of values for an axis), the axes in YAML order, the base seed, the
    episodes per cell, the YAML's folder and whether controllers share a program."""

    values: tuple[tuple[str, Any], ...]
    axis_order: tuple[str, ...]
    seed: int
    seeds: int
    base_dir: str
    mix_controllers: bool


# ---------------------------------------------------------------------------------------------
# Cells


@dataclasses.dataclass(frozen=True)
class Cell:
    """One grid point: `point` holds the axis values, `cfg` the cell's RunConfig (every
    section a validated domain config)."""

    index: int
    point: tuple[tuple[str, Any], ...]
    cfg: RunConfig


def _where(point) -> str:
    return "" if not point else " (cell " + ", ".join(f"{k}={v}" for k, v in point) + ")"


def cell_values(cfg: Grid, point) -> dict[str, Any]:
    vals = dict(cfg.values)
    vals.update(dict(point))
    return vals


@functools.lru_cache(maxsize=8)
def _expand(cfg: Grid) -> tuple[Cell, ...]:
    axes = [dict(cfg.values)[k] for k in cfg.axis_order]
    cells = []
    for i, combo in enumerate(itertools.product(*axes)):
        point = tuple(zip(cfg.axis_order, combo, strict=True))
        try:
            run = build_run(cell_values(cfg, point), cfg.seed, cfg.base_dir)
        except ValueError as e:
            raise ConfigError(f"{e}{_where(point)}") from None
        cells.append(Cell(i, point, run))
    return tuple(cells)


def expand(cfg: Grid) -> list[Cell]:
    """Cartesian product of the axes (first axis slowest) → cells."""
    return list(_expand(cfg))


def resolved(cfg: RunConfig) -> dict[str, Any]:
    """Flat dotted dict of every key of a cell config (field keys resolved from the preset),
    plus the checkpoint's path and content id."""
    out = cfg.flat()
    out["perception.checkpoint"] = checkpoint_path(cfg)
    out["perception.checkpoint_id"] = checkpoint_id(out["perception.checkpoint"])
    return out


def cell_hash(cell: Cell, extra: Any = None) -> str:
    """Identity of a cell's results: its resolved parameters (the checkpoint by its content,
    not its path) and `extra` (e.g. the static field shape of its group). 16 hex digits."""
    r = {k: v for k, v in resolved(cell.cfg).items() if k != "perception.checkpoint"}
    text = json.dumps([r, repr(extra)], sort_keys=True, default=str)
    return hashlib.sha256(text.encode()).hexdigest()[:16]


def static_key(cfg: RunConfig) -> tuple:
    """The static (compile-relevant) values of a cell config, except the field shape."""
    return cfg.static_key()


# ---------------------------------------------------------------------------------------------
# Checks


def check_grid(cfg: Grid) -> None:
    """ConfigError when the grid has more cells, or the sweep more episodes, than the bounds of
    mjxrow.limits; the message names the longest axis (or `seeds`). Runs before any cell is
    built."""
    vals = dict(cfg.values)
    sizes = {k: len(vals[k]) for k in cfg.axis_order}
    cells = math.prod(sizes.values())
    longest = max(sizes, key=sizes.get) if sizes else "seeds"
    if cells > limits.CELLS:
        raise ConfigError(f"{longest}: the grid has {cells:,} cells ("
                          + " × ".join(f"{n} {k}" for k, n in sizes.items())
                          + f"), beyond the bound of {limits.CELLS:,} (mjxrow/limits.py)")
    if cells * cfg.seeds > limits.EPISODES:
        raise ConfigError(f"seeds: {cells:,} cells × {cfg.seeds:,} seeds = "
                          f"{cells * cfg.seeds:,} episodes, beyond the bound of "
                          f"{limits.EPISODES:,} (mjxrow/limits.py)")


def checkpoint_path(cfg: RunConfig) -> str:
    """Checkpoint folder of a cell config ('' when no segmenter is used): the crop's shipped
    one (seg.checkpoint.resolve, which falls back to the all-crop model), or the given path
    (relative to the working directory, else to the YAML's folder). ConfigError if missing."""
    try:
        return cfg.checkpoint_path()
    except ValueError as e:
        raise ConfigError(f"perception.checkpoint: {e}") from None


@functools.lru_cache(maxsize=32)
def checkpoint_id(path: str) -> str:
    """sha256 (16 hex digits) of every file of a checkpoint folder: a retrained checkpoint in
    the same folder makes new cell hashes. '' for no checkpoint."""
    if not path:
        return ""
    h = hashlib.sha256()
    for f in sorted(Path(path).rglob("*")):
        if f.is_file():
            h.update(str(f.relative_to(path)).encode())
            h.update(f.read_bytes())
    return h.hexdigest()[:16]


def _blame(cfg: RunConfig, name: str, shape: mjxrow_field.FieldShape) -> str:
    """The dotted key to name for a failed field check `name`: the key itself when it was given
    (or is not a field key); else the given field key whose preset value makes the check pass
    (`d_rr: 1e9` fails the terrain_width check: the key to name is field.d_rr)."""
    key = f"field.{name}" if name in mjxrow_field.PARAM_NAMES else name
    given = [k for k, v in cfg.field.items() if v is not None]
    if name in given or not given:
        return key
    preset = crops.get(cfg.preset).preset
    for k in given:
        values = {**cfg.field_values(), k: preset[k]}
        ok, _ = mjxrow_field.checks(
            mjxrow_field.make_params(cfg.preset, host=True, **values), shape
        )[name]
        if bool(np.all(np.asarray(ok))):
            return f"field.{k}"
    return key


@functools.lru_cache(maxsize=32)
def _verified(path: str) -> str:
    """`path` once its weights restore (seg.checkpoint.load: config readable, weights present
    and whole; no program is compiled), so that damaged weights fail before any output folder."""
    if path:
        try:
            seg_checkpoint.load(path)
        except ValueError as e:
            raise ConfigError(f"perception.checkpoint: {e}") from None
    return path


def check(cfg: Grid) -> None:
    """Checks across keys and on every cell: each section's own checks (building the cell's
    domain configs), impossible fields (field.checks), missing checkpoints, the controller's
    params, the lane kind (`sim.lane`) and the physics patch's height range (`sim.patch_z`)
    against each cell's field (physics.sim.check_params). Raises ConfigError naming the dotted
    key and the cell."""
    cells = expand(cfg)
    params = mjxrow_field.stack_params(
        [mjxrow_field.make_params(c.cfg.preset, host=True, **c.cfg.field_values()) for c in cells]
    )
    roomy = mjxrow_field.FieldShape(crop="zucchini", max_rows=10**9, max_plants_per_row=10**9,
                                    obstacle_slots=10**9, weed_slots=10**9)
    for name, (ok, reason) in mjxrow_field.checks(params, roomy).items():
        if name in ("max_rows", "max_plants_per_row", "obstacle_slots", "weed_slots"):
            continue
        ok = np.asarray(ok).reshape(-1)
        if not ok.all():
            cell = cells[int(np.argmin(ok))]
            key = _blame(cell.cfg, name, roomy)
            raise ConfigError(f"{key}: {reason}{_where(cell.point)}")
    kinds: dict[str, tuple[str, Any]] = {}  # preset → (lane kind "auto" gives, first cell)
    for cell, kind in zip(cells, sim.auto_lane_kind(params), strict=True):
        if cell.cfg.sim.lane != "auto":
            continue
        first = kinds.setdefault(cell.cfg.preset, (str(kind), cell))
        if first[0] != kind:
            raise ConfigError(
                f"sim.lane: 'auto' drives the {first[0]} lane{_where(first[1].point)} but the "
                f"{kind} lane{_where(cell.point)}; set sim.lane to in_group or between_groups "
                "so that every cell drives the same kind of lane")
    shape = mjxrow_field.fit_shape(params, cells[0].cfg.preset)
    for size, bound, what, keys in (
            (shape.max_rows, limits.ROWS, "rows", ("d_rr", "d_RR", "terrain_width")),
            (shape.max_plants_per_row, limits.PLANTS_PER_ROW, "plants per row",
             ("d_pp", "row_length")),
            (shape.obstacle_slots, limits.OBSTACLES, "obstacles",
             ("stone_density", "branch_density", "row_length"))):
        if size > bound:
            given = {k for c in cells for k, v in c.cfg.field.items() if v is not None}
            key = next((k for k in keys if k in given), keys[0])
            raise ConfigError(f"field.{key}: gives {size:,} {what} in a field, beyond the "
                              f"bound of {bound:,} (mjxrow/limits.py)")
    if cfg.mix_controllers:
        variants: dict[tuple, set] = {}
        for cell in cells:
            variants.setdefault(cell.cfg.share_key(), set()).add(cell.cfg.variant_key())
        for cell in cells:
            c = control.get(cell.cfg.controller.name)
            if getattr(c, "make_policy", None) is not None and \
                    len(variants[cell.cfg.share_key()]) > 1:
                raise ConfigError(f"mix_controllers: controller {c.name!r} renders its own "
                                  "images and cannot share a program with other controllers; "
                                  f"set mix_controllers: false{_where(cell.point)}")
    for cell in cells:
        c = cell.cfg
        where = _where(cell.point)
        try:
            _verified(checkpoint_path(c))
            c.controller_params()
        except ConfigError as e:
            raise ConfigError(f"{e}{where}") from None
        except ValueError as e:
            raise ConfigError(f"{e}{where}") from None
        if c.controller.name == "segmin" and c.camera.width < c.controller.smooth + 4:
            raise ConfigError(f"camera.width: segmin needs at least controller.smooth + 4 = "
                              f"{c.controller.smooth + 4} columns, got {c.camera.width}{where}")
        try:  # the lane kind and the physics patch's height range (sim.check_params)
            sim.check_params(c.field_params(host=True), c.sim)
        except ValueError as e:
            raise ConfigError(f"{e}{where}") from None
        fv = c.field_values()
        if fv["row_length"] * fv["scale"] < c.sim.path_length:
            raise ConfigError(f"sim.path_length: {c.sim.path_length} m is longer than "
                              f"the rows ({fv['row_length'] * fv['scale']:.3g} m){where}")
