"""`--set KEY=VALUE` for training: keys under `train.`, `env.` (with `env.randomize.` and
`env.reward.`), `net.`, `ppo.` and `bc.` set fields of the training dataclasses (same names);
every other key is a run key (`camera.width`, `sim.path_length`, `field.d_rr`, ...) handed to
`rollout.config.build_run` for the environments and the evaluation. Values are YAML
(`[16, 32]`, `true`, `null`); an unknown key is a one-line error naming it."""

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


def _replace(obj: Any, path: list[str], value: Any, dotted: str) -> Any:
    names = {f.name: f for f in dataclasses.fields(obj)}
    head = path[0]
    if head not in names or head == "run":
        raise ValueError(f"{dotted}: unknown key (known: "
                         f"{', '.join(n for n in names if n != 'run')})")
    if len(path) > 1:
        sub = getattr(obj, head)
        if not dataclasses.is_dataclass(sub):
            raise ValueError(f"{dotted}: {head} has no sub-keys")
        value = _replace(sub, path[1:], value, dotted)
    elif isinstance(value, list):
        value = tuple(tuple(v) if isinstance(v, list) else v for v in value)
    try:
        return dataclasses.replace(obj, **{head: value})
    except (TypeError, ValueError) as e:
        msg = str(e)
        raise ValueError(msg if msg.startswith(dotted.split(".")[0]) else f"{dotted}: {msg}") \
            from None


def apply_sets(cfg: TrainConfig, sets: list[str] | tuple[str, ...]
               ) -> tuple[TrainConfig, dict[str, Any]]:
    """(cfg with the training keys of `sets` applied, {run key: value} of the others)."""
    run: dict[str, Any] = {}
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
        if section == "train":
            cfg = _replace(cfg, rest.split("."), value, key)
        else:
            cfg = _replace(cfg, [section, *rest.split(".")], value, key)
    return cfg, run
