"""The field, lane and start pose of ONE episode of a finished sweep run, for export: a failure
found in a sweep replayed in Gazebo or the MuJoCo viewer.

`episode_field` is the one place that reads the sweep's conventions (mjxrow.sweep): the run's
`config.yaml`, its `results.csv`, `sweep.run.plan` (groups and their fitted static shape),
`sweep.run.episode_keys` (then `jax.random.split` → [field key, rollout key]),
`sweep.run.static_configs` / `start_noise`, and the rollout's `k_reset, k_policy =
jax.random.split(rollout key)` (mjxrow.rollout.episode).
"""

from __future__ import annotations

import dataclasses
import sys
from pathlib import Path

import jax
import numpy as np
import pandas as pd
import yaml

from mjxrow import field as F
from mjxrow.field import scene as S


@dataclasses.dataclass(frozen=True)
class Episode:
    """One sweep episode, ready to export: `field` (numpy, one field), its static `shape`, the
    robot as the run ran it, and the `start` (lane index by y and the exact start qpos)."""

    field: F.Field
    shape: F.FieldShape
    robot: S.Robot
    start: S.Start
    name: str  # e.g. "zucchini_c3_e5"


def episode_field(run_dir: str | Path, cell: int, episode: int) -> Episode:
    """Regenerate the field of episode `episode` of cell `cell` of the sweep run in `run_dir`
    exactly as the sweep made it, with the lane the robot drove and its start pose (pose noise
    included). The cell is found by its hash in `results.csv` when the run wrote one (cell
    numbers in `config.yaml` follow its key order), else by its index. ValueError with the
    offending key (run_dir, cell, episode) when something is missing."""
    from mjxrow.sweep import config as C
    from mjxrow.sweep import run as SW

    run_dir = Path(run_dir)
    try:
        raw = yaml.safe_load((run_dir / "config.yaml").read_text())
    except OSError as e:
        raise ValueError(f"run_dir: cannot read {run_dir / 'config.yaml'} ({e.strerror}); is it "
                         "a sweep's output folder?") from None
    cfg = C.from_dict(raw, run_dir)
    if not 0 <= episode < cfg.seeds:
        raise ValueError(f"episode: {episode} is not an episode of this run (0..{cfg.seeds - 1})")
    row = None
    if (run_dir / "results.csv").exists():
        res = pd.read_csv(run_dir / "results.csv")
        hit = res[(res["cell"] == cell) & (res["episode"] == episode)]
        row = hit.iloc[0] if len(hit) else None
    groups = SW.plan(cfg)
    found = [(g, c) for g in groups for c, h in zip(g.cells, g.hashes, strict=True)
             if (row is not None and h == row["cell_hash"])]
    if not found:
        if row is not None:
            print(f"warning: cell {cell}'s hash {row['cell_hash']} is not in config.yaml's grid "
                  "(a retrained checkpoint?); taking cell number " f"{cell}", file=sys.stderr)
        found = [(g, c) for g in groups for c in g.cells if c.index == cell]
    if not found:
        n = sum(len(g.cells) for g in groups)
        raise ValueError(f"cell: {cell} is not a cell of this run (0..{n - 1})")
    group, c = found[0]
    robot_cfg, ep_cfg, intr = SW.static_configs(c.cfg, group.shape)
    robot = S.Robot(robot_cfg, ep_cfg.sim, (int(intr.width), int(intr.height)))
    params = F.make_params(c.cfg.preset, **C.field_values(c.cfg))
    k_field, k_roll = jax.random.split(SW.episode_keys(cfg.seed, [episode])[0])
    fld = S.host(jax.jit(F.generate, static_argnums=1)(params, group.shape, k_field))
    lane = int(F.robot_lane(fld))
    if row is not None and "lane" in row and int(row["lane"]) != lane:
        raise ValueError(f"lane: results.csv says episode {episode} of cell {cell} drove lane "
                         f"{int(row['lane'])}, the regenerated field's lane is {lane}: the field "
                         "generator changed since this run")
    k_reset, _ = jax.random.split(k_roll)
    qpos = S.start_poses(fld, group.shape, robot, [lane], k_reset[None],
                         SW.start_noise(c.cfg))[0]
    table_lane = int(np.flatnonzero(S.field_lanes(fld) == lane)[0])
    return Episode(fld, group.shape, robot, S.Start(table_lane, qpos),
                   f"{c.cfg.preset}_c{cell}_e{episode}")
