"""Resumable training states with orbax: a training state folder (`OUT/state/`) is an orbax
CheckpointManager of {params, opt_state, counters}, with `train.json` naming the observation
and network it belongs to."""

from __future__ import annotations

import json
import math
import time
from pathlib import Path
from typing import Any

import jax
import jax.numpy as jnp
import orbax.checkpoint as ocp

from mjxrow import runtime


def _manager(folder: Path) -> ocp.CheckpointManager:
    return ocp.CheckpointManager(folder.resolve(), options=ocp.CheckpointManagerOptions(
        max_to_keep=2, create=True))


class PendingSave:
    """A training state that orbax may still be writing (`save_state(..., wait=False)`)."""

    def __init__(self, mgr: ocp.CheckpointManager | None = None):
        self._mgr = mgr

    def wait(self) -> float:
        """Return once the state is on disk (at once the second time); seconds waited."""
        if self._mgr is None:
            return 0.0
        t0 = time.perf_counter()
        mgr, self._mgr = self._mgr, None
        try:
            mgr.wait_until_finished()
        finally:
            mgr.close()
        return time.perf_counter() - t0


def save_state(folder: str | Path, step: int, tree: Any, about: dict,
               wait: bool = True) -> PendingSave:
    """Save a training state `tree` (params, opt_state, counters) as step `step`, unless that
    step is saved already (the loop's periodic save and its final one can fall on the same
    iteration); `about` (JSON: observation, network, ...) is written beside it for
    `restore_state`'s check. The arrays are copied to the host before it returns; with
    `wait=False` orbax writes them in the background until the returned save's `wait()` (a
    state cut short is never the latest: orbax finalises a step by renaming its folder)."""
    folder = Path(folder)
    folder.mkdir(parents=True, exist_ok=True)
    (folder / "train.json").write_text(json.dumps(about, indent=2, sort_keys=True) + "\n")
    mgr = _manager(folder)
    try:
        if step in mgr.all_steps():  # saved at this iteration already (its last save_every)
            mgr.close()
            return PendingSave()
        mgr.save(step, args=ocp.args.StandardSave(jax.device_get(tree)), force=True)
    except BaseException:
        mgr.close()
        raise
    pending = PendingSave(mgr)
    if wait:
        pending.wait()
    return pending


def restore_state(folder: str | Path, target: Any, about: dict,
                  key: str = "--resume") -> tuple[int, Any] | None:
    """(step, tree) of the latest training state in `folder`, restored like `target`; None
    when there is none. ValueError naming `key` and the first entry of `about` that differs
    from the saved run's."""
    folder = Path(folder)
    if not (folder / "train.json").is_file():
        return None
    try:
        saved = json.loads((folder / "train.json").read_text())
    except (OSError, ValueError) as e:  # JSONDecodeError, UnicodeDecodeError: ValueErrors
        raise ValueError(f"{key}: {folder / 'train.json'} is damaged ({e}); use another --out "
                         "or remove the folder") from None
    if not isinstance(saved, dict):
        raise ValueError(f"{key}: {folder / 'train.json'} is damaged (not a mapping); use "
                         "another --out or remove the folder")
    for k, v in about.items():
        if saved.get(k) != json.loads(json.dumps(v)):
            raise ValueError(f"{key}: {folder} holds a run with another {k} "
                             f"({saved.get(k)!r}, this run: {v!r}); use another --out")
    with _manager(folder) as mgr:
        step = mgr.latest_step()
        if step is None:
            return None
        try:
            tree = mgr.restore(step, args=ocp.args.StandardRestore(target))
        except Exception as e:  # noqa: BLE001 (orbax raises many kinds; all mean "damaged")
            first = next((ln for ln in str(e).splitlines() if ln.strip()), type(e).__name__)
            raise ValueError(f"{key}: the training state {folder / str(step)} cannot be "
                             f"restored ({type(e).__name__}: {first[:200]}); remove that step "
                             "folder to resume from the one before, or use another --out"
                             ) from None
    return int(step), tree


def storable(tree: Any) -> dict:
    """The leaves of `tree` that orbax can store, by their index: typed PRNG keys as their key
    data, empty arrays left out (orbax refuses them; `restored` makes them again)."""
    out = {}
    for i, x in enumerate(jax.tree.leaves(tree)):
        if runtime.is_key(x):
            x = jax.random.key_data(x)
        if math.prod(x.shape):
            out[f"{i:05d}"] = x
    return out


def restored(stored: dict, like: Any) -> Any:
    """The tree of `like` (arrays or shapes) from `storable`'s leaves."""
    leaves, treedef = jax.tree.flatten(like)
    out = []
    for i, ref in enumerate(leaves):
        x = stored.get(f"{i:05d}")
        if runtime.is_key(ref):
            out.append(jax.random.wrap_key_data(jnp.asarray(x)))
        else:
            out.append(jnp.zeros(ref.shape, ref.dtype) if x is None else jnp.asarray(x))
    return jax.tree.unflatten(treedef, out)
