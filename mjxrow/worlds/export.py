"""Host-side exports of ONE generated field, with the robot at the start of a lane: MJCF
(MuJoCo and its viewer, `field.mjcf`), Gazebo Sim and Gazebo Classic 11 worlds (`field.sdf`,
`field.gzrobot`) and the ground truth as CSV. CLI: `python -m mjxrow.worlds` (mjxrow/worlds/cli.py).

Files written into an export folder for a world `<name>`:

    <name>.xml, <name>_terrain.bin     MJCF: field + robot (camera `front`) + overview camera `eye`
    <name>_plants.csv, <name>_lanes.csv  ground truth; lanes with their spawn poses
    <name>.sdf, models/<name>_field/, models/<name>_robot/                     (gazebo "sim")
    <name>_classic.world, models/<name>_field_classic/, models/<name>_robot_classic/  ("classic")
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pandas as pd

from mjxrow import field as mjxrow_field
from mjxrow.worlds import scene, sdf
from mjxrow.worlds.mjcf import lane_camera, snapshot, to_mjcf  # noqa: F401  (public names)
from mjxrow.worlds.scene import Robot, Start  # noqa: F401
from mjxrow.worlds.sdf import SDF_COLLISIONS, heightmap  # noqa: F401

GAZEBO = ("sim", "classic", "both", "none")


def plants_table(field: mjxrow_field.Field, shape: mjxrow_field.FieldShape) -> pd.DataFrame:
    """Active plants: row (0..R-1 by y), index (slot along the row), x, y, z (base centre on the
    terrain [m]), kind (crop), length, width, height [m], yaw [rad]."""
    f = scene.host(field)
    order, new_row = scene.active_rows(f)
    r, p = np.nonzero(f.plant_active[order])
    r = order[r]
    pos, size = f.plant_pos[r, p], f.plant_size[r, p]
    return pd.DataFrame({"row": new_row[r], "index": p, "x": pos[:, 0], "y": pos[:, 1],
                         "z": pos[:, 2], "kind": shape.crop, "length": size[:, 0],
                         "width": size[:, 1], "height": size[:, 2], "yaw": f.plant_yaw[r, p]})


def lanes_table(field: mjxrow_field.Field, shape: mjxrow_field.FieldShape | None = None,
                robot: scene.Robot | None = None, start: scene.Start | None = None) -> pd.DataFrame:
    """Each lane between consecutive active rows: lane (i: between rows i and i+1), y of its
    centre line, x_start/x_end (the rows' ends), z_start/z_end (terrain height there), width
    (row to row) [m], default (1 for `field.robot_lane`). With `shape` and `robot`, also the
    robot's start in each lane (`scene.start_poses`: the chassis origin resting on the terrain,
    `robot.sim.path_length` before the row end): spawn_x, spawn_y, spawn_z [m], spawn_roll,
    spawn_pitch, spawn_yaw [rad] (Gazebo's pose; `start` replaces its lane's row, e.g. a sweep
    episode's noisy start)."""
    f = scene.host(field)
    order, _ = scene.active_rows(f)
    y = 0.5 * (f.row_y[order[1:]] + f.row_y[order[:-1]])
    x0, x1 = (np.full_like(y, v) for v in f.row_x)
    z = [np.asarray(mjxrow_field.terrain_height(f.terrain, f.terrain_size, x, y)) for x in (x0, x1)]
    default = (order[:-1] == int(mjxrow_field.robot_lane(f))).astype(int)
    out = pd.DataFrame({"lane": np.arange(len(y)), "y": y, "x_start": x0, "x_end": x1,
                        "z_start": z[0], "z_end": z[1], "width": np.diff(f.row_y[order]),
                        "default": default})
    if shape is not None and robot is not None:
        poses = np.array([scene.Start(i, q).xyz_rpy
                          for i, q in enumerate(scene.start_poses(f, shape, robot))])
        if start is not None:
            poses[start.lane] = start.xyz_rpy
        for i, k in enumerate(("x", "y", "z", "roll", "pitch", "yaw")):
            out[f"spawn_{k}"] = poses[:, i]
    return out


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
    xml, plants, lanes, sdf (sim) / world (classic) and every other file's relative path."""
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
    for key, table in (("plants", plants_table(field, shape)),
                       ("lanes", lanes_table(field, shape, robot, start))):
        paths[key] = out / f"{name}_{key}.csv"
        table.to_csv(paths[key], index=False, float_format="%.4f")
    return paths
