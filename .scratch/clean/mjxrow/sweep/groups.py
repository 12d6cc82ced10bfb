"""The cells of a sweep in groups, and the evaluation of one group: grid → groups of cells
sharing every static value (one compile each) → batches of episodes → one row per episode.

`plan` groups the cells (`grid.expand`) and lists the episodes still to run; `evaluate_group` is
the real `Evaluator`, the narrow interface through which `run.run` evaluates a group (tests
inject a fake one):

    evaluate(group: Group, cfg: SweepConfig, on_batch_done: Callable[[DataFrame], None])
        -> DataFrame   # one row per episode of group.episodes: cell, episode, metrics...
"""

from __future__ import annotations

import dataclasses
from collections.abc import Callable
from pathlib import Path

import jax
import numpy as np
import pandas as pd

from mjxrow import field, runtime
from mjxrow.rollout import build as rollout_build
from mjxrow.rollout import metrics as rollout_metrics
from mjxrow.rollout.config import RunConfig
from mjxrow.sweep import cells as sweep_cells
from mjxrow.sweep import config as sweep_config
from mjxrow.sweep import grid as sweep_grid

Evaluator = Callable[
    ["Group", sweep_config.SweepConfig, Callable[[pd.DataFrame], None]], pd.DataFrame
]


@dataclasses.dataclass(frozen=True)
class Group:
    """Cells that share every static value: one static field shape, one compile.

    `episodes` lists the (cell index, episode index) pairs still to run, cell by cell."""

    index: int
    shape: field.FieldShape
    cells: tuple[sweep_grid.Cell, ...]
    hashes: tuple[str, ...]
    episodes: tuple[tuple[int, int], ...]

    @property
    def cfg(self) -> RunConfig:
        """A config with this group's static values (those of its first cell)."""
        return self.cells[0].cfg

    def cell(self, index: int) -> sweep_grid.Cell:
        return next(c for c in self.cells if c.index == index)


CPU_BATCH = 32  # episodes per call on a CPU: its closed loop's best throughput (bench closed_loop)
GPU_BATCH = 4096  # episodes per call and accelerator (beyond it the throughput curve is flat)


def batch_size(setting: int | str, seeds: int, episodes: int, platform: str, devices: int = 1
               ) -> int:
    """Episodes per call of a group of `episodes` episodes: `setting` (at most `episodes`), or
    for `auto`: on a CPU, the fewest whole cells of `seeds` episodes that hold CPU_BATCH (so that
    cells are kept on disk as the sweep goes, each batch at the CPU's best throughput); on an
    accelerator, every episode of the group up to GPU_BATCH per device (one call where it
    fits)."""
    if setting != sweep_config.AUTO:
        return min(int(setting), episodes)
    if platform == "cpu":
        return min(-(-CPU_BATCH // seeds) * seeds, episodes)
    return min(GPU_BATCH * devices, episodes)


def group_shape(cells: list[sweep_grid.Cell]) -> field.FieldShape:
    """The static FieldShape that holds every cell's field (rounded up by field.fit_shape)."""
    return rollout_build.fit_shape([c.cfg for c in cells])


def plan(cfg: sweep_config.SweepConfig, done: set[str] = frozenset()) -> list[Group]:
    """Group the cells by static values (with `mix_controllers`, by those but the
    controller's and the mask source: `RunConfig.share_key`), fit one field shape per group,
    hash every cell, and list the episodes of the cells whose hash is not in `done`."""
    by_key: dict[tuple, list[sweep_grid.Cell]] = {}
    for cell in sweep_grid.expand(cfg):
        key = cell.cfg.share_key() if cfg.mix_controllers else sweep_grid.static_key(cell.cfg)
        by_key.setdefault(key, []).append(cell)
    groups = []
    for gi, cells in enumerate(by_key.values()):
        shape = group_shape(cells)
        hashes = tuple(sweep_grid.cell_hash(c, shape) for c in cells)
        eps = tuple((c.index, e) for c, h in zip(cells, hashes, strict=True) if h not in done
                    for e in range(cfg.seeds))
        groups.append(Group(gi, shape, tuple(cells), hashes, eps))
    return groups


def pending(cfg: sweep_config.SweepConfig, out: Path, report: bool = False) -> list[Group]:
    """`plan` against the cells already finished in `out/cells` (process 0 reads them, every
    process gets its answer; `report`: as `cells.finished_cells`, only under the folder's
    lock)."""
    done = (sorted(sweep_cells.finished_cells(out / "cells", cfg.seeds, report=report))
            if runtime.writer() else [])
    return plan(cfg, set(runtime.agree(done)))


# ---------------------------------------------------------------------------------------------
# Evaluation of one group: fields → rollout → metrics


def evaluate_group(group: Group, cfg: sweep_config.SweepConfig,
                   on_batch_done: Callable[[pd.DataFrame], None]) -> pd.DataFrame:
    """Run `group.episodes` in batches of `batch_size(cfg.batch_size, ...)` (the last one
    padded, so one compile per group), sharded over all local devices (rollout.build), calling
    `on_batch_done(rows)` after each batch (and its `built()`, where it has one, once the
    group's model and policy are built: the batches' clock starts there). Rows: cell, episode,
    lane and every metric of `metrics.summarise` (reason as its name)."""
    by_cell = {c.index: c.cfg for c in group.cells}
    built = rollout_build.build(list(by_cell.values()), group.shape)
    if getattr(on_batch_done, "built", None) is not None:
        on_batch_done.built()
    size = built.padded(batch_size(cfg.batch_size, cfg.seeds, len(group.episodes),
                                   jax.default_backend(), built.devices))
    return evaluate_episodes(built, [(by_cell[c], c, e) for c, e in group.episodes], size,
                             on_batch_done, getattr(on_batch_done, "in_batch", None))


def evaluate_episodes(
    built: rollout_build.Built,
    items: list[tuple[RunConfig, int, int]],
    size: int,
    on_batch_done: Callable[[pd.DataFrame], None] | None = None,
    in_batch: Callable[[int, int, int], None] | None = None,
) -> pd.DataFrame:
    """Run `items` ((run, cell index, episode index) triples of runs `built` was built for)
    in batches of `size` (the last one padded), calling `on_batch_done(rows)` after each.
    Rows in the order of `items`: cell, episode, lane and every metric of
    `metrics.summarise` (reason as its name). With `in_batch`, each batch runs as it goes
    (`Built.rollout`'s progress): `in_batch(control steps run, episodes ended, episodes)`
    between its chunks of control steps (the same numbers)."""
    out = []
    for start in range(0, len(items), size):
        real = list(items[start:start + size])
        batch = built.batch([(r, e) for r, _, e in real], size)

        def shown(steps: int, ended: int, n: int = len(real)) -> None:
            in_batch(steps, min(ended, n), n)  # the padding's copies left out

        # no compile overlaps the run: the ETA leaves compiles out
        log = jax.block_until_ready(built.rollout(batch, shown if in_batch else None))
        met = built.summarise(log, len(real))
        rows = pd.DataFrame({"cell": [c for _, c, _ in real], "episode": [e for *_, e in real],
                             "lane": runtime.to_host(batch.lanes)[:len(real)],
                             **{k: (np.asarray(rollout_metrics.REASONS)[v] if k == "reason" else v)
                                for k, v in met.items() if np.ndim(v) == 1}})
        if on_batch_done is not None:
            on_batch_done(rows)
        out.append(rows)
    return pd.concat(out, ignore_index=True)
