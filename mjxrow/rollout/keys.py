"""The settable keys of every section of a run's config (the vocabulary `rollout.config` builds
runs from, sweeps and searches check against, and docs/sweep.md's key table lists): each
section IS a domain config, its keys that config's fields; a key's documentation is its field's
trailing comment, its type the annotation; `TRACED` / `STATIC` name the numbers that never
recompile, `CHOICES` the allowed strings, `REJECTED` the fields the YAML may not set."""

from __future__ import annotations

import dataclasses
import functools
import inspect
import re
from typing import Any

from mjxrow import control
from mjxrow.field import params as mjxrow_field_params
from mjxrow.physics.robot import RobotConfig
from mjxrow.physics.sim import SimConfig
from mjxrow.policies.perception import PerceptionConfig
from mjxrow.render import Intrinsics, RenderConfig
from mjxrow.rollout.step import EpisodeConfig

SECTIONS: dict[str, type] = {"sim": SimConfig, "robot": RobotConfig, "camera": Intrinsics,
                             "render": RenderConfig, "episode": EpisodeConfig,
                             "perception": PerceptionConfig}
ORDER = ("field", "sim", "robot", "camera", "render", "episode", "controller", "perception")

# fields of a domain config that the YAML cannot set, and why
REJECTED: dict[str, str] = {
    "robot.cam_fovy": "the camera's vertical field of view is camera.fovy",
    "episode.crop": "the crop is the top-level key preset",
    "episode.sim": "physics settings are the sim section",
}


@dataclasses.dataclass(frozen=True)
class Key:
    """One settable key: dotted name, scalar kind ('float', 'int', 'bool', 'str'), whether null
    is allowed, default, documentation, static (fixes the compiled program) or traced, the
    allowed strings, and the controllers that have it (controller keys only)."""

    name: str
    kind: str
    optional: bool
    default: Any
    doc: str
    static: bool
    choices: tuple[str, ...] | None = None
    controllers: tuple[str, ...] = ()


_FIELD = re.compile(r"^\s+(\w+)\s*:\s*([^=#]+?)\s*(?:=\s*([^#]*?))?\s*(?:#\s*(.*))?$")


@functools.cache
def comment_docs(cls: type) -> dict[str, str]:
    """name → the trailing comment of each field line of `cls` (continued on the following
    comment-only lines)."""
    out: dict[str, str] = {}
    last = None
    for line in inspect.getsource(cls).splitlines():
        cont = re.match(r"^\s+#\s*(.*)$", line)
        if cont and last is not None:
            out[last] += " " + cont.group(1).strip()
            continue
        m = _FIELD.match(line)
        last = None
        if m and m.group(4) is not None:
            last = m.group(1)
            out[last] = m.group(4).strip()
    return out


def _kind(annotation: str, default: Any) -> tuple[str, bool]:
    ann = str(annotation)
    optional = "None" in ann or default is None
    for k in ("bool", "int", "float", "str"):
        if re.search(rf"\b{k}\b", ann):
            return ("float" if k == "float" else k), optional
    return "float", optional


def _class_keys(section: str, cls: type, static_default: bool) -> dict[str, Key]:
    docs = comment_docs(cls)
    traced = set(getattr(cls, "TRACED", ()))
    static = set(getattr(cls, "STATIC", ()))
    choices = getattr(cls, "CHOICES", {})
    out = {}
    for f in dataclasses.fields(cls):
        name = f"{section}.{f.name}"
        if name in REJECTED or f.name.startswith("_"):
            continue
        default = f.default if f.default is not dataclasses.MISSING else None
        kind, optional = _kind(f.type, default)
        is_static = (f.name in static) or (static_default and f.name not in traced)
        out[name] = Key(name, kind, optional, default, docs.get(f.name, ""), is_static,
                        tuple(choices[f.name]) if f.name in choices else None)
    return out


FIELD_INTEGERS = ("rows_per_group",)  # FieldParams values that are counts


@functools.cache
def _field_keys() -> dict[str, Key]:
    docs = comment_docs(mjxrow_field_params.FieldParams)
    return {f"field.{n}": Key(f"field.{n}", "int" if n in FIELD_INTEGERS else "float", True,
                              None, docs.get(n, "") + " (null: the preset's value)", False)
            for n in mjxrow_field_params.PARAM_NAMES}


def controller_keys(names: tuple[str, ...] | None = None) -> dict[str, Key]:
    """`controller.*` keys of the named controllers (default: every registered one); a key
    several controllers share is listed once with all of them."""
    names = tuple(names or control.names())
    out: dict[str, Key] = {"controller.name": Key(
        "controller.name", "str", False, "segzeros",
        "the controller, by its registered name", True, control.names())}
    for n in names:
        c = control.get(n)
        for k, key in _class_keys("controller", c.config, False).items():
            prev = out.get(k)
            out[k] = dataclasses.replace(key, controllers=(prev.controllers if prev else ()) + (n,))
    return out


def section_keys(section: str, controllers: tuple[str, ...] | None = None) -> dict[str, Key]:
    """Every settable key of one section (dotted name → Key)."""
    if section == "field":
        return _field_keys()
    if section == "controller":
        return controller_keys(controllers)
    cls = SECTIONS[section]
    return _class_keys(section, cls, True)


def all_keys() -> dict[str, Key]:
    """Every section key, in section order."""
    out: dict[str, Key] = {}
    for s in ORDER:
        out.update(section_keys(s))
    return out


def is_static(dotted: str) -> bool:
    return all_keys()[dotted].static
