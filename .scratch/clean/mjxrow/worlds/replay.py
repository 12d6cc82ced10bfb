"""The field, lane and start pose of ONE episode, for export: an episode of `python -m
mjxrow.episode` or of a finished sweep run, replayed in Gazebo or the MuJoCo viewer.

An episode is what `rollout.build` makes of (run config, episode index): the keys
`episode_keys(run.seed, [episode])` split by `split_keys` into the field's key and the
rollout's key, the field from `generate_fn` on the run's static shape, the lane
`field.robot_lane`, and the start `sim.reset` with `k_reset, _ = split(rollout key)`
(`rollout.episode.episode`) and the run's start-pose noise. `resolve_run` makes the run config
and shape of a preset with `--set` items, `episode_world` repeats exactly that; `from_run`
finds a sweep cell's run config and its group's shape (`sweep.groups.plan`); `from_search` a
search failure's candidate (its run config from the search's config.yaml and the candidate's
normalised coordinates, as the search made it) and the search's field shape.
"""

from __future__ import annotations

import dataclasses
import json
import sys
from pathlib import Path

import jax
import numpy as np
import pandas as pd

from mjxrow import field as mjxrow_field
from mjxrow.rollout import build as rollout_build
from mjxrow.rollout.config import RunConfig
from mjxrow.search import box as search_box
from mjxrow.search import config as search_config
from mjxrow.sweep import config as sweep_config
from mjxrow.sweep import grid as sweep_grid
from mjxrow.sweep import groups as sweep_groups
from mjxrow.sweep.yamlfile import read_yaml
from mjxrow.worlds import scene


@dataclasses.dataclass(frozen=True)
class Episode:
    """One episode, ready to export: `field` (numpy, one field), its static `shape`, the robot
    as the run drives it, and the `start` (lane index across the rows and the exact start qpos)."""

    field: mjxrow_field.Field
    shape: mjxrow_field.FieldShape
    robot: scene.Robot
    start: scene.Start
    name: str  # e.g. "zucchini" or "zucchini_c3_e5"


def run_robot(run: RunConfig) -> scene.Robot:
    """The robot of a run config: its RobotConfig (camera fov from `camera.fovy`), the
    episode's SimConfig and the camera's image size."""
    return scene.Robot(run.robot_config(), run.episode.sim, (int(run.camera.width),
                                                             int(run.camera.height)))


def resolve_run(preset: str, seed: int = 0, sets: list[str] | tuple[str, ...] = ()):
    """(RunConfig, FieldShape) of one preset with `--set` items (the sweep's grammar and
    checks; the controller defaults to `oracle` with ground-truth perception, which need no
    checkpoint). ConfigError (a ValueError) naming the key."""
    base = [f"preset={preset}", f"seed={seed}", "controller.name=oracle",
            "perception.source=ground_truth"]
    cfg = sweep_config.from_dict({}, ".", [*base, *sets])
    if cfg.axis_order:
        raise sweep_config.ConfigError(
            f"{cfg.axis_order[0]}: one world needs one value, got a list"
        )
    run = sweep_grid.expand(cfg)[0].cfg
    return run, rollout_build.fit_shape([run])


def episode_world(run: RunConfig, shape: mjxrow_field.FieldShape, episode: int = 0,
                  lane: int | None = None, name: str | None = None) -> Episode:
    """Episode `episode` of `run` on the static `shape` (module doc). With `lane` (index of
    `lanes_table`, 0..n-1 by u), the robot starts in that lane instead, without pose noise."""
    if episode < 0:
        raise ValueError(f"episode: must be non-negative, got {episode}")
    fkeys, rkeys = rollout_build.split_keys(rollout_build.episode_keys(run.seed, [episode]))
    params = rollout_build.stack([run.field_params()])
    sim_cfg = run.episode.sim  # where the start zone lies and which lane: as rollout.build
    fld = scene.host(jax.tree.map(lambda x: x[0], rollout_build.generate_fn()(params, shape, fkeys,
                                                                              sim_cfg.path_length)))
    robot = run_robot(run)
    if lane is not None:
        start = scene.default_start(fld, shape, robot, lane)
    else:
        field_lane = int(mjxrow_field.robot_lane(fld, mode=sim_cfg.lane))
        k_reset, _ = jax.random.split(rkeys[0])
        qpos = scene.start_poses(fld, shape, robot, [field_lane], k_reset[None],
                                 run.episode.noise)[0]
        table_lane = int(np.flatnonzero(scene.field_lanes(fld) == field_lane)[0])
        start = scene.Start(table_lane, qpos)
    return Episode(fld, shape, robot, start, name or run.preset)


def from_run(run_dir: str | Path, cell: int, episode: int) -> Episode:
    """Episode `episode` of cell `cell` of the sweep run in `run_dir`, exactly as the sweep
    made it. The cell is found by its hash in `results.csv` when the run wrote one (cell numbers
    follow `config.yaml`'s axes), else by its number. ValueError naming the offending flag
    (--from-run, --cell, --episode) when something is missing or does not match."""

    run_dir = Path(run_dir)
    if not (run_dir / "config.yaml").is_file():
        raise ValueError(f"--from-run: no config.yaml in {run_dir}; is it a sweep's output "
                         "folder?")
    try:  # strictly, as a sweep YAML: an emptied file is no run (not the default sweep)
        cfg = sweep_config.from_dict(read_yaml(run_dir / "config.yaml"), run_dir)
    except ValueError as e:  # read_yaml's messages start with the file, from_dict's with a key
        where = "" if str(e).startswith(str(run_dir / "config.yaml")) else \
            f"{run_dir / 'config.yaml'}: "
        raise ValueError(f"--from-run: {where}{e}") from None
    if not 0 <= episode < cfg.seeds:
        raise ValueError(f"--episode: {episode} is not an episode of this run "
                         f"(0..{cfg.seeds - 1})")
    row = None
    if (run_dir / "results.csv").exists():
        res = _results(run_dir / "results.csv")
        hit = res[(res["cell"] == cell) & (res["episode"] == episode)]
        row = hit.iloc[0] if len(hit) else None
    groups = sweep_groups.plan(cfg)
    found = [(g, c) for g in groups for c, h in zip(g.cells, g.hashes, strict=True)
             if row is not None and h == row["cell_hash"]]
    if not found:
        if row is not None:
            print(f"warning: cell {cell}'s hash {row['cell_hash']} is not in config.yaml's grid "
                  f"(a retrained checkpoint?); taking cell number {cell}", file=sys.stderr)
        found = [(g, c) for g in groups for c in g.cells if c.index == cell]
    if not found:
        n = sum(len(g.cells) for g in groups)
        raise ValueError(f"--cell: {cell} is not a cell of this run (0..{n - 1})")
    group, c = found[0]
    ep = episode_world(c.cfg, group.shape, episode, name=f"{c.cfg.preset}_c{cell}_e{episode}")
    lane = int(scene.field_lanes(ep.field)[ep.start.lane])
    if row is not None and "lane" in row and row["lane"] != lane:
        raise ValueError(f"--episode: results.csv says episode {episode} of cell {cell} drove "
                         f"lane {int(row['lane'])}, the regenerated field's lane is {lane}: the "
                         "field generator changed since this run")
    return ep


RESULTS_COLUMNS = ("cell", "episode", "cell_hash")  # what from_run reads of results.csv


def _results(path: Path) -> pd.DataFrame:
    """A sweep's results.csv with the columns `from_run` reads, each of its type (cell, episode
    and lane integers, lane optional); ValueError naming --from-run, the file and the column."""
    try:
        res = pd.read_csv(path)
    except (OSError, ValueError, UnicodeDecodeError) as e:  # pandas' parse errors: ValueErrors
        raise ValueError(f"--from-run: {path} cannot be read ("
                         f"{str(e).splitlines()[0] if str(e) else type(e).__name__})") from None
    for col in RESULTS_COLUMNS + (("lane",) if "lane" in res else ()):
        if col not in res:
            raise ValueError(f"--from-run: {path} has no column {col!r}; is it a sweep's "
                             "results.csv?")
        if col != "cell_hash" and not (pd.api.types.is_integer_dtype(res[col])
                                       and (res[col] >= 0).all()):
            raise ValueError(f"--from-run: {path}: column {col!r} holds values that are not "
                             "non-negative integers (empty, NaN or text)")
    return res


def from_search(run_dir: str | Path, rank: int) -> Episode:
    """The episode in which the failure ranked `rank` (1 = worst, failures.csv) of the search
    in `run_dir` failed first, exactly as the search ran it: the candidate's run config from
    config.yaml and its normalised coordinates (`search.box.run_of`), the episode index
    `first_failing`, the search's field shape. ValueError naming the offending flag
    (--from-search, --rank) when something is missing or does not match."""
    run_dir = Path(run_dir)
    try:
        raw = read_yaml(run_dir / "config.yaml")  # strictly: no alias bomb, no empty file
        failures = pd.read_csv(run_dir / "failures.csv")
        state = json.loads((run_dir / "state.json").read_text())
        if not isinstance(state, dict):
            raise ValueError("state.json is not a mapping")
    except (OSError, ValueError) as e:
        raise ValueError(f"--from-search: cannot read the search in {run_dir} "
                         f"({getattr(e, 'strerror', None) or e}); is it a search's output "
                         "folder?") from None
    try:
        cfg = search_config.from_dict(raw, run_dir)
    except ValueError as e:
        raise ValueError(f"--from-search: {run_dir / 'config.yaml'}: {e}") from None
    if state.get("shape") != repr(cfg.shape):
        raise ValueError(f"--from-search: the field shape of {run_dir} is not the one its "
                         "config gives today (the field generator or limits changed)")
    hit = failures[failures["rank"] == rank] if "rank" in failures else failures.iloc[:0]
    if hit.empty:
        raise ValueError(f"--rank: {rank} is not a failure of this search "
                         + (f"(1..{len(failures)})" if len(failures) else "(it found none)"))
    row = hit.iloc[0]
    u = row[[f"u_{j}" for j in range(len(cfg.box))]].to_numpy(float)
    run = search_box.run_of(cfg.scenario, cfg.box, u)
    episode = int(row["first_failing"])
    ep = episode_world(run, cfg.shape, episode, name=f"{run.preset}_search_r{rank}")
    lane = int(scene.field_lanes(ep.field)[ep.start.lane])
    if "lane" in row and int(row["lane"]) != lane:
        raise ValueError(f"--rank: failures.csv says failure {rank} drove lane "
                         f"{int(row['lane'])}, the regenerated field's lane is {lane}: the "
                         "field generator changed since this search")
    return ep
