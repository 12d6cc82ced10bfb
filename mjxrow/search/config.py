"""Search configuration: YAML → a validated `SearchConfig`.

A search YAML is a sweep YAML without grid axes (the scenario: `name`, `preset`, `seed`, `out`
and the sections `field`, `sim`, `robot`, `camera`, `render`, `episode`, `controller`,
`perception`, read and checked by `mjxrow.sweep.config`), plus the search's own keys:

    box:                          # traced keys → [low, high] (or a list of names)
      field.row_curvature: [0.0, 0.04]
      perception.condition: [sunny, cloudy, crepuscular, long_shadows]
    method: cma_es                # cma_es | random | sobol
    baseline: auto                # random | sobol | none | auto (random, none when method is)
    population: 64                # candidates per generation: one batched call
    repeats: 2                    # episodes (seeds) per candidate
    budget: {episodes: 20000, minutes: 5, failures: null}
    objective: {margin: lane, fail_share: 0.5, merge_radius: 0.15}
    cma_es: {sigma: 0.3, patience: 10}
    top: 3                        # failures drawn (first frame, mask, trajectory)

Every searched key must be traced (a new value never recompiles: `rollout.config`'s
static / traced flags); each bound is checked alone against the key's limits (the domain
classes, `mjxrow.limits`, `field.checks`, the physics' lane and relief checks). `--set` takes
the same grammar as a sweep's (`--set box.field.d_rr=[1.2,2.4]`, `--set budget.episodes=500`).
Errors are one line naming the dotted key (`ConfigError`).
"""

from __future__ import annotations

import dataclasses
import math
from pathlib import Path
from typing import Any

from mjxrow import field as mjxrow_field
from mjxrow import limits
from mjxrow.rollout import keys as rollout_keys
from mjxrow.rollout.config import ConfigError, apply_sets
from mjxrow.search import box as search_box
from mjxrow.sweep import config as sweep_config
from mjxrow.sweep import grid as sweep_grid
from mjxrow.sweep.yamlfile import read_yaml

METHODS = ("cma_es", "random", "sobol")
BASELINES = ("random", "sobol", "none", "auto")
MARGINS = ("lane",)
SEARCH_KEYS = ("box", "method", "baseline", "population", "repeats", "budget", "objective",
               "cma_es", "top")
SCENARIO_KEYS = ("name", "preset", "seed", "out")
SWEEP_ONLY = {"seeds": "a search runs `repeats` episodes per candidate",
              "batch_size": "a search runs one generation (population × repeats) per call",
              "mix_controllers": "a search runs one controller"}
SECTIONS = {"budget": ("episodes", "minutes", "failures"),
            "objective": ("margin", "fail_share", "merge_radius"),
            "cma_es": ("sigma", "patience")}

# --smoke: a tiny generation, two of them, no time budget
SMOKE = {"population": 8, "repeats": 1, "budget": {"episodes": 16}, "top": 1}


@dataclasses.dataclass(frozen=True)
class SearchConfig:
    """A validated search: the scenario (a one-cell sweep config), the box, and the search's
    settings. `shape` is the static field shape that holds every field of the box."""

    scenario: sweep_config.SweepConfig
    box: search_box.Box
    shape: mjxrow_field.FieldShape
    method: str = "cma_es"
    baseline: str = "random"
    population: int = 64
    repeats: int = 2
    episodes: int | None = None  # budget: episodes of the search method
    minutes: float | None = None  # budget: wall time of the search method, compilation included
    failures: int | None = None  # budget: stop once this many distinct failures are found
    margin: str = "lane"
    fail_share: float = 0.5  # a candidate fails when at least this share of its repeats fail
    merge_radius: float = 0.15  # failures nearer than this (normalised L2) are one failure
    sigma: float = 0.3  # CMA-ES's initial step size in normalised coordinates
    patience: int = 10  # CMA-ES restarts after this many generations without progress
    top: int = 3  # failures drawn (first frame, mask, top-down trajectory)
    valid_share: float = 1.0  # share of the box that gives valid fields (1,024 points)

    @property
    def name(self) -> str:
        return self.scenario.name

    @property
    def seed(self) -> int:
        return self.scenario.seed

    @property
    def out(self) -> str:
        return self.scenario.out

    @property
    def generation(self) -> int:
        """Episodes of one generation: population × repeats (the batch of one call)."""
        return self.population * self.repeats

    @property
    def keys(self) -> tuple[str, ...]:
        return tuple(d.key for d in self.box)


def _flatten(node: Any, path: str, out: dict[str, Any]) -> None:
    """box's leaves as dotted keys (`field.d_rr: [...]` and `field: {d_rr: [...]}` alike; a
    later entry wins, as `--set` items come last)."""
    if not isinstance(node, dict):
        raise ConfigError(f"{path}: expected a mapping of keys to [low, high], got "
                          f"{type(node).__name__}")
    for k, v in node.items():
        p = f"{path}.{k}"
        if isinstance(v, dict):
            _flatten(v, p, out)
        else:
            out.pop(p.split(".", 1)[1], None)
            out[p.split(".", 1)[1]] = v


def _dim(key: str, v: Any, keys: dict[str, rollout_keys.Key], controller: str) -> search_box.Dim:
    path = f"box.{key}"
    spec = keys.get(key)
    if spec is None:
        if key == "preset" or key in sweep_config.TOP_KEYS:
            raise ConfigError(f"{path}: not a traced key (it fixes the compiled program or the "
                              "run); give it one value at the top of the file")
        if key in rollout_keys.all_keys():
            raise ConfigError(f"{path}: not a key of controller {controller!r}")
        section, _, name = key.partition(".")
        known = [k.split(".", 1)[1] for k in keys if k.startswith(f"{section}.")]
        if known:
            raise sweep_config.unknown_key(path, name, known)
        raise sweep_config.unknown_key(path, key, rollout_keys.ORDER)
    if spec.static:
        raise ConfigError(f"{path}: static (a new value compiles a new program, every "
                          "generation would recompile); search traced keys only, give this one "
                          f"value in its section (docs/sweep.md lists which keys are traced)")
    if spec.kind == "bool":
        raise ConfigError(f"{path}: true / false cannot be searched; give it one value")
    if spec.choices:
        if not isinstance(v, list) or len(v) < 2:
            raise ConfigError(f"{path}: expected a list of at least two of "
                              f"{', '.join(spec.choices)}, got {v!r}")
        names = tuple(sweep_config.scalar(f"{path}[{i}]", x, "str", choices=spec.choices)
                      for i, x in enumerate(v))
        if len(set(names)) != len(names):
            raise ConfigError(f"{path}: repeated names {list(names)}")
        return search_box.Dim(key, choices=names)
    if not isinstance(v, list) or len(v) != 2:
        raise ConfigError(f"{path}: expected [low, high], got {v!r}")
    lo, hi = (sweep_config.scalar(f"{path}[{i}]", x, "float") for i, x in enumerate(v))
    if not lo < hi:
        raise ConfigError(f"{path}: empty range [{lo:g}, {hi:g}]; give low < high (a fixed "
                          "value belongs in its section)")
    integer = spec.kind == "int"
    if integer and math.floor(hi) - math.ceil(lo) < 1:
        raise ConfigError(f"{path}: [{lo:g}, {hi:g}] holds fewer than two whole numbers")
    return search_box.Dim(key, lo, hi, integer=integer)


def _check_bounds(scenario: sweep_config.SweepConfig, dim: search_box.Dim) -> None:
    """Each bound alone (the other keys at the scenario's values) through the sweep's checks
    of a cell (`sweep.grid.check`); ConfigError naming the box key and the bound."""
    if dim.choices:
        return
    for which, bound in (("low", dim.low), ("high", dim.high)):
        value = int(round(bound)) if dim.integer else bound
        try:
            limits.check_value(dim.key, value)
            vals = {**dict(scenario.values), dim.key: value}
            sweep_grid.check(dataclasses.replace(scenario, values=tuple(vals.items())))
        except (ConfigError, limits.LimitError) as e:
            msg = str(e)
            msg = msg[len(dim.key) + 2:] if msg.startswith(f"{dim.key}: ") else msg
            raise ConfigError(f"box.{dim.key}: the {which} bound {value:g}: {msg}") from None


def _section(raw: dict, name: str) -> dict:
    sec = raw.get(name) or {}
    if not isinstance(sec, dict):
        raise ConfigError(f"{name}: expected a mapping of keys, got {type(sec).__name__}")
    for k in sec:
        if k not in SECTIONS[name]:
            raise sweep_config.unknown_key(f"{name}.{k}", k, SECTIONS[name])
    return sec


def from_dict(raw: Any, base_dir: str | Path = ".", sets=(), smoke: bool = False
              ) -> SearchConfig:
    """Validate a parsed search YAML (plus `--set` overrides) into a SearchConfig."""
    if not isinstance(raw, dict):
        raise ConfigError(f"<top>: expected a mapping of keys, got {type(raw).__name__}")
    raw = apply_sets(raw, sets)
    if smoke:
        raw = {**raw, **{k: v for k, v in SMOKE.items() if k != "budget"},
               "budget": {**SMOKE["budget"]}}
    for key in raw:
        if key in SWEEP_ONLY:
            raise ConfigError(f"{key}: a sweep's key; {SWEEP_ONLY[key]}")
        if key not in SEARCH_KEYS + SCENARIO_KEYS + rollout_keys.ORDER:
            raise sweep_config.unknown_key(key, key,
                                           SCENARIO_KEYS + SEARCH_KEYS + rollout_keys.ORDER)
    scenario = sweep_config.from_dict({k: v for k, v in raw.items() if k not in SEARCH_KEYS},
                                      base_dir, (), smoke)
    if scenario.axis_order:
        k = scenario.axis_order[0]
        raise ConfigError(f"{k}: a list is a sweep's grid axis; a search takes one value per key "
                          f"(search a range with box.{k}: [low, high])")

    def num(path: str, v: Any, kind: str, check: str | None = None, optional=False):
        return sweep_config.scalar(path, v, kind, optional=optional, check=check)

    method = num("method", raw.get("method", "cma_es"), "str")
    if method not in METHODS:
        raise ConfigError(f"method: {method!r} is not one of {', '.join(METHODS)}")
    baseline = num("baseline", raw.get("baseline", "auto"), "str")
    if baseline not in BASELINES:
        raise ConfigError(f"baseline: {baseline!r} is not one of {', '.join(BASELINES)}")
    if baseline == "auto":
        baseline = "none" if method == "random" else "random"
    if baseline == method:
        raise ConfigError(f"baseline: {baseline!r} is the search method itself; give none or "
                          "another method")
    population = num("population", raw.get("population", 64), "int", "positive")
    if population < 2:
        raise ConfigError(f"population: at least 2 candidates per generation, got {population}")
    repeats = num("repeats", raw.get("repeats", 2), "int", "positive")
    top = num("top", raw.get("top", 3), "int", "nonneg")
    if population * repeats > limits.VALUES["batch_size"][0]:
        raise ConfigError(f"population: {population:,} × {repeats:,} repeats = "
                          f"{population * repeats:,} episodes per call, beyond the bound of "
                          f"{limits.VALUES['batch_size'][0]:,} (mjxrow/limits.py)")
    budget, objective, cma = (_section(raw, s) for s in ("budget", "objective", "cma_es"))
    episodes = num("budget.episodes", budget.get("episodes"), "int", "positive", True)
    minutes = num("budget.minutes", budget.get("minutes"), "float", "positive", True)
    failures = num("budget.failures", budget.get("failures"), "int", "positive", True)
    if episodes is None and minutes is None:
        raise ConfigError("budget: give budget.episodes or budget.minutes (or both)")
    if episodes is not None and episodes < population * repeats:
        raise ConfigError(f"budget.episodes: {episodes:,} episodes is less than one generation "
                          f"(population {population} × repeats {repeats} = "
                          f"{population * repeats:,})")
    if episodes is not None and episodes > limits.EPISODES:
        raise ConfigError(f"budget.episodes: {episodes:,} episodes, beyond the bound of "
                          f"{limits.EPISODES:,} (mjxrow/limits.py)")
    margin = num("objective.margin", objective.get("margin", "lane"), "str")
    if margin not in MARGINS:
        raise ConfigError(f"objective.margin: {margin!r} is not one of {', '.join(MARGINS)}")
    fail_share = num("objective.fail_share", objective.get("fail_share", 0.5), "float",
                     "positive")
    merge = num("objective.merge_radius", objective.get("merge_radius", 0.15), "float",
                "positive")
    sigma = num("cma_es.sigma", cma.get("sigma", 0.3), "float", "positive")
    patience = num("cma_es.patience", cma.get("patience", 10), "int", "positive")
    if fail_share > 1:
        raise ConfigError(f"objective.fail_share: a share in (0, 1], got {fail_share}")
    if sigma > 1:
        raise ConfigError(f"cma_es.sigma: a step in normalised coordinates, in (0, 1], got "
                          f"{sigma}")

    flat: dict[str, Any] = {}
    if "box" not in raw or raw["box"] is None:
        raise ConfigError("box: missing; give the traced keys to search with [low, high]")
    _flatten(raw["box"], "box", flat)
    if not flat:
        raise ConfigError("box: empty; give at least one traced key with [low, high]")
    if smoke:  # the box wins over the smoke settings of the scenario (sweep_config.SMOKE)
        scenario = dataclasses.replace(scenario, values=tuple(
            (k, v) for k, v in scenario.values if k not in flat))
    keys = {k: v for s in rollout_keys.ORDER for k, v in rollout_keys.section_keys(
        s, (scenario.controller.name,) if s == "controller" else None).items()}
    given = dict(scenario.values)
    dims = []
    for key, v in flat.items():
        dim = _dim(key, v, keys, scenario.controller.name)
        if key in given:
            raise ConfigError(f"box.{key}: also given as {key} in the scenario; give it in one "
                              "place")
        _check_bounds(scenario, dim)
        dims.append(dim)
    box = tuple(dims)
    shape = search_box.fit_shape(scenario, box)
    share, reason = search_box.valid_share(scenario, box, shape)
    if share == 0:
        raise ConfigError(f"box: no valid field at 1,024 points spread over the box ({reason})")
    return SearchConfig(scenario, box, shape, method, baseline, population, repeats, episodes,
                        minutes, failures, margin, fail_share, merge, sigma, patience, top,
                        share)


def load(path: str | Path, sets=(), smoke: bool = False) -> SearchConfig:
    """Read a search YAML (strictly: `sweep.yamlfile.read_yaml`), apply `--set`, validate."""
    path = Path(path)
    return from_dict(read_yaml(path), path.parent, sets, smoke)


def to_dict(cfg: SearchConfig) -> dict[str, Any]:
    """Plain nested dict that `from_dict` reads back into the same config (config.yaml)."""
    out = {k: v for k, v in sweep_config.to_dict(cfg.scenario).items()
           if k not in SWEEP_ONLY}
    out.update(method=cfg.method, baseline=cfg.baseline, population=cfg.population,
               repeats=cfg.repeats,
               budget={"episodes": cfg.episodes, "minutes": cfg.minutes,
                       "failures": cfg.failures},
               objective={"margin": cfg.margin, "fail_share": cfg.fail_share,
                          "merge_radius": cfg.merge_radius},
               cma_es={"sigma": cfg.sigma, "patience": cfg.patience}, top=cfg.top,
               box={d.key: d.bounds() for d in cfg.box})
    return out


def identity(cfg: SearchConfig) -> dict[str, Any]:
    """What fixes the candidates a search evaluates (to_dict without the budget and `top`):
    a search resumed with a larger budget continues the same streams."""
    out = to_dict(cfg)
    for k in ("budget", "top", "out", "name"):
        out.pop(k, None)
    return out
