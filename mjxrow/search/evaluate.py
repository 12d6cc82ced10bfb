"""Episodes of a search: one compiled program for every candidate.

`Evaluator` builds the scenario once (`rollout.build` on the box's field shape: the MJX model,
the policy, the jitted closed loop) and runs any list of (candidate run, episode index) in
batches of one fixed size, population × repeats (padded to the device count, the last batch
padded with copies), as the sweep's `groups.evaluate_episodes` does. Every searched key is
traced, so each generation, the baseline's and the confirmation's episodes reuse the same
program: no recompilation after the first call.

`first_frames` renders the camera image each chosen episode starts with and the mask its
controller sees (the segmenter's, or the renderer's ground truth), for the failure figures.
"""

from __future__ import annotations

import functools
from collections.abc import Sequence
from typing import Any

import jax
import jax.numpy as jnp
import numpy as np

from mjxrow import control, render, runtime
from mjxrow.field import lanes as field_lanes
from mjxrow.physics import sim
from mjxrow.policies import perception
from mjxrow.rollout import build as rollout_build
from mjxrow.rollout import metrics as rollout_metrics
from mjxrow.rollout.config import RunConfig
from mjxrow.rollout.metrics import Log
from mjxrow.search import objective
from mjxrow.search.config import SearchConfig
from mjxrow.seg import model as seg_model
from mjxrow.sweep import grid as sweep_grid

PARAMS = ("row_amplitude", "row_wavelength", "plant_width", "scale")  # for the margin


class Evaluator:
    """Runs episodes of a search's candidates through one compiled program (module doc)."""

    def __init__(self, cfg: SearchConfig):
        self.cfg = cfg
        self.run = sweep_grid.expand(cfg.scenario)[0].cfg  # the scenario: the static values
        self.built = rollout_build.build([self.run], cfg.shape)
        self.size = self.built.padded(cfg.generation)

    def prepare(self) -> None:
        """Compile the program every batch runs in (or load it: the compilation cache and
        the kept traced programs), running no episode; a later Evaluator of the same search
        then finds it there. The scenario's own run stands for the candidates: every searched
        key is traced, so the program is theirs."""
        batch = self.built.batch([(self.run, e) for e in range(self.size)], self.size)
        self.built.executable(batch.args(self.built.mx))

    def _batch(self, items: Sequence[tuple[RunConfig, int]]) -> tuple[Any, Log]:
        batch = self.built.batch(list(items), self.size)
        return batch, jax.block_until_ready(self.built.rollout(batch))

    def episodes(self, items: Sequence[tuple[RunConfig, int]]) -> dict[str, np.ndarray]:
        """Per item (run, episode index), in order: reason (int, metrics.REASONS), margin,
        max_offset [m], half_free [m] (the lane's half free width), lane."""
        parts = []
        for start in range(0, len(items), self.size):
            chunk = list(items[start:start + self.size])
            n = len(chunk)
            batch, log = self._batch(chunk)
            met = self.built.summarise(log, n)
            lanes = np.asarray(runtime.to_host(batch.lanes))[:n]
            widths = np.asarray(runtime.to_host(batch.fields.lane_width))[:n]
            params = {k: np.asarray(runtime.to_host(getattr(batch.fields.params, k)))[:n]
                      for k in PARAMS}
            half = objective.half_free_width(widths[np.arange(n), lanes], params)
            reason = np.asarray(met["reason"]).astype(int)
            parts.append({"reason": reason, "max_offset": np.asarray(met["max_offset"], float),
                          "half_free": half, "lane": lanes,
                          "margin": objective.episode_margin(reason, met["max_offset"], half)})
        if not parts:
            return {k: np.zeros(0) for k in ("reason", "max_offset", "half_free", "lane",
                                              "margin")}
        return {k: np.concatenate([p[k] for p in parts]) for k in parts[0]}

    def replay(self, items: Sequence[tuple[RunConfig, int]]) -> tuple[Any, Log]:
        """(Batch, Log on the host) of at most one batch of items: the episodes again, for the
        figures (the same program and numbers as during the search)."""
        if len(items) > self.size:
            raise ValueError(f"replay: at most {self.size} episodes, got {len(items)}")
        batch, log = self._batch(items)
        return batch, runtime.to_host(log)

    def first_frames(self, batch: Any, runs: Sequence[RunConfig]) -> list[tuple[np.ndarray,
                                                                                   np.ndarray]]:
        """(rgb uint8 [H, W, 3], mask bool [H, W]) of the start of the first len(runs)
        episodes of `batch` (`replay`): the camera at the reset pose, as the controller's
        first step sees it."""
        run = self.run
        segmenter = None
        if control.get(run.controller.name).needs_mask and run.perception.source == "learned":
            segmenter = perception.load_segmenter(run.checkpoint_path(), run.preset)
        return first_frames(self.built, batch, runs, segmenter)


def first_frames(built: Any, batch: Any, runs: Sequence[RunConfig],
                 segmenter: tuple[Any, Any] | None = None) -> list[tuple[np.ndarray,
                                                                            np.ndarray]]:
    """(rgb uint8 [H, W, 3], mask bool [H, W]) at the reset pose of the first len(runs)
    episodes of `batch` (a batch of `built`, a `rollout.build.Built`), run i's sky and
    threshold for episode i; the mask the renderer's ground truth, or with `segmenter`
    ((module, variables) of `perception.load_segmenter`) the learned one."""
    module, variables = segmenter or (None, None)
    fn = _frame_fn(built.shape, built.run.camera, built.run.render, built.episode.sim, module)
    out = []
    for i, r in enumerate(runs):
        one = jax.tree.map(lambda x, i=i: x[i], (batch.fields, batch.lanes, batch.keys,
                                                 batch.noise))
        rgb, mask = fn(built.mx, *one, r.perception.conditions(),
                       np.float32(r.perception.threshold), variables)
        out.append((np.asarray(rgb), np.asarray(mask)))
    return out


def first_poses(built: Any, batch: Any, n: int) -> np.ndarray:
    """float32 [n, 2]: (signed lateral offset [m], heading error [rad]; + left of the lane's
    centre line, `rollout.metrics`) at the reset pose of the first n episodes of `batch` (a
    batch of `built`), the pose their `first_frames` are seen from."""
    fn = _pose_fn(built.episode.sim)
    out = []
    for i in range(n):
        one = jax.tree.map(lambda x, i=i: x[i], (batch.fields, batch.lanes, batch.keys,
                                                 batch.noise))
        out.append(np.asarray(fn(built.mx, *one)))
    return np.stack(out).astype(np.float32)


def _reset(mx, field, lane, key, noise, scfg):
    """One world's model and reset state, with the reset's key as `rollout.episode` splits it
    (reset, policy)."""
    m = sim.world_model(mx, field, lane, scfg)
    k_reset, _ = jax.random.split(key)
    return sim.reset(m, field, lane, k_reset, scfg, noise)


@functools.lru_cache(maxsize=4)
def _pose_fn(scfg):
    """jit: one world's (lateral offset, heading error) at its reset pose."""

    def offsets(mx, field, lane, key, noise):
        p = sim.pose(_reset(mx, field, lane, key, noise, scfg))[None]
        ln = field_lanes.lane(field, lane)
        return jnp.stack([rollout_metrics.lateral_offset(p, ln)[0],
                          rollout_metrics.heading_error(p, ln)[0]])

    return jax.jit(offsets)


@functools.lru_cache(maxsize=4)
def _frame_fn(shape, intr, rcfg, scfg, segmenter):
    """jit: one world's first camera frame and mask (reset → camera → render → segment)."""

    def frame(mx, field, lane, key, noise, cond, threshold, variables):
        s0 = _reset(mx, field, lane, key, noise, scfg)
        cam_pos, cam_rot = sim.camera_pose(s0)
        f = render.render(field, shape, cam_pos, cam_rot, intr, cond, None, rcfg)
        if segmenter is None:
            return f.rgb, f.mask
        return f.rgb, seg_model.predict_mask(segmenter, variables, f.rgb[None], threshold)[0]

    return jax.jit(frame)
