"""The config vocabulary of every command: each section IS a domain config, under its field names.

| section      | domain config                                   | numbers           |
|--------------|-------------------------------------------------|-------------------|
| `field`      | `field.FieldParams` overrides (null: preset's)  | traced            |
| `sim`        | `physics.sim.SimConfig`                         | static            |
| `robot`      | `physics.robot.RobotConfig`                     | static            |
| `camera`     | `render.Intrinsics`                             | static            |
| `render`     | `render.RenderConfig`                           | static            |
| `episode`    | `rollout.step.EpisodeConfig`                    | static but start noise |
| `controller` | `name` + the registered controller's `config`   | per controller    |
| `perception` | `control.perception.PerceptionConfig`           | static but threshold, condition |

The keys of every section, with their documentation, kinds and whether they recompile, are
`rollout.keys`; ranges are checked by the domain class itself when a cell is built.

`RunConfig` is one run's configuration (a sweep cell, the episode CLI's flags, a benchmark's
settings): every section built and checked by its domain class; `build_run(values)` makes one
from dotted keys, `apply_sets` is the one `--set KEY=VALUE` grammar.
"""

from __future__ import annotations

import dataclasses
import json
import math
from pathlib import Path
from typing import Any

import yaml

from mjxrow import control, crops, limits
from mjxrow import field as mjxrow_field
from mjxrow.physics.robot import RobotConfig
from mjxrow.physics.sim import SimConfig
from mjxrow.policies.perception import PerceptionConfig
from mjxrow.render import Intrinsics, RenderConfig
from mjxrow.rollout.keys import ORDER, Key, controller_keys, section_keys
from mjxrow.rollout.step import EpisodeConfig
from mjxrow.seg import checkpoint as seg_checkpoint

# ---------------------------------------------------------------------------------------------
# One run's configuration


class ConfigError(ValueError):
    """A one-line configuration error naming the offending dotted key."""


class Section:
    """Read-only attribute view of a section's values (`cfg.field.d_rr`)."""

    def __init__(self, name: str, values: dict[str, Any]):
        object.__setattr__(self, "_name", name)
        object.__setattr__(self, "_values", dict(values))

    def __getattr__(self, key: str) -> Any:
        try:
            return self._values[key]
        except KeyError:
            raise AttributeError(f"{self._name}.{key}") from None

    def __setattr__(self, key, value):
        raise AttributeError(f"{self._name}: read-only")

    def __eq__(self, other) -> bool:
        return isinstance(other, Section) and (self._name, self._values) == (other._name,
                                                                             other._values)

    def __hash__(self) -> int:
        return hash((self._name, tuple(sorted(self._values.items()))))

    def __repr__(self) -> str:
        return f"Section({self._name}, {self._values})"

    def items(self):
        return self._values.items()


@dataclasses.dataclass(frozen=True)
class ControllerChoice:
    """The chosen controller (`name`) and its config (an instance of the registered
    controller's `config` class); attributes of the config read through
    (`cfg.controller.omega_gain`)."""

    name: str
    params: Any

    def __getattr__(self, key: str) -> Any:
        if key.startswith("__") or key in ("name", "params"):
            raise AttributeError(key)
        return getattr(self.params, key)


@dataclasses.dataclass(frozen=True)
class RunConfig:
    """One run: every section a validated domain config. Hashable."""

    preset: str
    field: Section  # FieldParams overrides given (None: the preset's value)
    sim: SimConfig
    robot: RobotConfig
    camera: Intrinsics
    render: RenderConfig
    episode: EpisodeConfig
    controller: ControllerChoice
    perception: PerceptionConfig
    seed: int = 0
    base_dir: str = "."

    def field_values(self) -> dict[str, float]:
        """Resolved FieldParams values: the preset's with the overrides."""
        over = {k: v for k, v in self.field.items() if v is not None}
        return {**crops.get(self.preset).preset, **over}

    def field_params(self, host: bool = False) -> mjxrow_field.FieldParams:
        """The run's FieldParams; `host`: numpy arrays (field.make_params)."""
        return mjxrow_field.make_params(self.preset, host=host, **self.field_values())

    def get(self, dotted: str) -> Any:
        if dotted in ("preset", "seed"):
            return getattr(self, dotted)
        section, _, key = dotted.partition(".")
        obj = getattr(self, section)
        if section == "controller" and key == "name":
            return obj.name
        return getattr(obj.params if section == "controller" else obj, key)

    def keys(self) -> dict[str, Key]:
        """The keys of this run (its controller's only)."""
        out: dict[str, Key] = {}
        for s in ORDER:
            out.update(section_keys(s, (self.controller.name,) if s == "controller" else None))
        return out

    def flat(self) -> dict[str, Any]:
        """Every key → value (field keys resolved from the preset); `preset` and `seed` first."""
        out: dict[str, Any] = {"preset": self.preset, "seed": self.seed}
        fv = self.field_values()
        for k in self.keys():
            out[k] = float(fv[k[6:]]) if k.startswith("field.") else self.get(k)
        return out

    def static_key(self) -> tuple:
        """The values that fix the compiled program (all but the field shape)."""
        return (self.preset,) + tuple((k, self.get(k)) for k, key in self.keys().items()
                                      if key.static)

    def variant_key(self) -> tuple:
        """The static values of what decides the commands: `controller.*` and, for a mask
        controller, `perception.source`."""
        sees = control.get(self.controller.name).needs_mask
        return tuple(x for x in self.static_key()[1:]
                     if x[0].startswith("controller.") or (sees and x[0] == "perception.source"))

    def share_key(self) -> tuple:
        """The static values but the controller's and the mask source: runs with equal share
        keys can run in one program whose episodes each pick their controller
        (`rollout.build`, `control.perception.mixed_policy`)."""
        return tuple(x for x in self.static_key() if not isinstance(x, tuple) or not (
            x[0].startswith("controller.") or x[0] == "perception.source"))

    def intrinsics(self) -> Intrinsics:
        return self.camera

    def robot_config(self) -> RobotConfig:
        """The robot, its camera's field of view from `camera.fovy`."""
        return dataclasses.replace(self.robot, cam_fovy=self.camera.fovy)

    def controller_params(self) -> Any:
        """The controller's traced params (registry `make_params`) for this image size."""
        c = control.get(self.controller.name)
        return c.make_params(self.controller.params, (self.camera.height, self.camera.width))

    def checkpoint_path(self) -> str:
        """Checkpoint folder ('' when no segmenter is used): 'shipped' is the crop's (or the
        all-crop model), else a path relative to the working directory or `base_dir`.
        ValueError if missing."""
        if self.perception.source != "learned" or not control.get(
                self.controller.name).needs_mask:
            return ""

        ck = self.perception.checkpoint
        if ck == "shipped":
            ck = self.preset
        else:
            p = Path(ck).expanduser()
            ck = str(p if p.is_absolute() or p.exists() else Path(self.base_dir) / p)
        return str(seg_checkpoint.resolve(ck))


def _section(name: str, cls: type, kw: dict[str, Any]) -> Any:
    try:
        return cls(**kw)
    except ValueError as e:
        msg = str(e)
        raise ConfigError(msg if msg.startswith(f"{name}.") else f"{name}.{msg}") from None


def build_run(values: dict[str, Any], seed: int = 0, base_dir: str | Path = ".") -> RunConfig:
    """A RunConfig from dotted keys → scalars (`preset`, `field.d_rr`, `sim.dt`, ...; absent
    keys take their defaults). Every section is built by its domain class, whose checks raise
    ConfigError naming the dotted key."""
    preset = values.get("preset", "zucchini")
    if preset not in crops.CROPS:
        raise ConfigError(f"preset: {preset!r} is not one of {', '.join(crops.names())}")
    by: dict[str, dict[str, Any]] = {s: {} for s in ORDER}
    for k, v in values.items():
        if k == "preset":
            continue
        s, _, key = k.partition(".")
        if s not in by:
            raise ConfigError(f"{k}: unknown key")
        by[s][key] = v
    name = by["controller"].pop("name", "segzeros")
    try:
        c = control.get(name)
    except ValueError as e:
        raise ConfigError(str(e)) from None
    own = {f.name for f in dataclasses.fields(c.config)}
    for key in by["controller"]:
        if key not in own and f"controller.{key}" not in controller_keys():
            raise ConfigError(f"controller.{key}: unknown key")
    ctrl = _section("controller", c.config,
                    {k: v for k, v in by["controller"].items() if k in own})
    unknown = set(by["field"]) - set(mjxrow_field.PARAM_NAMES)
    if unknown:
        raise ConfigError(f"field.{sorted(unknown)[0]}: unknown key")
    try:
        for k, v in values.items():
            limits.check_value(k, v)
        limits.check_value("seed", seed)
    except limits.LimitError as e:
        raise ConfigError(str(e)) from None
    sim_cfg = _section("sim", SimConfig, by["sim"])
    run = RunConfig(
        preset=preset,
        field=Section("field", {n: by["field"].get(n) for n in mjxrow_field.PARAM_NAMES}),
        sim=sim_cfg,
        robot=_section("robot", RobotConfig, by["robot"]),
        camera=_section("camera", Intrinsics, by["camera"]),
        render=_section("render", RenderConfig, by["render"]),
        episode=_section(
            "episode", EpisodeConfig, {**by["episode"], "crop": preset, "sim": sim_cfg}
        ),
        controller=ControllerChoice(name, ctrl),
        perception=_section("perception", PerceptionConfig, by["perception"]),
        seed=int(seed),
        base_dir=str(base_dir),
    )
    check_sizes(run, values)
    return run


def check_sizes(run: RunConfig, given: dict[str, Any] = {}) -> None:  # noqa: B006
    """ConfigError when a size derived from several keys (control steps, physics substeps,
    pixels, terrain patch cells) exceeds its bound in rollout.limits; the message names the key
    that was given (`given`), or the first of the keys the size depends on."""
    def blame(*keys: str) -> str:
        return next((k for k in keys if k in given), keys[0])

    cells = math.ceil(run.sim.patch_size[0] / run.sim.patch_cell) * math.ceil(
        run.sim.patch_size[1] / run.sim.patch_cell)
    try:
        limits.check_count(blame("episode.max_time", "sim.control_hz"), "control steps",
                           run.episode.n_steps, limits.STEPS)
        limits.check_count(blame("sim.dt", "sim.control_hz"), "physics steps per control step",
                           run.sim.substeps, limits.SUBSTEPS)
        limits.check_count(blame("camera.width", "camera.height"), "pixels",
                           run.camera.width * run.camera.height, limits.PIXELS)
        limits.check_count(blame("sim.patch_cell", "sim.path_length", "sim.patch_width"),
                           "terrain patch cells", cells, limits.PATCH_CELLS)
    except limits.LimitError as e:
        raise ConfigError(str(e)) from None


def apply_sets(raw: dict, sets: list[str] | tuple[str, ...] = ()) -> dict:
    """Apply `key.sub=value` overrides to a nested mapping; VALUE is parsed as YAML
    (`[1.2, 1.8]`, `{start: 0, stop: 1, num: 3}`, `true`): the one `--set KEY=VALUE` grammar of
    every command. ConfigError for an item without '=' or with a value that is not YAML."""
    raw = json.loads(json.dumps(raw))
    for item in sets:
        key, sep, text = item.partition("=")
        key = key.strip()
        if not sep or not key:
            raise ConfigError(f"--set {item!r}: expected key=value")
        try:
            value = yaml.safe_load(text)
        except yaml.YAMLError as e:
            raise ConfigError(f"--set {key}: value {text!r} is not valid YAML ({e.problem})") \
                from None
        parts = key.split(".")
        d = raw
        for p in parts[:-1]:
            nxt = d.setdefault(p, {})
            if not isinstance(nxt, dict):
                raise ConfigError(f"{key}: {p} is not a section")
            d = nxt
        d.pop(parts[-1], None)  # re-inserted: an axis given with --set comes last
        d[parts[-1]] = value
    return raw
