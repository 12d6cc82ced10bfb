"""Sweep configuration: YAML → validated frozen dataclasses → grid of cells.

One source of truth: every key, its type, default, unit, meaning and whether it is static (fixes
an array shape or a Python branch, so a different value compiles again) lives in the section
dataclasses below; the docs table (`reference_rows`) is generated from them.

A value is a scalar, a list of scalars, or a range `{start, stop, num}` (inclusive, evenly
spaced). A list or a range is a grid axis; the grid is the cartesian product of all axes, in the
order the axes appear in the YAML (command-line `--set` axes come last). Every cell runs `seeds`
episodes; episode `i` of every cell uses the key `fold_in(key(seed), i)` (common random numbers
across cells, so surfaces compare cells on the same random draws).
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
import yaml

from mjxrow import field as F

CONTROLLERS = ("segzeros", "segmin", "oracle")
VARIANTS = ("paper", "public")
ON_END = ("straight", "lane", "stop", "hold")
SOURCES = ("learned", "ground_truth")
CONDITIONS = ("sunny", "cloudy", "crepuscular", "long_shadows")


class ConfigError(ValueError):
    """A one-line configuration error naming the offending dotted key."""


def _k(default, doc, unit="", check=None, static=False, choices=None, kind=float):
    """Field spec: `check` is None, 'positive', 'nonneg', 'unit' ([0, 1]), 'prob' ([0, 1)),
    'pitch' ((-90, 90)) or 'fov' ((0, 180));
    `kind` the scalar type (float, int, str; None means 'float or null')."""
    meta = dict(doc=doc, unit=unit, check=check, static=static, choices=choices, kind=kind)
    return dataclasses.field(default=default, metadata=meta)


@dataclasses.dataclass(frozen=True)
class EpisodeSection:
    path_length: float = _k(20.0, "path driven inside the row; the goal is the row's end "
                            "point this far from the start", "m", "positive", static=True)
    max_time: float = _k(60.0, "timeout; the episode has ceil(max_time·control_hz) control "
                         "steps", "s", "positive", static=True)
    control_hz: float = _k(15.0, "control (and camera) rate", "Hz", "positive", static=True)
    v_max: float = _k(0.5, "clip on the forward speed command", "m/s", "positive",
                      static=True)
    omega_max: float = _k(1.0, "clip on the yaw-rate command", "rad/s", "positive",
                          static=True)
    goal_tolerance: float = _k(0.40, "goal reached within this distance", "m", "positive",
                               static=True)
    start_offset_std: float = _k(0.0, "std of the start's lateral offset from the lane "
                                 "centre", "m", "nonneg")
    start_yaw_std: float = _k(0.0, "std of the start heading about the row direction", "deg",
                              "nonneg")


@dataclasses.dataclass(frozen=True)
class ControllerSection:
    name: str = _k("segzeros", "controller: segzeros, segmin (mask based) or oracle (pure "
                   "pursuit on the true lane centre line)", static=True, choices=CONTROLLERS,
                   kind=str)
    variant: str = _k("paper", "SegZeros/SegMin law: the paper's (linear ω) or the authors' "
                      "public code's (quadratic ω, EMA 0.5, 3-frame mask OR, 5 m depth cut)",
                      static=True, choices=VARIANTS, kind=str)
    omega_gain: float = _k(3.0, "ω = −omega_gain·d, d = offset of the free run's centre from "
                           "the image centre, normalised by w/2", "rad/s", "nonneg")
    v_gain: float = _k(1.0, "v = v_gain·(1 − d²) before the episode.v_max clip", "m/s",
                       "nonneg")
    min_run: int = _k(3, "free-column runs of at most this many columns are dropped", "px",
                      "nonneg", kind=int)
    end_fraction: float = _k(0.8, "a free run wider than this fraction of the image width "
                             "means end of row", "-", "unit")
    ema: float = _k(None, "EMA factor α on the commands (1 = off); default: the variant's "
                    "(paper 1, public 0.5)", "-", "unit")
    depth_cut: float = _k(None, "mask pixels farther than this are ignored; default: the "
                          "variant's (paper none, public 5 m)", "m", "positive")
    n_frames: int = _k(None, "masks OR'd over the last n frames; default: the variant's "
                       "(paper 1, public 3)", "count", "positive", static=True, kind=int)
    smooth: int = _k(11, "segmin: moving-average width of the column histogram (odd)", "px",
                     "positive", static=True, kind=int)
    on_end: str = _k("straight", "at the end of a row: drive on holding the in-row heading "
                     "(straight), drive on following the in-row line, heading and lateral "
                     "position from odometry (lane), stop, or hold the last command",
                     static=True, choices=ON_END, kind=str)
    heading_alpha: float = _k(0.005, "on_end straight: EMA factor per control step of the "
                              "in-row heading it holds (0.005 at 15 Hz: about 13 s)", "-",
                              "rate")
    lookahead: float = _k(1.0, "oracle: pure-pursuit look-ahead distance", "m", "positive")


@dataclasses.dataclass(frozen=True)
class PerceptionSection:
    source: str = _k("learned", "mask from the learned segmenter or the renderer's ground "
                     "truth", static=True, choices=SOURCES, kind=str)
    checkpoint: str = _k("shipped", "'shipped' (mjxrow/checkpoints/<crop>/) or a checkpoint "
                         "directory (relative to the working directory or the YAML file); one "
                         "group per checkpoint, but the weights are traced, so checkpoints of "
                         "one architecture share one compile", static=True, kind=str)
    threshold: float = _k(0.7, "segmenter output threshold", "-", "unit")
    condition: str = _k("sunny", "sky / lighting condition of the renderer", static=False,
                        choices=CONDITIONS, kind=str)


@dataclasses.dataclass(frozen=True)
class CameraSection:
    mount_height: float = _k(0.40, "camera height above the ground", "m", "positive",
                             static=True)
    mount_forward: float = _k(0.20, "camera offset ahead of the robot centre", "m", None,
                              static=True)
    pitch: float = _k(-10.0, "camera pitch, negative looks down", "deg", "pitch", static=True)
    fovy: float = _k(42.0, "vertical field of view", "deg", "fov", static=True)
    width: int = _k(64, "image width", "px", "positive", static=True, kind=int)
    height: int = _k(64, "image height", "px", "positive", static=True, kind=int)


FieldSection = dataclasses.make_dataclass(
    "FieldSection",
    [(n, Any, dataclasses.field(default=None, metadata=dict(
        doc="field parameter (null: the preset's value)", unit="", check=None, static=False,
        choices=None, kind=None))) for n in F.PARAM_NAMES],
    frozen=True)
FieldSection.__doc__ = "Overrides of the preset's FieldParams (None keeps the preset's value)."

SECTIONS = {"field": FieldSection, "episode": EpisodeSection, "controller": ControllerSection,
            "perception": PerceptionSection, "camera": CameraSection}


@dataclasses.dataclass(frozen=True)
class SweepConfig:
    name: str = _k("sweep", "sweep name, used in titles", kind=str)
    preset: str = _k("zucchini", "base crop preset (FieldParams defaults, plant model, shipped "
                     "checkpoint)", static=True, choices=F.CROPS, kind=str)
    seeds: int = _k(8, "episodes per cell", "count", "positive", static=True, kind=int)
    seed: int = _k(0, "base random seed", "", "nonneg", static=True, kind=int)
    batch_size: int = _k(256, "episodes per jitted call (padded to a multiple of the device "
                         "count)", "count", "positive", static=True, kind=int)
    out: str = _k("runs/sweep", "output directory (the CLI's --out wins)", kind=str)
    field: Any = dataclasses.field(default_factory=FieldSection)
    episode: EpisodeSection = dataclasses.field(default_factory=EpisodeSection)
    controller: ControllerSection = dataclasses.field(default_factory=ControllerSection)
    perception: PerceptionSection = dataclasses.field(default_factory=PerceptionSection)
    camera: CameraSection = dataclasses.field(default_factory=CameraSection)
    axis_order: tuple[str, ...] = dataclasses.field(default=(), metadata=dict(internal=True))
    base_dir: str = dataclasses.field(default=".", metadata=dict(internal=True))


TOP_KEYS = tuple(f.name for f in dataclasses.fields(SweepConfig)
                 if f.name not in SECTIONS and not f.metadata.get("internal"))
# Keys that cannot be grid axes (they name the sweep as a whole).
NOT_AXES = {"name", "seeds", "seed", "batch_size", "out"}

# --smoke: a quick check of the whole pipeline on tiny problems.
SMOKE: dict[str, Any] = {"seeds": 2, "batch_size": 8, "episode.max_time": 4.0,
                         "episode.path_length": 1.5, "camera.width": 16, "camera.height": 16,
                         "field.row_length": 6.0, "field.terrain_length": 10.0}


# ---------------------------------------------------------------------------------------------
# Parsing


def _unknown(path: str, key: str, known) -> ConfigError:
    near = difflib.get_close_matches(str(key), list(known), n=1)
    hint = f"; did you mean {near[0]}?" if near else f"; known: {', '.join(known)}"
    return ConfigError(f"{path}: unknown key{hint}")


def _scalar(path: str, v: Any, meta: dict) -> Any:
    kind, choices, check = meta["kind"], meta["choices"], meta["check"]
    if isinstance(v, bool) or v is None or isinstance(v, (dict, list)):
        raise ConfigError(f"{path}: expected {getattr(kind, '__name__', 'a number')}, got "
                          f"{type(v).__name__} {v!r}")
    if kind is str:
        if not isinstance(v, str):
            raise ConfigError(f"{path}: expected a string, got {type(v).__name__} {v!r}")
        if choices and v not in choices:
            raise ConfigError(f"{path}: {v!r} is not one of {', '.join(choices)}")
        return v
    if kind is int:
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
    ok = {None: True, "positive": v > 0, "nonneg": v >= 0, "unit": 0 <= v <= 1,
          "rate": 0 < v <= 1, "prob": 0 <= v < 1, "pitch": -90 < v < 90, "fov": 0 < v < 180}[check]
    if not ok:
        need = {"positive": "> 0", "nonneg": ">= 0", "unit": "in [0, 1]", "rate": "in (0, 1]",
                "prob": "in [0, 1)",
                "pitch": "in (-90, 90)", "fov": "in (0, 180)"}
        raise ConfigError(f"{path}: must be {need[check]}, got {v}")
    return v


def _value(path: str, v: Any, meta: dict, axis_ok: bool) -> Any:
    """A scalar, or a tuple of scalars for a grid axis."""
    if isinstance(v, (list, dict)) and not axis_ok:
        raise ConfigError(f"{path}: cannot be a grid axis; give one value")
    if isinstance(v, list):
        if not v:
            raise ConfigError(f"{path}: an axis needs at least one value")
        vals = tuple(_scalar(f"{path}[{i}]", x, meta) for i, x in enumerate(v))
        if len(set(vals)) != len(vals):
            raise ConfigError(f"{path}: repeated values in the axis {list(vals)}")
        return vals
    if isinstance(v, dict):
        extra = set(v) - {"start", "stop", "num"}
        if extra:
            raise _unknown(f"{path}.{sorted(extra)[0]}", sorted(extra)[0], ("start", "stop", "num"))
        if set(v) != {"start", "stop", "num"}:
            raise ConfigError(f"{path}: a range needs start, stop and num")
        if meta["kind"] is str:
            raise ConfigError(f"{path}: a range needs a numeric key")
        num = _scalar(f"{path}.num", v["num"], dict(meta, kind=int, check="positive"))
        a = _scalar(f"{path}.start", v["start"], dict(meta, kind=float, check=None))
        b = _scalar(f"{path}.stop", v["stop"], dict(meta, kind=float, check=None))
        vals = [round(float(x), 10) for x in np.linspace(a, b, num)]
        if meta["kind"] is int:
            if not all(float(x).is_integer() for x in vals):
                raise ConfigError(f"{path}: range gives non-integer values {vals}")
            vals = [int(x) for x in vals]
        return _value(path, vals, meta, True)
    return _scalar(path, v, meta)


def _set_dotted(raw: dict, dotted: str, value: Any) -> None:
    parts = dotted.split(".")
    d = raw
    for p in parts[:-1]:
        nxt = d.setdefault(p, {})
        if not isinstance(nxt, dict):
            raise ConfigError(f"{dotted}: {p} is not a section")
        d = nxt
    d.pop(parts[-1], None)  # re-insert so that an override axis comes last in axis order
    d[parts[-1]] = value


def apply_sets(raw: dict, sets: list[str] | tuple[str, ...] = ()) -> dict:
    """Apply `key.sub=value` overrides (value parsed as YAML: `[1.2, 1.8]`, `{start: ...}`)."""
    raw = json.loads(json.dumps(raw))
    for item in sets:
        key, sep, text = item.partition("=")
        if not sep or not key.strip():
            raise ConfigError(f"--set {item!r}: expected key=value")
        try:
            value = yaml.safe_load(text)
        except yaml.YAMLError as e:
            raise ConfigError(f"--set {key}: value {text!r} is not valid YAML ({e.problem})") \
                from None
        _set_dotted(raw, key.strip(), value)
    return raw


def from_dict(raw: Any, base_dir: str | Path = ".", sets=(), smoke: bool = False) -> SweepConfig:
    """Validate a parsed YAML mapping (plus `--set` overrides) into a SweepConfig."""
    if raw is None:
        raw = {}
    if not isinstance(raw, dict):
        raise ConfigError(f"<top>: expected a mapping of keys, got {type(raw).__name__}")
    raw = apply_sets(raw, sets)
    kw: dict[str, Any] = {}
    axes: list[str] = []
    meta_of = {f.name: f.metadata for f in dataclasses.fields(SweepConfig)}
    for key, v in raw.items():
        if key in SECTIONS:
            if not isinstance(v, dict):
                raise ConfigError(f"{key}: expected a mapping of keys, got {type(v).__name__}")
            cls = SECTIONS[key]
            fields = {f.name: f.metadata for f in dataclasses.fields(cls)}
            sub = {}
            for k2, v2 in v.items():
                path = f"{key}.{k2}"
                if k2 not in fields:
                    raise _unknown(path, k2, fields)
                sub[k2] = _value(path, v2, fields[k2], True)
                if isinstance(sub[k2], tuple):
                    axes.append(path)
            kw[key] = cls(**sub)
        elif key in TOP_KEYS:
            kw[key] = _value(key, v, meta_of[key], key not in NOT_AXES)
            if isinstance(kw[key], tuple):
                axes.append(key)
        else:
            raise _unknown(key, key, TOP_KEYS + tuple(SECTIONS))
    cfg = SweepConfig(**kw, axis_order=tuple(axes), base_dir=str(base_dir))
    if smoke:
        cfg = shrink(cfg)
    check(cfg)
    return cfg


def load(path: str | Path, sets=(), smoke: bool = False) -> SweepConfig:
    """Read a sweep YAML (`yaml.safe_load`), apply `--set` overrides, validate."""
    path = Path(path)
    try:
        raw = yaml.safe_load(path.read_text())
    except OSError as e:
        raise ConfigError(f"{path}: cannot read ({e.strerror})") from None
    except yaml.YAMLError as e:
        mark = getattr(e, "problem_mark", None)
        where = f":{mark.line + 1}" if mark else ""
        raise ConfigError(f"{path}{where}: invalid YAML ({getattr(e, 'problem', e)})") from None
    return from_dict(raw, path.parent, sets, smoke)


# ---------------------------------------------------------------------------------------------
# Access by dotted key


def get(cfg: SweepConfig, dotted: str) -> Any:
    obj = cfg
    for p in dotted.split("."):
        obj = getattr(obj, p)
    return obj


def replace(cfg: SweepConfig, dotted: str, value: Any) -> SweepConfig:
    head, _, rest = dotted.partition(".")
    if not rest:
        return dataclasses.replace(cfg, **{head: value})
    return dataclasses.replace(cfg, **{head: dataclasses.replace(getattr(cfg, head),
                                                                 **{rest: value})})


def leaf_keys() -> list[tuple[str, dict]]:
    """Every dotted key with its metadata, top-level keys first."""
    out = [(f.name, f.metadata) for f in dataclasses.fields(SweepConfig)
           if f.name in TOP_KEYS]
    for sec, cls in SECTIONS.items():
        out += [(f"{sec}.{f.name}", f.metadata) for f in dataclasses.fields(cls)]
    return out


def is_static(dotted: str) -> bool:
    return bool(dict(leaf_keys())[dotted]["static"])


def shrink(cfg: SweepConfig) -> SweepConfig:
    """--smoke: the first and last value of the first two axes, the first of any other axis,
    and the SMOKE settings for every key that is not an axis."""
    axes = []
    for i, key in enumerate(cfg.axis_order):
        vals = get(cfg, key)
        keep = (vals[0], vals[-1]) if i < 2 and len(vals) > 1 else vals[:1]
        cfg = replace(cfg, key, keep if len(keep) > 1 else keep[0])
        if len(keep) > 1:
            axes.append(key)
    free_x = not {"field.row_length", "field.terrain_length"} & set(cfg.axis_order)
    for key, v in SMOKE.items():
        if key not in cfg.axis_order and (free_x or not key.startswith("field.")):
            cur = get(cfg, key)
            cfg = replace(cfg, key, v if cur is None or key in ("seeds", "batch_size") or
                          key.startswith(("camera.", "episode.")) else min(cur, v))
    return dataclasses.replace(cfg, axis_order=tuple(axes))


# ---------------------------------------------------------------------------------------------
# Grid


@dataclasses.dataclass(frozen=True)
class Cell:
    """One grid point: `point` holds the axis values, `cfg` the config with every axis resolved
    to this cell's scalar."""

    index: int
    point: tuple[tuple[str, Any], ...]
    cfg: SweepConfig


def expand(cfg: SweepConfig) -> list[Cell]:
    """Cartesian product of the axes (first axis slowest) → cells."""
    values = [get(cfg, k) for k in cfg.axis_order]
    cells = []
    for i, combo in enumerate(itertools.product(*values)):
        c = cfg
        for k, v in zip(cfg.axis_order, combo, strict=True):
            c = replace(c, k, v)
        cells.append(Cell(i, tuple(zip(cfg.axis_order, combo, strict=True)), c))
    return cells


def field_values(cfg: SweepConfig) -> dict[str, float]:
    """Resolved FieldParams of a cell config: the preset's values with the overrides."""
    return {**F.PRESETS[cfg.preset],
            **{k: v for k in F.PARAM_NAMES if (v := getattr(cfg.field, k)) is not None}}


def resolved(cfg: SweepConfig) -> dict[str, Any]:
    """Flat dotted dict of every key of a cell config (field keys resolved from the preset)."""
    out = {k: get(cfg, k) for k, _ in leaf_keys() if not k.startswith("field.")}
    out.update({f"field.{k}": float(v) for k, v in field_values(cfg).items()})
    out["perception.checkpoint"] = checkpoint_path(cfg)
    out["perception.checkpoint_id"] = checkpoint_id(out["perception.checkpoint"])
    return out


def to_dict(cfg: SweepConfig) -> dict[str, Any]:
    """Nested plain dict (axes as lists) for YAML dumps; None field overrides left out."""
    out: dict[str, Any] = {k: get(cfg, k) for k in TOP_KEYS}
    for sec, cls in SECTIONS.items():
        sub = {f.name: getattr(getattr(cfg, sec), f.name) for f in dataclasses.fields(cls)}
        out[sec] = {k: list(v) if isinstance(v, tuple) else v for k, v in sub.items()
                    if v is not None}
    return {k: list(v) if isinstance(v, tuple) else v for k, v in out.items()}


def cell_hash(cell: Cell, extra: Any = None) -> str:
    """Identity of a cell's results: its resolved parameters (not name, out or batch size;
    the checkpoint by its content, not its path) and `extra` (e.g. the static field shape of
    its group). 16 hex digits."""
    skip = ("name", "out", "batch_size", "perception.checkpoint")
    r = {k: v for k, v in resolved(cell.cfg).items() if k not in skip}
    text = json.dumps([r, repr(extra)], sort_keys=True, default=str)
    return hashlib.sha256(text.encode()).hexdigest()[:16]


def static_key(cfg: SweepConfig) -> tuple:
    """The static (compile-relevant) values of a cell config, except the field shape."""
    return tuple((k, get(cfg, k)) for k, m in leaf_keys() if m["static"] and k != "seed")


# ---------------------------------------------------------------------------------------------
# Checks


def checkpoint_path(cfg: SweepConfig) -> str:
    """Checkpoint folder of a cell config ('' when no segmenter is used): the crop's shipped
    one (seg.checkpoint.resolve, which falls back to the all-crop model), or the given path
    (relative to the working directory, else to the YAML's folder). ConfigError if missing."""
    if cfg.perception.source != "learned" or cfg.controller.name == "oracle":
        return ""
    from mjxrow.seg import checkpoint as ckpt

    ck = cfg.perception.checkpoint
    if ck == "shipped":
        ck = cfg.preset
    else:
        p = Path(ck).expanduser()
        ck = str(p if p.is_absolute() or p.exists() else Path(cfg.base_dir) / p)
    try:
        return str(ckpt.resolve(ck))
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


def check(cfg: SweepConfig) -> None:
    """Checks across keys and on every cell: impossible fields (field.validate), missing
    checkpoints. Raises ConfigError naming the dotted key and the cell."""
    cells = expand(cfg)
    params = F.stack_params([F.make_params(cell.cfg.preset, **field_values(cell.cfg))
                             for cell in cells])
    shape_keys = ("max_rows", "max_plants_per_row", "obstacle_slots")
    roomy = F.FieldShape(crop="zucchini", max_rows=10**9, max_plants_per_row=10**9,
                         obstacle_slots=10**9)
    for name, (ok, reason) in F.checks(params, roomy).items():
        if name in shape_keys:
            continue
        ok = np.asarray(ok).reshape(-1)
        if not ok.all():
            cell = cells[int(np.argmin(ok))]
            where = "" if not cell.point else " (cell " + ", ".join(
                f"{k}={v}" for k, v in cell.point) + ")"
            key = f"field.{name}" if name in F.PARAM_NAMES else name
            raise ConfigError(f"{key}: {reason}{where}")
    for cell in cells:
        c = cell.cfg
        where = "" if not cell.point else " (cell " + ", ".join(
            f"{k}={v}" for k, v in cell.point) + ")"
        try:
            checkpoint_path(c)
        except ConfigError as e:
            raise ConfigError(f"{e}{where}") from None
        if c.controller.name == "segmin" and c.controller.smooth % 2 == 0:
            raise ConfigError(f"controller.smooth: must be odd, got {c.controller.smooth}")
        if c.controller.name == "segmin" and c.camera.width < c.controller.smooth + 4:
            raise ConfigError(f"camera.width: segmin needs at least controller.smooth + 4 = "
                              f"{c.controller.smooth + 4} columns, got {c.camera.width}{where}")
        fv = field_values(c)
        if fv["row_length"] * fv["scale"] < c.episode.path_length:
            raise ConfigError(f"episode.path_length: {c.episode.path_length} m is longer than "
                              f"the rows ({fv['row_length'] * fv['scale']:.3g} m){where}")


# ---------------------------------------------------------------------------------------------
# Reference (docs/sweep.md is generated from this)


def _field_docs() -> dict[str, str]:
    import inspect
    import re

    src = inspect.getsource(F.FieldParams)
    return {m[1]: m[2].strip() for m in re.finditer(r"^\s+(\w+): jax\.Array\s+#\s*(.*)$", src,
                                                    re.M)}


def reference_markdown() -> str:
    """The config reference as a markdown table: key, type, default, static, meaning."""
    docs = _field_docs()
    lines = ["| key | type | default | static | meaning |", "|---|---|---|---|---|"]
    for key, m in leaf_keys():
        if key.startswith("field."):
            name = key.split(".", 1)[1]
            doc = docs.get(name, "").replace("|", "\\|")
            lines.append(f"| `{key}` | number | preset's | no | {doc} |")
            continue
        d = get(SweepConfig(), key)
        kind = m["kind"].__name__ if m["kind"] else "number"
        kind = {"float": "number", "int": "integer", "str": "string"}[kind]
        if m["choices"]:
            kind = " \\| ".join(f"`{c}`" for c in m["choices"])
        unit = f" [{m['unit']}]" if m["unit"] not in ("", "-") else ""
        axis = " (not an axis)" if key in NOT_AXES else ""
        default = "variant's" if d is None else f"`{d}`"
        lines.append(f"| `{key}` | {kind} | {default} | {'yes' if m['static'] else 'no'} | "
                     f"{m['doc']}{unit}{axis} |")
    return "\n".join(lines)
