"""Sweep configuration: YAML → a validated `SweepConfig`, whose grid `grid.expand` turns into
cells, each cell a `RunConfig` of domain configs (`from_dict` runs `grid`'s checks on them).

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
import math
from pathlib import Path
from typing import Any

import numpy as np

from mjxrow import control, crops, limits
from mjxrow.rollout import keys as rollout_keys
from mjxrow.rollout.config import (
    ConfigError,
    ControllerChoice,
    RunConfig,
    Section,
    apply_sets,
)
from mjxrow.sweep import grid
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
    batch_size: int | str = _k("auto", "episodes per jitted call (padded to a multiple of the "
                               "device count), or `auto`: by device (groups.batch_size)",
                               "count", "positive", kind="batch")
    out: str = _k("runs/sweep", "output directory, relative to the working directory (no '..') "
                  "or absolute; the CLI's --out wins", kind=str)
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
        if section in rollout_keys.ORDER:
            vals = dict(self.values)
            keys = rollout_keys.section_keys(section)
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
    others = {k.split(".", 1)[1]: k for k in rollout_keys.all_keys()}
    near = difflib.get_close_matches(str(key), list(others), n=1, cutoff=0.8)
    if near:
        return ConfigError(f"{path}: unknown key; did you mean {others[near[0]]}?")
    return _unknown(path, key, known)


_NEED = {"positive": "> 0", "nonneg": ">= 0"}
AUTO = "auto"  # batch_size: sized by the device (groups.batch_size)


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


# The checked scalar and the unknown-key message, for the configs that share this vocabulary
# (mjxrow.search.config).
scalar = _scalar
unknown_key = _unknown


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
        if key in rollout_keys.ORDER:
            if not isinstance(v, dict):
                raise ConfigError(f"{key}: expected a mapping of keys, got {type(v).__name__}")
            known = rollout_keys.section_keys(key, _controllers_named(raw) if key == "controller"
                                                else None)
            everything = rollout_keys.section_keys(key) if key == "controller" else known
            for k2, v2 in v.items():
                path = f"{key}.{k2}"
                if path in rollout_keys.REJECTED:
                    raise ConfigError(
                        f"{path}: cannot be set here: {rollout_keys.REJECTED[path]}"
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
        elif key == "batch_size" and v == AUTO:
            top[key] = AUTO
        elif key == "out" and isinstance(v, str) and not v.strip():
            raise ConfigError("out: must not be empty (the folder the sweep writes, relative to "
                              "the working directory; the CLI's --out wins)")
        elif key == "out" and isinstance(v, str) and not Path(v).expanduser().is_absolute() \
                and ".." in Path(v).parts:
            raise ConfigError(f"out: {v!r} climbs out of the working directory ('..'); a YAML's "
                              "out is a folder under the working directory (or an absolute path; "
                              "the CLI's --out wins)")
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
            raise _unknown(key, key, TOP_KEYS + rollout_keys.ORDER)
        for k, val in list(values.items()):
            if isinstance(val, tuple) and k not in axes:
                axes.append(k)
    cfg = SweepConfig(**top, values=tuple(values.items()), axis_order=tuple(axes),
                      base_dir=str(base_dir))
    if smoke:
        cfg = shrink(cfg)
    grid.check_grid(cfg)
    grid.check(cfg)
    return cfg


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


def leaf_keys() -> list[tuple[str, rollout_keys.Key | dict]]:
    """Every dotted key with its spec, top-level keys first."""
    out: list[tuple[str, Any]] = [(k, {}) for k in TOP_KEYS]
    return out + list(rollout_keys.all_keys().items())


def is_static(dotted: str) -> bool:
    return rollout_keys.is_static(dotted)


def shrink(cfg: SweepConfig) -> SweepConfig:
    """--smoke: the first and last value of the first two axes, the first of any other axis,
    and the SMOKE settings for every key that is not an axis (the camera's size stays where a
    cell runs a learned policy: its network takes the images it was trained on)."""
    vals = dict(cfg.values)
    names = cfg.controller.name  # a name, or a tuple of them on an axis
    policy = "policy" in (names if isinstance(names, tuple) else (names,))
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
        elif policy and key.startswith("camera."):
            continue
        elif key not in cfg.axis_order and (free_x or not key.startswith("field.")):
            cur = vals.get(key)
            vals[key] = v if cur is None or not key.startswith("field.") else min(cur, v)
    return dataclasses.replace(cfg, **top, values=tuple(vals.items()), axis_order=tuple(axes))


def field_values(cfg: SweepConfig | RunConfig) -> dict[str, float]:
    """Resolved FieldParams of a cell config: the preset's values with the overrides."""
    if isinstance(cfg, SweepConfig):
        cfg = grid.expand(cfg)[0].cfg
    return cfg.field_values()


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


__all__ = ["ConfigError", "ControllerChoice", "RunConfig", "Section", "SweepConfig", "apply_sets",
           "field_values", "from_dict", "get", "is_static", "leaf_keys", "load", "scalar",
           "shrink", "to_dict", "unknown_key", "with_values"]
