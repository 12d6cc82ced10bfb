"""Inference checkpoints of the segmenter: model config (JSON) + weights (orbax).

A checkpoint folder holds

    config.json   {"model": SegNet attributes, "weights_dtype": "float16" | ..., "meta": {...}}
    weights/      orbax StandardCheckpointer tree {"params": ..., "batch_stats": ...}

Shipped checkpoints live in `mjxrow/checkpoints/<crop>/` (one per crop, or `all/` for one model
trained on every crop). `load` always returns float32 variables, whatever the stored dtype.
"""

from __future__ import annotations

import importlib.resources
import json
import shutil
from pathlib import Path
from typing import Any

import jax
import jax.numpy as jnp
import numpy as np
import orbax.checkpoint as ocp

from mjxrow import crops
from mjxrow.seg.model import SegNet

CHECKPOINT_DIR = Path(str(importlib.resources.files("mjxrow").joinpath("checkpoints")))
WEIGHT_DTYPES = ("float32", "float16", "bfloat16")


def save(path: str | Path, module: SegNet, variables: dict, *, weights_dtype: str = "float32",
         meta: dict[str, Any] | None = None, overwrite: bool = True) -> Path:
    """Write `variables` ({'params', 'batch_stats'}) and `module`'s config to folder `path`.

    weights_dtype: storage precision of floating arrays ("float16" halves the size; the values
    then round to ~1e-3 relative). meta: JSON-serialisable training facts (command, steps, IoU)."""
    if weights_dtype not in WEIGHT_DTYPES:
        raise ValueError(f"weights_dtype: expected one of {WEIGHT_DTYPES}, got {weights_dtype!r}")
    path = Path(path).resolve()
    if (path / "config.json").exists() and not overwrite:
        raise ValueError(f"checkpoint {path}: already exists (pass overwrite=True to replace it)")
    tree = {k: variables[k] for k in ("params", "batch_stats") if k in variables}
    tree = jax.tree.map(lambda x: np.asarray(x).astype(weights_dtype)
                        if jnp.issubdtype(x.dtype, jnp.floating) else np.asarray(x), tree)
    path.mkdir(parents=True, exist_ok=True)
    if (path / "weights").exists():
        shutil.rmtree(path / "weights")
    with ocp.StandardCheckpointer() as ckptr:
        ckptr.save(path / "weights", tree)
    config = {"model": module.config(), "weights_dtype": weights_dtype, "meta": meta or {}}
    (path / "config.json").write_text(json.dumps(config, indent=2, sort_keys=True) + "\n")
    return path


def resolve(crop_or_path: str | Path) -> Path:
    """Folder of a checkpoint: a crop name (shipped; falls back to the all-crop model `all/`)
    or a path. Raises ValueError naming the crop or path when there is no checkpoint."""
    name = str(crop_or_path)
    if (name in crops.CROPS or name == "all") and not Path(name).exists():
        for cand in (CHECKPOINT_DIR / name, CHECKPOINT_DIR / "all"):
            if (cand / "config.json").is_file():
                return cand
        raise ValueError(
            f"segmenter checkpoint for crop {name!r}: none shipped (looked for "
            f"{CHECKPOINT_DIR / name}/config.json and {CHECKPOINT_DIR / 'all'}/config.json); "
            f"train one with `python -m mjxrow.seg.train --crop {name} --export-to "
            f"{CHECKPOINT_DIR / name}`")
    path = Path(name).resolve()
    if not (path / "config.json").is_file() or not (path / "weights").is_dir():
        raise ValueError(f"segmenter checkpoint {str(crop_or_path)!r}: no config.json and "
                         f"weights/ in {path}")
    return path


class CheckpointError(ValueError):
    """A checkpoint that cannot be used: one line naming the folder and what is wrong."""


def read_config(crop_or_path: str | Path) -> dict[str, Any]:
    """The checkpoint's config.json as a dict (model attributes, weights dtype, meta).
    CheckpointError when it is unreadable or not a checkpoint config."""
    path = resolve(crop_or_path) / "config.json"
    try:
        cfg = json.loads(path.read_text())
    except (OSError, UnicodeDecodeError, json.JSONDecodeError) as e:
        raise CheckpointError(f"segmenter checkpoint {path.parent}: config.json is damaged "
                              f"({str(e).splitlines()[0] if str(e) else type(e).__name__})") \
            from None
    if not isinstance(cfg, dict) or not isinstance(cfg.get("model"), dict):
        raise CheckpointError(f"segmenter checkpoint {path.parent}: config.json has no "
                              "'model' mapping")
    return cfg


def module_from_config(model_cfg: dict[str, Any]) -> SegNet:
    """SegNet from a config dict; ValueError on unknown keys."""
    known = set(SegNet().config())
    unknown = sorted(set(model_cfg) - known)
    if unknown:
        raise ValueError(f"model config: unknown keys {unknown}; known: {sorted(known)}")
    return SegNet(**model_cfg)


def verify(crop_or_path: str | Path) -> Path:
    """Cheap checks before any work: config.json readable with a valid model, weights/ not
    empty. Returns the folder; CheckpointError otherwise (`load` finds damaged weights)."""
    path = resolve(crop_or_path)
    cfg = read_config(path)
    try:
        module_from_config(cfg["model"])
        jnp.dtype(cfg.get("weights_dtype", "float32"))
    except (ValueError, TypeError) as e:
        raise CheckpointError(f"segmenter checkpoint {path}: {e}") from None
    if not any(f.is_file() and f.stat().st_size for f in (path / "weights").rglob("*")):
        raise CheckpointError(f"segmenter checkpoint {path}: weights/ holds no data")
    return path


def load(crop_or_path: str | Path) -> tuple[SegNet, dict]:
    """(module, variables) of a shipped crop model or a checkpoint folder; float32 arrays.
    CheckpointError (one line) for a missing, empty or damaged checkpoint."""
    path = verify(crop_or_path)
    cfg = read_config(path)
    module = module_from_config(cfg["model"])
    stored = jnp.dtype(cfg.get("weights_dtype", "float32"))
    target = jax.eval_shape(lambda: module.init(jax.random.key(0),  # shapes only: no program
                                                jnp.zeros((1, 64, 64, 3), jnp.uint8)))
    target = {k: target[k] for k in ("params", "batch_stats") if k in target}
    target = jax.tree.map(lambda s: jax.ShapeDtypeStruct(s.shape, stored)
                          if jnp.issubdtype(s.dtype, jnp.floating) else s, target)
    try:
        with ocp.StandardCheckpointer() as ckptr:
            tree = ckptr.restore(path / "weights", target)
    except Exception as e:  # noqa: BLE001 (orbax raises many kinds; all mean "damaged")
        first = next((ln for ln in str(e).splitlines() if ln.strip()), type(e).__name__)
        raise CheckpointError(f"segmenter checkpoint {path}: weights/ cannot be restored "
                              f"({type(e).__name__}: {first[:200]})") from None
    variables = jax.tree.map(lambda x: x.astype(jnp.float32)
                             if jnp.issubdtype(x.dtype, jnp.floating) else x, tree)
    return module, dict(variables)


def size_bytes(crop_or_path: str | Path) -> int:
    """Bytes on disk of a checkpoint folder (config + weights)."""
    return sum(f.stat().st_size for f in resolve(crop_or_path).rglob("*") if f.is_file())
