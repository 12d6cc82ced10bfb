"""What fixes a closed-loop program, as text the same in every process: the key under which
`runtime.exported` keeps a traced program (`program_key`), and the config text it is made of
(`stable_text`). '' (or `Foreign`) where code from outside the mjxrow package takes part, whose
source `runtime.code_version` does not cover: such a program is traced every run."""

from __future__ import annotations

import dataclasses
import hashlib
from collections.abc import Sequence
from typing import Any

import jax
import numpy as np

from mjxrow import control, crops
from mjxrow import field as mjxrow_field
from mjxrow.rollout import step as rollout_step
from mjxrow.rollout.config import RunConfig


class Foreign(Exception):
    """Code from outside the mjxrow package (its source is not in runtime.code_version)."""


def stable_text(x: Any) -> str:
    """Text of a config value that is the same in every process: dataclasses and tuples field
    by field, functions by module and name (Foreign when not mjxrow's), arrays by content."""
    if dataclasses.is_dataclass(x) and not isinstance(x, type):
        return f"{type(x).__qualname__}(" + ", ".join(
            f"{f.name}={stable_text(getattr(x, f.name))}" for f in dataclasses.fields(x)) + ")"
    if isinstance(x, (tuple, list)):
        return f"{type(x).__qualname__}[" + ", ".join(stable_text(v) for v in x) + "]"
    if isinstance(x, dict):
        return "{" + ", ".join(f"{stable_text(k)}: {stable_text(v)}" for k, v in x.items()) + "}"
    if isinstance(x, (np.ndarray, jax.Array)):
        a = np.asarray(x)
        return f"array{a.shape}{a.dtype}:{hashlib.sha256(a.tobytes()).hexdigest()}"
    if isinstance(x, type) or callable(x):
        mod = getattr(x, "__module__", "") or ""
        if not mod.startswith("mjxrow"):
            raise Foreign(mod)
        return f"{mod}.{getattr(x, '__qualname__', repr(x))}"
    return repr(x)


def _statics(run: RunConfig) -> tuple:
    """The run's static values as its controller says they fix the program (a learned
    policy: its checkpoint's architecture, not its path), else `static_key()`."""
    f = getattr(control.get(run.controller.name), "program_statics", None)
    return run.static_key() if f is None else f(run)


def program_key(
    run: RunConfig | Sequence[RunConfig],
    shape: mjxrow_field.FieldShape,
    episode: rollout_step.EpisodeConfig,
    model_xml: str,
    segmenter: Any = None,
) -> str:
    """What fixes a group's closed-loop program, as text: the run's static values
    (`_statics`), the field shape, the static episode config, the MJX model, the controller and
    the crop as registered, the segmenter's architecture; for a mixed group (a list of runs, one per
    variant) every variant's static values and controller. '' when a controller is code from
    outside the mjxrow package (then the program is traced every run)."""

    runs = [run] if isinstance(run, RunConfig) else list(run)
    try:
        statics = " | ".join(repr(_statics(r)) for r in runs)
        ctrls = " | ".join(stable_text(control.get(r.controller.name)) for r in runs)
        parts = (statics, repr(shape), repr(episode), model_xml, ctrls,
                 stable_text(crops.get(shape.crop)), repr(segmenter))
    except Foreign:
        return ""
    return "\n".join(parts)
