"""A sweep group's cell files, each written (atomically) as soon as its last episode is in
(`CellWriter`, the group's `on_batch_done`), with the progress bar and the ETA it moves: a
cell file holds the cell's episode rows, its identity columns and every resolved parameter
(`cell_rows`)."""

from __future__ import annotations

import contextlib
import dataclasses
import time
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np
import pandas as pd

from mjxrow import render as mjxrow_render
from mjxrow import runtime, stopwatch
from mjxrow.rollout.config import RunConfig
from mjxrow.sweep import grid as sweep_grid
from mjxrow.sweep import report as sweep_report

if TYPE_CHECKING:
    from mjxrow.sweep import groups as sweep_groups


def atomic_write_csv(path: Path, df: pd.DataFrame) -> None:
    sweep_report.atomic_write_text(path, df.to_csv(index=False))


def resolved_params(run: RunConfig) -> dict[str, Any]:
    """grid.resolved with the render knobs left at None (by crop, by resolution, by backend) set
    to the values the renderer used (render.resolve), so that results.csv says what ran. The
    cell hash keeps the given values."""

    out = sweep_grid.resolved(run)
    used = mjxrow_render.resolve(run.render, run.preset, run.camera)
    for k, v in dataclasses.asdict(used).items():
        if out.get(f"render.{k}", 0) is None:
            out[f"render.{k}"] = v
    return out


def cell_rows(group: sweep_groups.Group, cell_index: int, rows: pd.DataFrame) -> pd.DataFrame:
    """Episode rows of one cell with identity columns and every resolved parameter."""
    cell = group.cell(cell_index)
    rows = rows.sort_values("episode").reset_index(drop=True)
    ident = pd.DataFrame({"cell": cell.index, "episode": rows["episode"],
                          "cell_hash": group.hashes[group.cells.index(cell)],
                          "group": group.index})
    params = pd.DataFrame([resolved_params(cell.cfg)] * len(rows))
    metrics = rows.drop(columns=[c for c in ("cell", "episode") if c in rows])
    return pd.concat([ident, params, metrics], axis=1)


COMPILE_EVENT = "/jax/core/compile/backend_compile_duration"  # jax.monitoring, per XLA compile


class CellWriter:
    """on_batch_done of one group: collects episode rows per cell and writes each cell's file
    (atomically) as soon as all its episodes are in; advances the progress bar."""

    def __init__(self, group: sweep_groups.Group, seeds: int, cells_dir: Path, bar,
                 watch: stopwatch.Stopwatch | None = None, lock=None, in_batch: bool = False):
        self.group, self.seeds, self.dir, self.bar = group, seeds, cells_dir, bar
        # a shown bar on a CPU moves inside a batch (its batches take minutes there)
        self.in_batch = self._in_batch if in_batch else None
        self.shown = 0  # episodes of the running batch already counted on the bar
        self.watch = watch or stopwatch.Stopwatch()
        self.lock = lock or contextlib.nullcontext()
        self.pending: dict[int, list[pd.DataFrame]] = {}
        self.times = [time.perf_counter()]
        self.episodes = 0
        self.compile_s, self.programs = 0.0, 0
        self.clock = stopwatch.Stopwatch()  # the batches' time, compilation apart (the ETA's)
        self.run_s = 0.0  # the batches' time outside compilation, up to the last one

    def built(self) -> None:
        """The group's model and policy are built: its batches' clock starts now (building
        happens once per group, so it is no part of the time per batch the ETA counts)."""
        self.clock = stopwatch.Stopwatch()

    def on_compile(self, event: str, seconds: float, **_) -> None:
        """A jax.monitoring listener: adds up XLA compilations, so that the bar tells compile
        from run and the ETA counts run time only."""
        if event != COMPILE_EVENT:
            return
        self.compile_s += seconds
        self.programs += 1
        if not self.episodes:
            self.bar.set_postfix_str(f"group {self.group.index}: compiling, then the first "
                                     f"batch ({self.compile_s:.0f} s of compilation so far)",
                                     refresh=False)

    def __call__(self, rows: pd.DataFrame) -> None:
        self.times.append(time.perf_counter())
        self.run_s = self.clock.split()["run"]
        for ci, part in rows.groupby("cell", sort=False):
            parts = self.pending.setdefault(int(ci), [])
            parts.append(part)
            if sum(len(p) for p in parts) >= self.seeds:
                df = cell_rows(self.group, int(ci), pd.concat(self.pending.pop(int(ci))))
                if runtime.writer():
                    with self.lock, self.watch.writing():
                        atomic_write_csv(self.dir / f"{df['cell_hash'].iloc[0]}.csv", df)
        self.episodes += len(rows)
        self.bar.update(len(rows) - self.shown)
        self.shown = 0
        self.bar.set_postfix_str(f"group {self.group.index}: {self.eta()}")

    def _in_batch(self, steps: int, ended: int, n: int) -> None:
        """Between chunks of a running batch: its episodes ended so far go on the bar, with
        the control steps run (`groups.evaluate_episodes`' in_batch)."""
        if ended > self.shown:
            self.bar.update(ended - self.shown)
            self.shown = ended
        self.bar.set_postfix_str(f"group {self.group.index}: batch at control step {steps}, "
                                 f"{ended} of {n} episodes ended; {self.eta()}", refresh=False)

    def eta_seconds(self) -> float | None:
        """Seconds left in this group at the rate of the batches so far (tracing, lowering and
        compilation left out: the union of JAX's compile spans); None before the first
        batch."""
        if not self.episodes or self.run_s <= 0:
            return None
        return (len(self.group.episodes) - self.episodes) * self.run_s / self.episodes

    def eta(self) -> str:
        """`eta_seconds` as the progress bar says it: known from the first batch on."""
        if self.episodes >= len(self.group.episodes):
            return "done"
        left = self.eta_seconds()
        return "running" if left is None else f"about {left:.0f} s left in this group"

    def timing(self) -> str:
        dt = np.diff(self.times)
        if not dt.size:
            return "no batch finished"
        rest = f", then {np.median(dt[1:]):.1f} s per batch (median of {dt.size - 1})" \
            if dt.size > 1 else ""
        return (f"{self.times[-1] - self.times[0]:.1f} s for {self.episodes} episodes: first "
                f"batch {dt[0]:.1f} s including {self.compile_s:.1f} s of compilation{rest}")
