"""Sweep configuration: YAML → validated grid of cells, each cell a `RunConfig` of domain configs.

The sections are the domain configs themselves under their own field names (`schema`): `field`
(FieldParams overrides), `sim`, `robot`, `camera` (Intrinsics), `render`, `episode`, `controller`
(`name` + the registered controller's config), `perception`. Top-level keys: `name`, `preset`,
`seeds`, `seed`, `batch_size`, `out`.

A value is a scalar, a list of scalars, or a range `{start, stop, num}` (inclusive, evenly
spaced). A list or a range is a grid axis; the grid is the cartesian product of all axes, in the
order the axes appear in the YAML (command-line `--set` axes come last). Every cell runs `seeds`
episodes; episode `i` of every cell uses the key `fold_in(key(seed), i)` (common random numbers
across cells, so surfaces compare cells on the same random draws; `rollout.build.episode_keys`).

The same grammar serves every command: `--set KEY=VALUE` with a dotted key and a YAML value
(`apply_sets`).
"""

from __future__ import annotations

import dataclasses
import difflib
import functools
import hashlib
import itertools
import json
import math
from pathlib import Path
from typing import Any

import numpy as np

from mjxrow import control, crops, limits
from mjxrow import field as mjxrow_field
from mjxrow.physics import sim
from mjxrow.rollout import config as rollout_config
from mjxrow.rollout.config import (
    ConfigError,
    ControllerChoice,
    RunConfig,
    Section,
    apply_sets,
    build_run,
)
from mjxrow.seg import checkpoint as seg_checkpoint
from mjxrow.sweep.yamlfile import read_yaml


def _k(default, doc, unit="", check=None, choices=None, kind=int):
    return dataclasses.field(default=default, metadata=dict(doc=doc, unit=unit, check=check,
                                                            choices=choices, kind=kind))


@dataclasses.dataclass(frozen=True)
class SweepConfig:
    """A validated sweep: the top-level keys, and `values`, the given section keys (dotted
    name → scalar, or tuple of values for a grid axis). Sections read as attributes with
    their defaults filled in: `cfg.field.d_rr`, `cfg.controller.name`, `cfg.sim.dt`."""

    name: str = _k("sweep", "sweep name, used in titles", kind=str)
    seeds: int = _k(8, "episodes per cell", "count", "positive")
    seed: int = _k(0, "base random seed", "", "nonneg")
    batch_size: int = _k(256, "episodes per jitted call (padded to a multiple of the device "
                         "count)", "count", "positive")
    out: str = _k("runs/sweep", "output directory (the CLI's --out wins)", kind=str)
    mix_controllers: bool = _k(False, "cells that differ only in `controller.*` and "
                               "`perception.source` run in one compiled program: one compile "
                               "instead of one per controller, but every episode pays for "
                               "every controller's stages (render, segmenter)", kind=bool)
    values: tuple[tuple[str, Any], ...] = ()
    axis_order: tuple[str, ...] = ()
    base_dir: str = "."

    @property
    def preset(self):
        return dict(self.values).get("preset", "zucchini")

    def __getattr__(self, section: str):
        if section in rollout_config.ORDER:
            vals = dict(self.values)
            keys = rollout_config.section_keys(section)
            return Section(section, {k.split(".", 1)[1]: vals.get(k, key.default)
                                     for k, key in keys.items()})
        raise AttributeError(section)


TOP_KEYS = ("name", "preset", "seeds", "seed", "batch_size", "out", "mix_controllers")
NOT_AXES = {"name", "seeds", "seed", "batch_size", "out", "mix_controllers"}
PRESET_DOC = "base crop preset (FieldParams defaults, plant model, shipped checkpoint)"

# --smoke: a quick check of the whole pipeline on tiny problems.
SMOKE: dict[str, Any] = {"seeds": 2, "batch_size": 8, "episode.max_time": 4.0,
                         "sim.path_length": 1.5, "camera.width": 16, "camera.height": 16,
                         "field.row_length": 6.0, "field.terrain_length": 10.0}


# ---------------------------------------------------------------------------------------------
# Parsing


def _unknown(path: str, key: str, known) -> ConfigError:
    near = difflib.get_close_matches(str(key), list(known), n=1)
    hint = f"; did you mean {near[0]}?" if near else f"; known: {', '.join(known)}"
    return ConfigError(f"{path}: unknown key{hint}")


def _unknown_key(path: str, key: str, known) -> ConfigError:
    """Unknown key in a section: the nearest key of the section, else the nearest key of
    another section (a key that moved: `episode.path_length` → `sim.path_length`)."""
    if difflib.get_close_matches(str(key), list(known), n=1):
        return _unknown(path, key, known)
    others = {k.split(".", 1)[1]: k for k in rollout_config.all_keys()}
    near = difflib.get_close_matches(str(key), list(others), n=1, cutoff=0.8)
    if near:
        return ConfigError(f"{path}: unknown key; did you mean {others[near[0]]}?")
    return _unknown(path, key, known)


_NEED = {"positive": "> 0", "nonneg": ">= 0"}


def _scalar(path: str, v: Any, kind: str, optional: bool = False, choices=None,
            check: str | None = None) -> Any:
    """One scalar of `kind` ('float', 'int', 'bool', 'str'), checked."""
    if v is None and optional:
        return None
    names = {"float": "a number", "int": "an integer", "bool": "true or false", "str": "a string"}
    if v is None or isinstance(v, (dict, list)) or (isinstance(v, bool) and kind != "bool"):
        raise ConfigError(f"{path}: expected {names[kind]}, got {type(v).__name__} {v!r}")
    if kind == "bool":
        if not isinstance(v, bool):
            raise ConfigError(f"{path}: expected true or false, got {type(v).__name__} {v!r}")
        return v
    if kind == "str":
        if not isinstance(v, str):
            raise ConfigError(f"{path}: expected a string, got {type(v).__name__} {v!r}")
        if choices and v not in choices:
            raise ConfigError(f"{path}: {v!r} is not one of {', '.join(choices)}")
        return v
    if kind == "int":
        if isinstance(v, float) and v.is_integer():
            v = int(v)
        if not isinstance(v, int):
            raise ConfigError(f"{path}: expected an integer, got {type(v).__name__} {v!r}")
    else:
        if not isinstance(v, (int, float)):
            raise ConfigError(f"{path}: expected a number, got {type(v).__name__} {v!r}")
        v = float(v)
        if not math.isfinite(v):
            raise ConfigError(f"{path}: must be finite, got {v}")
    if check and not {"positive": v > 0, "nonneg": v >= 0}[check]:
        raise ConfigError(f"{path}: must be {_NEED[check]}, got {v}")
    return v


def _value(path: str, v: Any, parse, axis_ok: bool) -> Any:
    """A scalar (parse(path, v)), or a tuple of scalars for a grid axis."""
    if isinstance(v, (list, dict)) and not axis_ok:
        raise ConfigError(f"{path}: cannot be a grid axis; give one value")
    if isinstance(v, list):
        if not v:
            raise ConfigError(f"{path}: an axis needs at least one value")
        vals = tuple(parse(f"{path}[{i}]", x) for i, x in enumerate(v))
        if len(set(vals)) != len(vals):
            raise ConfigError(f"{path}: repeated values in the axis {list(vals)}")
        return vals
    if isinstance(v, dict):
        extra = set(v) - {"start", "stop", "num"}
        if extra:
            raise _unknown(f"{path}.{sorted(extra)[0]}", sorted(extra)[0], ("start", "stop", "num"))
        if set(v) != {"start", "stop", "num"}:
            raise ConfigError(f"{path}: a range needs start, stop and num")
        num = _scalar(f"{path}.num", v["num"], "int", check="positive")
        if num > limits.AXIS_VALUES:
            raise ConfigError(f"{path}.num: {num:,} values, beyond the bound of "
                              f"{limits.AXIS_VALUES:,} values per axis (mjxrow/limits.py)")
        a = _scalar(f"{path}.start", v["start"], "float")
        b = _scalar(f"{path}.stop", v["stop"], "float")
        return _value(path, [round(float(x), 10) for x in np.linspace(a, b, num)], parse, True)
    return parse(path, v)


def _controllers_named(raw: dict) -> tuple[str, ...]:
    sec = raw.get("controller") or {}
    name = sec.get("name", "segzeros") if isinstance(sec, dict) else "segzeros"
    names = name if isinstance(name, list) else [name]
    return tuple(n for n in names if n in control.CONTROLLERS) or ("segzeros",)


def from_dict(raw: Any, base_dir: str | Path = ".", sets=(), smoke: bool = False) -> SweepConfig:
    """Validate a parsed YAML mapping (plus `--set` overrides) into a SweepConfig."""
    if raw is None:
        raw = {}
    if not isinstance(raw, dict):
        raise ConfigError(f"<top>: expected a mapping of keys, got {type(raw).__name__}")
    raw = apply_sets(raw, sets)
    top: dict[str, Any] = {}
    values: dict[str, Any] = {}
    axes: list[str] = []
    meta = {f.name: f.metadata for f in dataclasses.fields(SweepConfig) if f.metadata}
    for key, v in raw.items():
        if key in rollout_config.ORDER:
            if not isinstance(v, dict):
                raise ConfigError(f"{key}: expected a mapping of keys, got {type(v).__name__}")
            known = rollout_config.section_keys(key, _controllers_named(raw) if key == "controller"
                                                else None)
            everything = rollout_config.section_keys(key) if key == "controller" else known
            for k2, v2 in v.items():
                path = f"{key}.{k2}"
                if path in rollout_config.REJECTED:
                    raise ConfigError(
                        f"{path}: cannot be set here: {rollout_config.REJECTED[path]}"
                    )
                if path not in everything:
                    raise _unknown_key(path, k2, [k.split(".", 1)[1] for k in known])
                spec = everything[path]  # another controller's key: that controller's only

                def parse(p, x, spec=spec):
                    return _scalar(p, x, spec.kind, spec.optional, spec.choices)

                values[path] = _value(path, v2, parse, True)
        elif key == "preset":
            values["preset"] = _value(key, v, lambda p, x: _scalar(p, x, "str",
                                                                  choices=crops.names()), True)
        elif key in TOP_KEYS:
            m = meta[key]
            kind = {str: "str", bool: "bool"}.get(m["kind"], "int")
            top[key] = _value(key, v, lambda p, x, m=m, kind=kind: _scalar(
                p, x, kind, choices=m["choices"], check=m["check"]), False)
            try:
                limits.check_value(key, top[key])
            except limits.LimitError as e:
                raise ConfigError(str(e)) from None
        else:
            raise _unknown(key, key, TOP_KEYS + rollout_config.ORDER)
        for k, val in list(values.items()):
            if isinstance(val, tuple) and k not in axes:
                axes.append(k)
    cfg = SweepConfig(**top, values=tuple(values.items()), axis_order=tuple(axes),
                      base_dir=str(base_dir))
    if smoke:
        cfg = shrink(cfg)
    check_grid(cfg)
    check(cfg)
    return cfg


def check_grid(cfg: SweepConfig) -> None:
    """ConfigError when the grid has more cells, or the sweep more episodes, than the bounds of
    rollout.limits; the message names the longest axis (or `seeds`). Runs before any cell is
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


def load(path: str | Path, sets=(), smoke: bool = False) -> SweepConfig:
    """Read a sweep YAML (`read_yaml`: no duplicate keys, not empty), apply `--set` overrides,
    validate."""
    path = Path(path)
    return from_dict(read_yaml(path), path.parent, sets, smoke)


# ---------------------------------------------------------------------------------------------
# Access by dotted key


def get(cfg: SweepConfig | RunConfig, dotted: str) -> Any:
    """A key's value: `preset`, a top-level key, or `section.key`."""
    if isinstance(cfg, RunConfig):
        return cfg.get(dotted)
    if dotted in NOT_AXES:
        return getattr(cfg, dotted)
    if dotted == "preset":
        return cfg.preset
    section, _, key = dotted.partition(".")
    return getattr(getattr(cfg, section), key)


def with_values(cfg: SweepConfig, **updates: Any) -> SweepConfig:
    """`cfg` with dotted keys set (keyword names use '__' for '.')."""
    vals = dict(cfg.values)
    vals.update({k.replace("__", "."): v for k, v in updates.items()})
    return dataclasses.replace(cfg, values=tuple(vals.items()))


def leaf_keys() -> list[tuple[str, rollout_config.Key | dict]]:
    """Every dotted key with its spec, top-level keys first."""
    out: list[tuple[str, Any]] = [(k, {}) for k in TOP_KEYS]
    return out + list(rollout_config.all_keys().items())


def is_static(dotted: str) -> bool:
    return rollout_config.is_static(dotted)


def shrink(cfg: SweepConfig) -> SweepConfig:
    """--smoke: the first and last value of the first two axes, the first of any other axis,
    and the SMOKE settings for every key that is not an axis."""
    vals = dict(cfg.values)
    axes = []
    for i, key in enumerate(cfg.axis_order):
        v = vals[key]
        keep = (v[0], v[-1]) if i < 2 and len(v) > 1 else v[:1]
        vals[key] = keep if len(keep) > 1 else keep[0]
        if len(keep) > 1:
            axes.append(key)
    free_x = not {"field.row_length", "field.terrain_length"} & set(cfg.axis_order)
    top = {}
    for key, v in SMOKE.items():
        if key in ("seeds", "batch_size"):
            top[key] = v
        elif key not in cfg.axis_order and (free_x or not key.startswith("field.")):
            cur = vals.get(key)
            vals[key] = v if cur is None or not key.startswith("field.") else min(cur, v)
    return dataclasses.replace(cfg, **top, values=tuple(vals.items()), axis_order=tuple(axes))


# ---------------------------------------------------------------------------------------------
# Grid


@dataclasses.dataclass(frozen=True)
class Cell:
    """One grid point: `point` holds the axis values, `cfg` the cell's RunConfig (every
    section a validated domain config)."""

    index: int
    point: tuple[tuple[str, Any], ...]
    cfg: RunConfig


def _where(point) -> str:
    return "" if not point else " (cell " + ", ".join(f"{k}={v}" for k, v in point) + ")"


def cell_values(cfg: SweepConfig, point) -> dict[str, Any]:
    vals = dict(cfg.values)
    vals.update(dict(point))
    return vals


@functools.lru_cache(maxsize=8)
def _expand(cfg: SweepConfig) -> tuple[Cell, ...]:
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


def expand(cfg: SweepConfig) -> list[Cell]:
    """Cartesian product of the axes (first axis slowest) → cells."""
    return list(_expand(cfg))


def field_values(cfg: SweepConfig | RunConfig) -> dict[str, float]:
    """Resolved FieldParams of a cell config: the preset's values with the overrides."""
    if isinstance(cfg, SweepConfig):
        cfg = expand(cfg)[0].cfg
    return cfg.field_values()


def resolved(cfg: RunConfig) -> dict[str, Any]:
    """Flat dotted dict of every key of a cell config (field keys resolved from the preset),
    plus the checkpoint's path and content id."""
    out = cfg.flat()
    out["perception.checkpoint"] = checkpoint_path(cfg)
    out["perception.checkpoint_id"] = checkpoint_id(out["perception.checkpoint"])
    return out


def to_dict(cfg: SweepConfig) -> dict[str, Any]:
    """Nested plain dict (axes as lists) for YAML dumps: the keys given, no defaults."""
    out: dict[str, Any] = {k: getattr(cfg, k) for k in TOP_KEYS if k != "preset"}
    out["preset"] = cfg.preset if not isinstance(cfg.preset, tuple) else list(cfg.preset)
    for k, v in cfg.values:
        if k == "preset":
            continue
        sec, _, key = k.partition(".")
        out.setdefault(sec, {})[key] = list(v) if isinstance(v, tuple) else v
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
    """`path` once seg.checkpoint.verify passes (config readable, weights present)."""
    if path:

        try:
            seg_checkpoint.verify(path)
        except ValueError as e:
            raise ConfigError(f"perception.checkpoint: {e}") from None
    return path


def check(cfg: SweepConfig) -> None:
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
                                    obstacle_slots=10**9)
    for name, (ok, reason) in mjxrow_field.checks(params, roomy).items():
        if name in ("max_rows", "max_plants_per_row", "obstacle_slots"):
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


__all__ = ["Cell", "ConfigError", "ControllerChoice", "RunConfig", "Section", "SweepConfig",
           "apply_sets", "cell_hash", "check", "checkpoint_id", "checkpoint_path", "expand",
           "field_values", "from_dict", "get", "is_static", "leaf_keys", "load", "resolved",
           "shrink", "static_key", "to_dict", "with_values"]
