"""`--set KEY=VALUE` for training: keys under `train.`, `env.` (with `env.randomize.` and
`env.reward.`), `net.`, `ppo.` and `bc.` set fields of the training dataclasses (same names);
every other key is a run key (`camera.width`, `sim.path_length`, `field.d_rr`, ...) handed to
`rollout.config.build_run` for the environments and the evaluation. Values are YAML
(`[16, 32]`, `true`, `null`); an unknown key is a one-line error naming it. The keys of one
dataclass are set together and then checked (`--set net.channels=[16,32,32] --set
net.kernels=[5,3,3] --set net.strides=[2,2,2]`: a torso of another depth)."""

from __future__ import annotations

import dataclasses
from typing import Any

import yaml

from mjxrow.train.loop import TrainConfig

SECTIONS = ("train", "env", "net", "ppo", "bc")


def _value(text: str, key: str) -> Any:
    try:
        value = yaml.safe_load(text)
    except yaml.YAMLError as e:
        raise ValueError(f"--set {key}: value {text!r} is not valid YAML ({e.problem})") \
            from None
    if isinstance(value, str):  # YAML 1.1 reads 1e-4 (no dot) as a string
        try:
            return float(value)
        except ValueError:
            pass
    return value


def _check_key(obj: Any, name: str, dotted: str) -> None:
    names = [f.name for f in dataclasses.fields(obj)]
    if name not in names or name == "run":
        raise ValueError(f"{dotted}: unknown key (known: "
                         f"{', '.join(n for n in names if n != 'run')})")


def _replace(obj: Any, path: list[str], leaves: dict[str, tuple[Any, str]]) -> Any:
    """`obj` with the fields `leaves` ({name: (value, dotted key)}) of its dataclass at `path`
    set in one replace, so that fields checked together (a network's channels, kernels and
    strides) can change together."""
    first = next(iter(leaves.values()))[1]
    if path:
        _check_key(obj, path[0], first)
        sub = getattr(obj, path[0])
        if not dataclasses.is_dataclass(sub):
            raise ValueError(f"{first}: {path[0]} has no sub-keys")
        changes, keys = {path[0]: _replace(sub, path[1:], leaves)}, first
    else:
        changes = {}
        for name, (value, dotted) in leaves.items():
            _check_key(obj, name, dotted)
            if isinstance(value, list):
                value = tuple(tuple(v) if isinstance(v, list) else v for v in value)
            changes[name] = value
        keys = ", ".join(d for _, d in leaves.values())
    try:
        return dataclasses.replace(obj, **changes)
    except (TypeError, ValueError) as e:
        msg = str(e)
        raise ValueError(msg if msg.startswith(first.split(".")[0]) else f"{keys}: {msg}") \
            from None


def apply_sets(cfg: TrainConfig, sets: list[str] | tuple[str, ...]
               ) -> tuple[TrainConfig, dict[str, Any]]:
    """(cfg with the training keys of `sets` applied, {run key: value} of the others)."""
    run: dict[str, Any] = {}
    groups: dict[tuple[str, ...], dict[str, tuple[Any, str]]] = {}
    for item in sets:
        key, sep, text = item.partition("=")
        key = key.strip()
        if not sep or not key:
            raise ValueError(f"--set {item!r}: expected key=value")
        value = _value(text, key)
        section, _, rest = key.partition(".")
        if section not in SECTIONS:
            run[key] = value
            continue
        if not rest:
            raise ValueError(f"{key}: expected {section}.<field>")
        path = rest.split(".") if section == "train" else [section, *rest.split(".")]
        groups.setdefault(tuple(path[:-1]), {})[path[-1]] = (value, key)
    for path, leaves in groups.items():  # the keys of one dataclass set together
        cfg = _replace(cfg, list(path), leaves)
    return cfg, run
