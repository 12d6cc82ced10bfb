"""Host-side exports of ONE generated field, with the robot at the start of a lane: MJCF
(MuJoCo and its viewer, `field.mjcf`), Gazebo Sim and Gazebo Classic 11 worlds (`field.sdf`,
`field.gzrobot`) and the ground truth as CSV. CLI: `python -m mjxrow.worlds` (mjxrow/worlds/cli.py).

Files written into an export folder for a world `<name>`:

    <name>.xml, <name>_terrain.bin     MJCF: field + robot (camera `front`) + overview camera `eye`
    <name>_plants.csv, <name>_lanes.csv  ground truth; lanes with their spawn poses
    <name>_lanes_polyline.csv            each lane's centre line as points
    <name>_weeds.csv                     the weeds (a header only when there are none)
    <name>.sdf, models/<name>_field/, models/<name>_robot/                     (gazebo "sim")
    <name>_classic.world, models/<name>_field_classic/, models/<name>_robot_classic/  ("classic")

Every position is in world coordinates (metres, z up); on a field with curved rows
(`mjxrow.field.lanes`) the rows and lanes follow curves, and the field coordinates (s along
the rows, u across them) equal x and y only on straight rows. The CSVs, one row per:

- plants: active plant; `row` (0..n-1 by u), `index` (slot along the row), `x, y, z` (base
  centre on the terrain), `kind` (crop), `length, width, height` [m], `yaw` (turn of the
  plant's leaves), `heading` (direction of the row at the plant) [rad].
- lanes: lane between consecutive active rows; `lane` (i: between rows i and i+1), `y` (u of
  its centre line: its y on straight rows), `x_start, x_end, z_start, z_end` (world x and
  terrain height of the centre line at the rows' first and last plant slot; the end is the
  goal), `width` (row to row, across the rows) [m], `default` (1 for `field.robot_lane`),
  the robot's start `spawn_x, spawn_y, spawn_z` [m], `spawn_roll, spawn_pitch, spawn_yaw`
  [rad] (with a robot), then `y_start, y_end` (world y of the two ends), `s_start, s_end`
  (their s) [m] and `heading_start, heading_end` (the centre line's direction there) [rad].
- lanes_polyline: point of a lane's centre line, in order along it; `lane` (as in the lanes
  CSV), `point` (0, 1, ... from the start to the end), `s` [m], `x, y, z` (on the terrain)
  [m], `heading` [rad]. Points lie at most `POLYLINE_STEP` apart along s (closer on short
  sinusoids: 32 per wavelength), the first and last at the lane's ends.
- weeds: active weed; `weed` (its slot, the `i` of the MJCF / SDF names `weed_{i}_k{k}`),
  `x, y, z` (base centre on the terrain), `diameter, height` [m], `yaw` [rad].
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pandas as pd

from mjxrow import field as mjxrow_field
from mjxrow.field import lanes as field_lanes
from mjxrow.worlds import scene, sdf
from mjxrow.worlds.mjcf import lane_camera, snapshot, to_mjcf  # noqa: F401  (public names)
from mjxrow.worlds.scene import Robot, Start  # noqa: F401
from mjxrow.worlds.sdf import SDF_COLLISIONS, heightmap  # noqa: F401

GAZEBO = ("sim", "classic", "both", "none")
POLYLINE_STEP = 0.25  # m, the largest step along s between two points of a lane's polyline
TABLES = ("plants", "lanes", "lanes_polyline", "weeds")  # the CSVs, `<name>_<table>.csv`


def plants_table(field: mjxrow_field.Field, shape: mjxrow_field.FieldShape) -> pd.DataFrame:
    """Active plants (module doc): row, index, x, y, z, kind, length, width, height [m], yaw,
    heading [rad]."""
    f = scene.host(field)
    order, new_row = scene.active_rows(f)
    r, p = np.nonzero(f.plant_active[order])
    r = order[r]
    pos, size = f.plant_pos[r, p], f.plant_size[r, p]
    return pd.DataFrame({"row": new_row[r], "index": p, "x": pos[:, 0], "y": pos[:, 1],
                         "z": pos[:, 2], "kind": shape.crop, "length": size[:, 0],
                         "width": size[:, 1], "height": size[:, 2], "yaw": f.plant_yaw[r, p],
                         "heading": f.plant_heading[r, p]})


def _on_field(f: mjxrow_field.Field, s: np.ndarray, u: np.ndarray) -> dict[str, np.ndarray]:
    """World x, y [m], terrain height z [m] and the row direction `heading` [rad] at the field
    points (s, u) (arrays of one shape)."""
    bend = field_lanes.field_bend(f)
    x, y = (np.asarray(v) for v in field_lanes.to_world(bend, s, u))
    z = np.asarray(mjxrow_field.terrain_height(f.terrain, f.terrain_size, x, y))
    return {"x": x, "y": y, "z": z, "heading": np.asarray(field_lanes.heading(bend, s, u))}


def _lane_u(f: mjxrow_field.Field) -> tuple[np.ndarray, np.ndarray]:
    """(u of each lane's centre line [n-1], the active rows' u [n]), lanes by u."""
    order, _ = scene.active_rows(f)
    u = f.row_y[order]
    return 0.5 * (u[1:] + u[:-1]), u


def lanes_table(field: mjxrow_field.Field, shape: mjxrow_field.FieldShape | None = None,
                robot: scene.Robot | None = None, start: scene.Start | None = None) -> pd.DataFrame:
    """Each lane between consecutive active rows (module doc). With `shape` and `robot`, also
    the robot's start in each lane (`scene.start_poses`: the chassis origin resting on the
    terrain, `robot.sim.path_length` before the row end): spawn_x, spawn_y, spawn_z [m],
    spawn_roll, spawn_pitch, spawn_yaw [rad] (Gazebo's pose; `start` replaces its lane's row,
    e.g. a sweep episode's noisy start)."""
    f = scene.host(field)
    order, _ = scene.active_rows(f)
    u, rows = _lane_u(f)
    ends = [_on_field(f, np.full_like(u, s), u) for s in f.row_x]
    default = (order[:-1] == int(mjxrow_field.robot_lane(f))).astype(int)
    out = pd.DataFrame({"lane": np.arange(len(u)), "y": u, "x_start": ends[0]["x"],
                        "x_end": ends[1]["x"], "z_start": ends[0]["z"], "z_end": ends[1]["z"],
                        "width": np.diff(rows), "default": default})
    if shape is not None and robot is not None:
        poses = np.array([scene.Start(i, q).xyz_rpy
                          for i, q in enumerate(scene.start_poses(f, shape, robot))])
        if start is not None:
            poses[start.lane] = start.xyz_rpy
        for i, k in enumerate(("x", "y", "z", "roll", "pitch", "yaw")):
            out[f"spawn_{k}"] = poses[:, i]
    out["y_start"], out["y_end"] = ends[0]["y"], ends[1]["y"]
    out["s_start"], out["s_end"] = (np.full_like(u, s) for s in f.row_x)
    out["heading_start"], out["heading_end"] = ends[0]["heading"], ends[1]["heading"]
    return out


def polyline_points(field: mjxrow_field.Field) -> np.ndarray:
    """float64 [N]: the s of every lane's polyline points from the rows' first plant slot to
    their last, at most POLYLINE_STEP apart (a 32nd of the wavelength on rows that follow a
    sinusoid, when that is shorter)."""
    f = scene.host(field)
    bend = field_lanes.field_bend(f)
    step = POLYLINE_STEP
    if float(bend.amplitude) > 0:
        step = min(step, float(bend.wavelength) / 32)
    s0, s1 = (float(v) for v in f.row_x)
    return np.linspace(s0, s1, max(int(np.ceil((s1 - s0) / step - 1e-9)) + 1, 2))


def lanes_polyline_table(field: mjxrow_field.Field) -> pd.DataFrame:
    """Each lane's centre line as points (module doc): lane, point, s, x, y, z [m], heading
    [rad]; lanes as in `lanes_table`, points in order along s (`polyline_points`)."""
    f = scene.host(field)
    u, _ = _lane_u(f)
    s = polyline_points(f)
    ss, uu = np.meshgrid(s, u)  # [lanes, points]
    at = _on_field(f, ss.astype(np.float32), uu)
    lane, point = np.meshgrid(np.arange(len(u)), np.arange(len(s)), indexing="ij")
    return pd.DataFrame({"lane": lane.ravel(), "point": point.ravel(), "s": ss.ravel(),
                         **{k: at[k].ravel() for k in ("x", "y", "z", "heading")}})


def weeds_table(field: mjxrow_field.Field) -> pd.DataFrame:
    """Active weeds (module doc): weed, x, y, z, diameter, height [m], yaw [rad]."""
    f = scene.host(field)
    i = np.flatnonzero(f.weed_active)
    pos = f.weed_pos[i].reshape(-1, 3)
    return pd.DataFrame({"weed": i, "x": pos[:, 0], "y": pos[:, 1], "z": pos[:, 2],
                         "diameter": f.weed_size[i, 0], "height": f.weed_size[i, 1],
                         "yaw": f.weed_yaw[i]})


def write_tables(field: mjxrow_field.Field, shape: mjxrow_field.FieldShape, out_dir: str | Path,
                 name: str, robot: scene.Robot | None = None,
                 start: scene.Start | None = None) -> dict[str, Path]:
    """Write the CSVs (module doc; the lanes' spawn columns only with `robot`) into `out_dir`
    as `<name>_<table>.csv`, 0.1 mm / 0.1 mrad decimals. Returns {table: path} (TABLES)."""
    tables = {"plants": plants_table(field, shape),
              "lanes": lanes_table(field, shape, robot, start),
              "lanes_polyline": lanes_polyline_table(field), "weeds": weeds_table(field)}
    paths = {}
    Path(out_dir).mkdir(parents=True, exist_ok=True)
    for key, table in tables.items():
        paths[key] = Path(out_dir) / f"{name}_{key}.csv"
        table.to_csv(paths[key], index=False, float_format="%.4f")
    return paths


def flavours(gazebo: str) -> tuple[str, ...]:
    """Gazebo flavours of a `--gazebo` choice (GAZEBO)."""
    if gazebo not in GAZEBO:
        raise ValueError(f"gazebo: {gazebo!r} is not one of {GAZEBO}")
    return {"both": sdf.FLAVOURS, "none": ()}.get(gazebo, (gazebo,))


def export(
    field: mjxrow_field.Field,
    shape: mjxrow_field.FieldShape,
    out_dir: str | Path,
    name: str,
    robot: scene.Robot | None = None,
    start: scene.Start | None = None,
    gazebo: str = "sim",
    sdf_collisions: str = "footprint",
) -> dict[str, Path]:
    """Write one world's files (module doc) into `out_dir`: the MJCF with the robot at `start`
    (default robot: `scene.robot_for`; default start: `scene.default_start`, the field's
    default lane), the CSVs and the Gazebo
    flavours of `gazebo` ("sim", "classic", "both", "none"). Returns {what: path} with keys
    xml, the CSVs' (TABLES: plants, lanes, lanes_polyline, weeds), sdf (sim) / world
    (classic) and every other file's relative path."""
    robot = robot or scene.robot_for(field)
    gz = flavours(gazebo)
    start = start or scene.default_start(field, shape, robot)
    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    xml, assets = to_mjcf(field, shape, name, robot, start)
    files = {f"{name}.xml": xml.encode(), **assets}
    for flavour in gz:
        files.update(sdf.gazebo_files(field, shape, name, flavour, robot, start, sdf_collisions))
    paths: dict[str, Path] = {}
    for rel, data in files.items():
        p = out / rel
        p.parent.mkdir(parents=True, exist_ok=True)
        p.write_bytes(data)
        paths[rel] = p
    paths["xml"] = out / f"{name}.xml"
    for flavour in gz:
        paths["world" if flavour == "classic" else "sdf"] = out / sdf.names(name, flavour)["world"]
    paths.update(write_tables(field, shape, out, name, robot, start))
    return paths
