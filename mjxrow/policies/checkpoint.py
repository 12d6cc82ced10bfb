"""Policy checkpoints (what the `policy` controller loads) and training states (what a
training run resumes from), both with orbax.

A policy checkpoint folder holds

    policy.json   {"observation": ObsSpec, "network": NetConfig, "action": {v_max, omega_max},
                   "weights_dtype", "meta": {...}}
    params/       orbax StandardCheckpointer tree: the network's variables

and loads back only where it fits: `load(path, expect=...)` raises a one-line ValueError naming
the config key (`controller.checkpoint` by default) and the mismatch when the folder holds no
policy or one trained on another observation (kind, image size, proprioception).
The shipped policy lives in `mjxrow/checkpoints/policy/` ('shipped').

A training state folder (`OUT/state/`) is an orbax CheckpointManager of {params, opt_state,
counters}, with `train.json` naming the observation and network it belongs to.
"""

from __future__ import annotations

import dataclasses
import importlib.resources
import json
import shutil
from pathlib import Path
from typing import Any

import jax
import jax.numpy as jnp
import numpy as np
import orbax.checkpoint as ocp

from mjxrow.policies import networks
from mjxrow.policies.observe import ObsSpec

SHIPPED = Path(str(importlib.resources.files("mjxrow").joinpath("checkpoints", "policy")))
SPEC_FILE = "policy.json"
WEIGHT_DTYPES = ("float32", "float16")


@dataclasses.dataclass(frozen=True, eq=False)
class PolicyCheckpoint:
    """A loaded policy: network module and variables (float32), what it observes, its action
    limits (v_max [m/s], ω_max [rad/s]) and the training facts."""

    path: Path
    net: networks.PolicyNet
    variables: Any
    spec: ObsSpec
    limits: tuple[float, float]
    meta: dict


def resolve(name: str | Path, base_dir: str | Path = ".", key: str = "controller.checkpoint"
            ) -> Path:
    """The folder of a policy checkpoint: 'shipped' (mjxrow/checkpoints/policy/), or a path
    (absolute, relative to the working directory, else to `base_dir`). ValueError naming
    `key` when it holds no policy."""
    if str(name) == "shipped":
        path = SHIPPED
    else:
        p = Path(name).expanduser()
        path = p if p.is_absolute() or p.exists() else Path(base_dir) / p
    path = path.resolve()
    if not (path / SPEC_FILE).is_file() or not (path / "params").is_dir():
        raise ValueError(f"{key}: no policy checkpoint in {path} (expected {SPEC_FILE} and "
                         f"params/)")
    return path


def save(path: str | Path, variables: Any, spec: ObsSpec, net: networks.NetConfig,
         limits: tuple[float, float], meta: dict | None = None,
         weights_dtype: str = "float32") -> Path:
    """Write a policy checkpoint folder (replacing one there). weights_dtype "float16" halves
    the size (values round to ~1e-3 relative)."""
    if weights_dtype not in WEIGHT_DTYPES:
        raise ValueError(f"weights_dtype: one of {WEIGHT_DTYPES}, got {weights_dtype!r}")
    path = Path(path).resolve()
    path.mkdir(parents=True, exist_ok=True)
    tree = jax.tree.map(lambda x: np.asarray(x, weights_dtype), jax.device_get(variables))
    if (path / "params").exists():
        shutil.rmtree(path / "params")
    with ocp.StandardCheckpointer() as ck:
        ck.save(path / "params", tree)
    doc = {"observation": spec.to_dict(), "network": net.to_dict(),
           "action": {"v_max": float(limits[0]), "omega_max": float(limits[1])},
           "weights_dtype": weights_dtype, "meta": meta or {}}
    (path / SPEC_FILE).write_text(json.dumps(doc, indent=2, sort_keys=True) + "\n")
    return path


MAX_SPEED = 100.0  # bound of action.v_max [m/s] and action.omega_max [rad/s] in policy.json


def _check_doc(doc: Any) -> None:
    """ValueError naming the first field of a parsed policy.json of the wrong type or range (its
    values are trusted nowhere after this: a NaN speed or an unknown dtype fails here)."""
    def is_int(v):
        return isinstance(v, int) and not isinstance(v, bool)

    def number(name, v):
        if isinstance(v, bool) or not isinstance(v, (int, float)) or not np.isfinite(v):
            raise ValueError(f"{name}: expected a finite number, got {v!r}")

    if not isinstance(doc, dict):
        raise ValueError(f"expected a mapping, got {type(doc).__name__}")
    for name in ("observation", "network", "action", "meta"):
        if not isinstance(doc.get(name, {}), dict):
            raise ValueError(f"{name}: expected a mapping, got {type(doc[name]).__name__}")
    for name in ("observation", "network"):
        if name not in doc:
            raise ValueError(f"{name}: missing")
    obs = doc["observation"]
    for name in ("height", "width"):
        if name in obs and not (is_int(obs[name]) and 1 <= obs[name] <= 2048):
            raise ValueError(f"observation.{name}: expected an integer in [1, 2048] px, got "
                             f"{obs[name]!r}")
    if not isinstance(obs.get("proprio", True), bool):
        raise ValueError(f"observation.proprio: expected true or false, got {obs['proprio']!r}")
    net = doc["network"]
    for name in ("channels", "kernels", "strides"):
        v = net.get(name, [1])
        if not (isinstance(v, list) and v and all(is_int(x) and 1 <= x <= 4096 for x in v)):
            raise ValueError(f"network.{name}: expected a list of integers in [1, 4096], got "
                             f"{v!r}")
    if not (is_int(net.get("hidden", 1)) and 1 <= net.get("hidden", 1) <= 65536):
        raise ValueError(f"network.hidden: expected an integer in [1, 65536], got "
                         f"{net['hidden']!r}")
    number("network.init_log_std", net.get("init_log_std", 0.0))
    for name, v in doc.get("action", {}).items():
        if name not in ("v_max", "omega_max"):
            raise ValueError(f"action.{name}: unknown key (v_max, omega_max)")
        number(f"action.{name}", v)
        if not 0 < v <= MAX_SPEED:
            raise ValueError(f"action.{name}: expected a value in (0, {MAX_SPEED:g}], got {v!r}")
    if doc.get("weights_dtype", "float32") not in WEIGHT_DTYPES:
        raise ValueError(f"weights_dtype: one of {', '.join(WEIGHT_DTYPES)}, got "
                         f"{doc['weights_dtype']!r}")
    shape = doc.get("meta", {}).get("image_shape")
    if shape is not None and not (isinstance(shape, list) and len(shape) == 3 and all(
            is_int(x) and 1 <= x <= 4096 for x in shape)):
        raise ValueError(f"meta.image_shape: expected 3 positive integers, got {shape!r}")


def read_spec(path: Path, key: str = "controller.checkpoint") -> tuple[ObsSpec, networks.NetConfig,
                                                                       dict]:
    """(observation, network, the whole policy.json) of a checkpoint folder, each field checked
    (`_check_doc`): a one-line ValueError naming `key`, the file and the field."""
    try:
        doc = json.loads((path / SPEC_FILE).read_text())
        _check_doc(doc)
        return ObsSpec(**doc["observation"]), networks.NetConfig.from_dict(doc["network"]), doc
    except (KeyError, TypeError, ValueError, OSError) as e:  # JSONDecodeError: a ValueError
        raise ValueError(f"{key}: {path / SPEC_FILE} is not a policy spec "
                         f"({str(e).splitlines()[0] if str(e) else type(e).__name__})") from None


def check_spec(saved: ObsSpec, expect: dict[str, Any], where: str,
               key: str = "controller.checkpoint") -> None:
    """ValueError naming `key` and the first field of `expect` (ObsSpec field → value) that
    differs from the saved observation."""
    for name, want in expect.items():
        have = getattr(saved, name)
        if have != want:
            what = {"kind": "observation", "height": "image height [px]",
                    "width": "image width [px]", "proprio": "proprioception"}[name]
            raise ValueError(f"{key}: {where} was trained on {saved.describe()}; this run "
                             f"needs {what} {want!r}, the checkpoint has {have!r}")


def load(name: str | Path, expect: dict[str, Any] | None = None, base_dir: str | Path = ".",
         key: str = "controller.checkpoint") -> PolicyCheckpoint:
    """Load a policy checkpoint ('shipped' or a folder), checking `expect` (ObsSpec field →
    value, e.g. {"height": 64, "width": 64}) against what it was trained on. One-line
    ValueErrors naming `key`."""
    path = resolve(name, base_dir, key)
    spec, net_cfg, doc = read_spec(path, key)
    check_spec(spec, expect or {}, str(path), key)
    net = networks.PolicyNet(net_cfg)
    obs = example_obs(spec, doc.get("meta", {}).get("image_shape"))
    target = jax.eval_shape(lambda: networks.init(net, obs, jax.random.key(0)))
    stored = doc.get("weights_dtype", "float32")
    target = jax.tree.map(lambda s: jax.ShapeDtypeStruct(s.shape, jnp.dtype(stored)), target)
    try:
        with ocp.StandardCheckpointer() as ck:
            tree = ck.restore(path / "params", target)
    except Exception as e:  # orbax raises several kinds on a structure mismatch
        msg = str(e).splitlines()[0] if str(e) else type(e).__name__
        raise ValueError(f"{key}: {path} params do not match its {SPEC_FILE} "
                         f"({spec.describe()}, network {net_cfg}): {msg}") from None
    have = [tuple(x.shape) for x in jax.tree.leaves(tree)]
    want = [tuple(x.shape) for x in jax.tree.leaves(target)]
    if have != want:
        bad = next((i for i, (a, b) in enumerate(zip(have, want, strict=False)) if a != b),
                   min(len(have), len(want)))
        raise ValueError(f"{key}: {path} params do not match its {SPEC_FILE} ({spec.describe()}, "
                         f"network {net_cfg}): array {bad} is stored as "
                         f"{have[bad] if bad < len(have) else 'missing'}, the network needs "
                         f"{want[bad] if bad < len(want) else 'none'}")
    variables = jax.tree.map(lambda x: jnp.asarray(x, jnp.float32), tree)
    act = doc.get("action", {})
    return PolicyCheckpoint(path, net, variables, spec,
                            (float(act.get("v_max", 0.5)), float(act.get("omega_max", 1.0))),
                            doc.get("meta", {}))


def example_obs(spec: ObsSpec, image_shape=None) -> dict:
    """A zero observation of `spec` (features: the saved image shape)."""
    if spec.kind in ("rgb", "chroma"):
        img = jnp.zeros((spec.height, spec.width, 3), jnp.uint8)
    elif spec.kind == "mask":
        img = jnp.zeros((spec.height, spec.width, 1), jnp.uint8)
    else:
        if image_shape is None:
            raise ValueError("features checkpoint: meta.image_shape missing")
        img = jnp.zeros(tuple(image_shape), jnp.float32)
    out = {"image": img}
    if spec.proprio:
        out["proprio"] = jnp.zeros(4, jnp.float32)
    return out
