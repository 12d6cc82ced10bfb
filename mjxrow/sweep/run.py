"""`python -m mjxrow.sweep SWEEP.yaml [--out DIR] [--smoke] [--set key=value ...]`.

YAML → validated config (config.py) → grid of cells → groups of cells sharing every static
value (one compile each) → batches of episodes → per-episode metrics → `results.csv`,
`summary.csv`, one PNG per metric, `report.md`.

Resumable: each finished cell is written at once to `DIR/cells/<hash>.csv` (temp file +
`os.replace`), `hash` covering the cell's resolved parameters and its group's static field
shape; a re-run skips the cells whose file exists. Ctrl-C and SIGTERM stop between writes, so
no finished cell is lost and no file is left half-written.

The evaluation of one group is one call with a narrow interface (tests inject a fake one):

    evaluate(group: Group, cfg: SweepConfig, on_batch_done: Callable[[DataFrame], None])
        -> DataFrame   # one row per episode of group.episodes: cell, episode, metrics...
"""

from __future__ import annotations

import argparse
import contextlib
import dataclasses
import datetime
import functools
import math
import os
import signal
import sys
import threading
import time
from collections.abc import Callable
from pathlib import Path
from typing import Any

if "jax" not in sys.modules and "xla_force_host_platform_device_count" not in os.environ.get(
        "XLA_FLAGS", ""):
    # one XLA CPU device per core: on a CPU-only machine the batch is sharded over the cores
    # (XLA runs most of one device's program on one thread); accelerators are unaffected
    os.environ["XLA_FLAGS"] = (os.environ.get("XLA_FLAGS", "") +
                               f" --xla_force_host_platform_device_count={os.cpu_count() or 1}"
                               ).strip()

import jax  # noqa: E402
import jax.numpy as jnp
import numpy as np
import pandas as pd
from tqdm.auto import tqdm

from mjxrow import field as F
from mjxrow.sweep import config as C
from mjxrow.sweep import report as plots

Evaluator = Callable[["Group", C.SweepConfig, Callable[[pd.DataFrame], None]], pd.DataFrame]


@dataclasses.dataclass(frozen=True)
class Group:
    """Cells that share every static value: one static field shape, one compile.

    `episodes` lists the (cell index, episode index) pairs still to run, cell by cell."""

    index: int
    shape: F.FieldShape
    cells: tuple[C.Cell, ...]
    hashes: tuple[str, ...]
    episodes: tuple[tuple[int, int], ...]

    @property
    def cfg(self) -> C.SweepConfig:
        """A config with this group's static values (those of its first cell)."""
        return self.cells[0].cfg

    def cell(self, index: int) -> C.Cell:
        return next(c for c in self.cells if c.index == index)


def group_shape(cells: list[C.Cell]) -> F.FieldShape:
    """The static FieldShape that holds every cell's field (rounded up by field.fit_shape)."""
    params = F.stack_params([F.make_params(c.cfg.preset, **C.field_values(c.cfg))
                             for c in cells])
    return F.fit_shape(params, cells[0].cfg.preset)


def plan(cfg: C.SweepConfig, done: set[str] = frozenset()) -> list[Group]:
    """Group the cells by static values, fit one field shape per group, hash every cell, and
    list the episodes of the cells whose hash is not in `done`."""
    by_key: dict[tuple, list[C.Cell]] = {}
    for cell in C.expand(cfg):
        by_key.setdefault(C.static_key(cell.cfg), []).append(cell)
    groups = []
    for gi, cells in enumerate(by_key.values()):
        shape = group_shape(cells)
        hashes = tuple(C.cell_hash(c, shape) for c in cells)
        eps = tuple((c.index, e) for c, h in zip(cells, hashes, strict=True) if h not in done
                    for e in range(cfg.seeds))
        groups.append(Group(gi, shape, tuple(cells), hashes, eps))
    return groups


def episode_keys(seed: int, episodes) -> jax.Array:
    """PRNG keys [N] of episodes `episodes` (indices within a cell): fold_in(key(seed), i).
    The same for every cell (common random numbers) and independent of the batching."""
    base = jax.random.key(seed)
    return jax.vmap(lambda i: jax.random.fold_in(base, i))(jnp.asarray(episodes, jnp.uint32))


# ---------------------------------------------------------------------------------------------
# Files


atomic_write_text = plots.atomic_write_text


def atomic_write_csv(path: Path, df: pd.DataFrame) -> None:
    atomic_write_text(path, df.to_csv(index=False))


def finished_cells(cells_dir: Path) -> set[str]:
    """Hashes of the finished cells; removes temp files a killed run may have left."""
    if not cells_dir.is_dir():
        return set()
    for tmp in cells_dir.glob(".*.tmp"):
        tmp.unlink(missing_ok=True)
    return {p.stem for p in cells_dir.glob("*.csv")}


def cell_rows(group: Group, cell_index: int, rows: pd.DataFrame) -> pd.DataFrame:
    """Episode rows of one cell with identity columns and every resolved parameter."""
    cell = group.cell(cell_index)
    rows = rows.sort_values("episode").reset_index(drop=True)
    ident = pd.DataFrame({"cell": cell.index, "episode": rows["episode"],
                          "cell_hash": group.hashes[group.cells.index(cell)],
                          "group": group.index})
    params = pd.DataFrame([C.resolved(cell.cfg)] * len(rows))
    metrics = rows.drop(columns=[c for c in ("cell", "episode") if c in rows])
    return pd.concat([ident, params, metrics], axis=1)


# ---------------------------------------------------------------------------------------------
# Summary


def write_outputs(cfg: C.SweepConfig, groups: list[Group], out: Path, info: dict[str, Any],
                  figures: bool = True) -> dict[str, Path]:
    """results.csv rebuilt from this sweep's cell files, then summary.csv, config.yaml and
    (with `figures`) the PNGs and report.md (plots.write_outputs)."""
    frames = []
    for g in groups:
        for cell, h in zip(g.cells, g.hashes, strict=True):
            p = out / "cells" / f"{h}.csv"
            if p.exists():
                frames.append(pd.read_csv(p).assign(cell=cell.index, group=g.index))
    if not frames:
        return {}
    results = pd.concat(frames, ignore_index=True).sort_values(["cell", "episode"])
    atomic_write_csv(out / "results.csv", results)
    return {"results": out / "results.csv", **plots.write_outputs(results, cfg, out, info,
                                                                   figures)}


# ---------------------------------------------------------------------------------------------
# Evaluation of one group: fields → rollout → metrics


@functools.lru_cache(maxsize=8)
def _generate_fn():
    return jax.jit(jax.vmap(F.generate, in_axes=(0, None, 0)), static_argnums=1)


def static_configs(cfg: C.SweepConfig, shape: F.FieldShape):
    """(RobotConfig, EpisodeConfig, Intrinsics) of a group's static values."""
    from mjxrow import render
    from mjxrow.physics import robot as R
    from mjxrow.physics import sim
    from mjxrow.rollout import episode as E

    ep, cam = cfg.episode, cfg.camera
    robot_cfg = R.RobotConfig(v_max=ep.v_max, omega_max=ep.omega_max,
                              cam_height=cam.mount_height, cam_forward=cam.mount_forward,
                              cam_pitch_deg=cam.pitch, cam_fovy=cam.fovy)
    sim_cfg = sim.SimConfig(control_hz=ep.control_hz, path_length=ep.path_length)
    ep_cfg = E.EpisodeConfig(crop=shape.crop, n_steps=math.ceil(ep.max_time * ep.control_hz - 1e-9),
                             goal_radius=ep.goal_tolerance, sim=sim_cfg)
    intr = render.Intrinsics(width=cam.width, height=cam.height, fovy=cam.fovy)
    return robot_cfg, ep_cfg, intr


def start_noise(cfg: C.SweepConfig):
    """The start-pose noise of one cell (sim.PoseNoise of jax scalars: traced, per episode)."""
    from mjxrow.physics import sim

    ep = cfg.episode
    return sim.pose_noise(ep.start_offset_std, math.radians(ep.start_yaw_std))


def controller_params(cfg: C.SweepConfig):
    """The controller's params of one cell (jax scalars: traced, batched over episodes)."""
    from mjxrow import control as K

    c, ep = cfg.controller, cfg.episode
    if c.name == "oracle":
        return K.oracle_params(lookahead=c.lookahead, v_max=ep.v_max, omega_max=ep.omega_max)
    return K.seg_params("zeros" if c.name == "segzeros" else "min", c.variant,
                        v_max=c.v_gain, omega_gain=c.omega_gain, v_limit=ep.v_max,
                        omega_limit=ep.omega_max, min_run=c.min_run, end_frac=c.end_fraction,
                        ema_alpha=c.ema, depth_max=c.depth_cut, n_frames=c.n_frames,
                        smooth=c.smooth, on_end=c.on_end, heading_alpha=c.heading_alpha,
                        image_hw=(cfg.camera.height, cfg.camera.width))


def make_policy(cfg: C.SweepConfig, shape: F.FieldShape, intr):
    """(policy, params_of(cell_cfg)) for a group. The oracle's params are its gains; a mask
    controller runs in the perception loop of `closed_loop` (render → ground-truth mask, or
    the learned segmenter of `perception.checkpoint`), its params are
    `(PerceptionParams(condition, threshold, segmenter weights), controller gains)`: the
    weights are loaded once and the same object for every cell (shared by a batch, see
    `params_axes`), everything else per cell and traced."""
    from mjxrow import control as K
    from mjxrow.control import perception as closed_loop

    name = cfg.controller.name
    if name == "oracle":
        return K.as_policy("oracle"), controller_params
    policy, base = closed_loop.make(name, shape, intr, cfg.perception.source,
                                    C.checkpoint_path(cfg))

    def params_of(c: C.SweepConfig):
        return (closed_loop.perception_params(c.perception.condition, c.perception.threshold,
                                              base.variables), controller_params(c))

    return policy, params_of


def params_axes(cfg: C.SweepConfig):
    """vmap axes of a group's policy params (episode.rollout's params_axes): the oracle's all
    per episode; a mask controller's segmenter weights shared, the rest per episode."""
    from mjxrow.control import perception as closed_loop

    return 0 if cfg.controller.name == "oracle" else closed_loop.PARAMS_AXES


def _stack(trees):
    return jax.tree.map(lambda *xs: jnp.stack([jnp.asarray(x) for x in xs]), *trees)


def _put_params(params, axes, batched, replicated, placed: dict):
    """device_put of policy params: per-episode parts sharded on the batch, shared parts
    replicated, each shared object once (`placed`: id → its placed copy, kept by the caller)."""
    from mjxrow.rollout import episode as E

    treedef, leaves = E.canonical_axes(axes)
    out = []
    for a, x in zip(leaves, treedef.flatten_up_to(params), strict=True):
        if a is not None:
            out.append(jax.device_put(x, batched))
            continue
        if id(x) not in placed:
            placed[id(x)] = (x, jax.device_put(x, replicated))
        out.append(placed[id(x)][1])
    return treedef.unflatten(out)


def evaluate_group(group: Group, cfg: C.SweepConfig,
                   on_batch_done: Callable[[pd.DataFrame], None]) -> pd.DataFrame:
    """Run `group.episodes` in batches of `cfg.batch_size` (the last one padded, so one compile
    per group), sharded over all local devices, calling `on_batch_done(rows)` after each batch.
    Rows: cell, episode, lane and every metric of `metrics.summarise` (reason as its name)."""
    from mjxrow.physics import sim
    from mjxrow.rollout import episode as E
    from mjxrow.rollout import metrics as M

    shape, gcfg = group.shape, group.cfg
    robot_cfg, ep_cfg, intr = static_configs(gcfg, shape)
    _, mx = sim.make_model(shape, ep_cfg.sim, robot_cfg)
    policy, params_of = make_policy(gcfg, shape, intr)
    axes = params_axes(gcfg)
    devices = jax.devices()
    mesh = jax.sharding.Mesh(np.array(devices), ("batch",))
    batched = jax.sharding.NamedSharding(mesh, jax.sharding.PartitionSpec("batch"))
    replicated = jax.sharding.NamedSharding(mesh, jax.sharding.PartitionSpec())
    mx = jax.device_put(mx, replicated)
    n = len(devices)
    B = -(-min(cfg.batch_size, len(group.episodes)) // n) * n
    by_cell = {c.index: c.cfg for c in group.cells}
    fparams = {i: F.make_params(c.preset, **C.field_values(c)) for i, c in by_cell.items()}
    pparams = {i: params_of(c) for i, c in by_cell.items()}
    noise = {i: start_noise(c) for i, c in by_cell.items()}
    placed: dict[int, Any] = {}
    out = []
    for start in range(0, len(group.episodes), B):
        real = list(group.episodes[start:start + B])
        eps = real + [real[-1]] * (B - len(real))
        keys = jax.vmap(jax.random.split)(episode_keys(cfg.seed, [e for _, e in eps]))
        put = functools.partial(jax.device_put, device=batched)
        params = put(_stack([fparams[c] for c, _ in eps]))
        fields = _generate_fn()(params, shape, put(keys[:, 0]))
        lanes = jax.vmap(F.robot_lane)(fields)
        pol = _put_params(E.stack_params([pparams[c] for c, _ in eps], axes), axes, batched,
                          replicated, placed)
        log = E.rollout(mx, fields, lanes, put(keys[:, 1]), policy, pol, ep_cfg,
                        params_axes=axes, noise=put(_stack([noise[c] for c, _ in eps])))
        k = len(real)
        met = {name: np.asarray(v)[:k] for name, v in E.summarise(log, ep_cfg).items()}
        rows = pd.DataFrame({"cell": [c for c, _ in real], "episode": [e for _, e in real],
                             "lane": np.asarray(lanes)[:k],
                             **{k: (np.asarray(M.REASONS)[v] if k == "reason" else v)
                                for k, v in met.items() if np.ndim(v) == 1}})
        on_batch_done(rows)
        out.append(rows)
    return pd.concat(out, ignore_index=True)


# ---------------------------------------------------------------------------------------------
# Driver


class _Terminated(KeyboardInterrupt):
    pass


def _raise_interrupt(signum, frame):
    raise _Terminated(f"signal {signum}")


class _CellWriter:
    """on_batch_done of one group: collects episode rows per cell and writes each cell's file
    (atomically) as soon as all its episodes are in; advances the progress bar."""

    def __init__(self, group: Group, seeds: int, cells_dir: Path, bar):
        self.group, self.seeds, self.dir, self.bar = group, seeds, cells_dir, bar
        self.pending: dict[int, list[pd.DataFrame]] = {}
        self.times = [time.perf_counter()]
        self.episodes = 0

    def __call__(self, rows: pd.DataFrame) -> None:
        self.times.append(time.perf_counter())
        for ci, part in rows.groupby("cell", sort=False):
            parts = self.pending.setdefault(int(ci), [])
            parts.append(part)
            if sum(len(p) for p in parts) >= self.seeds:
                df = cell_rows(self.group, int(ci), pd.concat(self.pending.pop(int(ci))))
                atomic_write_csv(self.dir / f"{df['cell_hash'].iloc[0]}.csv", df)
        self.episodes += len(rows)
        self.bar.update(len(rows))
        self.bar.set_postfix_str(f"group {self.group.index}")

    def timing(self) -> str:
        dt = np.diff(self.times)
        if not dt.size:
            return "no batch finished"
        rest = f", then {np.median(dt[1:]):.1f} s per batch (median of {dt.size - 1})" \
            if dt.size > 1 else ""
        return (f"{self.times[-1] - self.times[0]:.1f} s for {self.episodes} episodes: first "
                f"batch {dt[0]:.1f} s including compilation{rest}")


@contextlib.contextmanager
def _ticking(bar, enabled: bool):
    """Refresh the bar every second, so elapsed time moves during long batches."""
    stop = threading.Event()

    def tick():
        while not stop.wait(1.0):
            bar.refresh()

    thread = threading.Thread(target=tick, daemon=True)
    if enabled:
        thread.start()
    try:
        yield
    finally:
        stop.set()
        if enabled:
            thread.join()


def run(cfg: C.SweepConfig, out: str | Path, evaluate: Evaluator | None = None,
        progress: bool = True, command: str = "", figures: bool = True) -> dict[str, Any]:
    """Run every unfinished cell of `cfg`, persisting each as it finishes, then write the
    outputs (without `figures`: no PNGs and no report). Returns {'groups', 'ran', 'skipped',
    'files'}. On Ctrl-C or SIGTERM the finished cells are kept, results.csv and summary.csv
    hold them, and KeyboardInterrupt propagates."""
    evaluate = evaluate or evaluate_group
    out = Path(out)
    (out / "cells").mkdir(parents=True, exist_ok=True)
    groups = plan(cfg, finished_cells(out / "cells"))
    n_cells = sum(len(g.cells) for g in groups)
    total, todo = n_cells * cfg.seeds, sum(len(g.episodes) for g in groups)
    skipped = (total - todo) // cfg.seeds
    info: dict[str, Any] = {"date": datetime.datetime.now().isoformat(timespec="seconds"),
                            "command": command or "(API call)", "device": _device(),
                            "cells": n_cells, "episodes": total, "groups": len(groups),
                            "cells skipped (already finished)": skipped}
    bar = tqdm(total=total, initial=total - todo, unit="ep", disable=not progress,
               desc=cfg.name, dynamic_ncols=True)
    old = signal.signal(signal.SIGTERM, _raise_interrupt) if _main_thread() else None
    ran, t0 = 0, time.perf_counter()
    try:
        with _ticking(bar, progress):
            for g in groups:
                if not g.episodes:
                    continue
                bar.set_postfix_str(f"group {g.index}: compiling")
                writer = _CellWriter(g, cfg.seeds, out / "cells", bar)
                try:
                    evaluate(g, cfg, writer)
                finally:
                    ran += writer.episodes
                    info[f"group {g.index} ({g.shape.crop}, {len(g.cells)} cells)"] = \
                        writer.timing()
    except KeyboardInterrupt:
        bar.close()
        write_outputs(cfg, groups, out, info, figures=False)
        kept = len(finished_cells(out / "cells") & {h for g in groups for h in g.hashes})
        print(f"interrupted: {kept} of {n_cells} cells finished and kept in {out}; run the "
              "same command again to resume", file=sys.stderr)
        raise
    finally:
        bar.close()
        if old is not None:
            signal.signal(signal.SIGTERM, old)
    info["wall time"] = f"{time.perf_counter() - t0:.1f} s for {ran} episodes"
    return {"groups": groups, "ran": ran, "skipped": skipped,
            "files": write_outputs(cfg, groups, out, info, figures)}


def _main_thread() -> bool:
    return threading.current_thread() is threading.main_thread()


def _device() -> str:
    devs = jax.devices()
    return f"{len(devs)} × {devs[0].device_kind}"


# ---------------------------------------------------------------------------------------------
# CLI


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(prog="python -m mjxrow.sweep", description=__doc__.split("\n")[2],
                                formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("config", help="sweep YAML file")
    p.add_argument("--out", help="output directory (default: the YAML's `out`)")
    p.add_argument("--smoke", action="store_true",
                   help="2 × 2 cells, 2 seeds, short episodes, tiny images: a quick check")
    p.add_argument("--set", action="append", default=[], metavar="KEY=VALUE",
                   help="override a dotted key, e.g. --set field.d_rr=[1.2,1.8] (repeatable)")
    p.add_argument("--no-progress", action="store_true", help="no progress bar")
    args = p.parse_args(argv)
    try:
        cfg = C.load(args.config, args.set, args.smoke)
    except C.ConfigError as e:
        print(f"error: {e}", file=sys.stderr)
        return 2
    out = Path(args.out or cfg.out)
    if args.smoke and not args.out:
        out = out.with_name(out.name + "_smoke")
    command = "python -m mjxrow.sweep " + " ".join(argv if argv is not None else sys.argv[1:])
    try:
        res = run(cfg, out, progress=not args.no_progress, command=command)
    except KeyboardInterrupt:
        return 130
    print(f"{res['ran']} episodes run, {res['skipped']} cells skipped; report: "
          f"{res['files'].get('report', out)}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
