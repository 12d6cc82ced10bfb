"""Host-side exports of ONE generated field: MJCF (MuJoCo and its viewer), SDF 1.9 (Gazebo Sim)
and the ground truth as CSV. CLI: `python -m mjxrow.worlds --preset zucchini --seed 0 --out DIR`.

Geom names: terrain `terrain`, plant primitives `plant_r{row}_p{index}_k{k}` (row 0..R-1 by
increasing y, index = the plant's slot along its row, k = primitive of `plants.plant_prims`),
obstacles `stone_{i}` / `branch_{i}` (counted per kind). Groups: terrain 0, plants 1,
obstacles 2. Plants never collide (contype = conaffinity = 0).
"""

from __future__ import annotations

import argparse
import gzip
import io
import sys
from pathlib import Path

import jax
import numpy as np
import pandas as pd
from PIL import Image

from mjxrow import crops
from mjxrow import field as F
from mjxrow.crops import prims as PL
from mjxrow.files import check_out_dir, check_out_file
from mjxrow.overrides import parse_sets

PLANT_RGB = {"leaf": (0.23, 0.50, 0.14), "stem": (0.42, 0.60, 0.22), "trunk": (0.36, 0.25, 0.16),
             "canopy": (0.17, 0.40, 0.12), "fruit": (0.85, 0.75, 0.25)}
STONE_RGB, BRANCH_RGB, SOIL_RGB = (0.50, 0.48, 0.45), (0.40, 0.29, 0.18), (0.45, 0.34, 0.23)
EYE_FOVY = 45.0  # deg, vertical field of view of the `eye` camera
HFIELD_BASE = 0.5  # m, thickness of the MuJoCo heightfield below its lowest sample


def _f(x: float, nd: int = 3) -> str:
    """A number with `nd` decimals, trailing zeros dropped ('1.500' → '1.5', '-0.000' → '0')."""
    s = f"{float(x):.{nd}f}".rstrip("0").rstrip(".")
    return "0" if s in ("-0", "") else s


def _v(xs, nd: int = 3) -> str:
    return " ".join(_f(x, nd) for x in np.ravel(xs))


def _euler_zyx(rot: np.ndarray) -> np.ndarray:
    """Angles (a, b, c) [rad] with rot = Rz(a) @ Ry(b) @ Rx(c): MJCF `euler` with
    eulerseq="zyx", and SDF's pose (roll, pitch, yaw) = (c, b, a). rot: [..., 3, 3] → [..., 3]."""
    sb = np.clip(-rot[..., 2, 0], -1.0, 1.0)
    lock = np.abs(sb) > 1.0 - 1e-6
    a = np.where(lock, np.arctan2(-rot[..., 0, 1], rot[..., 1, 1]),
                 np.arctan2(rot[..., 1, 0], rot[..., 0, 0]))
    c = np.where(lock, 0.0, np.arctan2(rot[..., 2, 1], rot[..., 2, 2]))
    return np.stack([a, np.arcsin(sb), c], -1)


def _host(field: F.Field) -> F.Field:
    f = jax.tree.map(np.asarray, field)
    if f.terrain.ndim != 2:
        raise ValueError(f"field: expected ONE field (terrain [NY, NX]), got terrain shape "
                         f"{f.terrain.shape}; index the batch first")
    return f


def _rows(f: F.Field) -> tuple[np.ndarray, np.ndarray]:
    """Active rows sorted by y: (field row index [n], new index 0..n-1 per field row [R])."""
    act = np.flatnonzero(f.row_active)
    order = act[np.argsort(f.row_y[act], kind="stable")]
    new = np.full(f.row_y.shape, -1)
    new[order] = np.arange(len(order))
    return order, new


def lane_camera(field: F.Field, height: float = 1.0, back: float = 1.0,
                pitch_deg: float = -15.0) -> tuple[np.ndarray, np.ndarray]:
    """A camera at the start of the default lane (`field.robot_lane`), `back` metres before the
    rows, `height` metres above the terrain, looking along +x pitched by `pitch_deg` (negative
    = down). Returns (cam_pos float32 [3], cam_rot float32 [3, 3]) in MuJoCo's convention
    (columns: right, up, backwards)."""
    f = _host(field)
    lane = int(F.robot_lane(f))
    x, y = float(f.row_x[0]) - back, float(f.lane_y[lane])
    z = float(F.terrain_height(f.terrain, f.terrain_size, x, y)) + height
    p = np.deg2rad(pitch_deg)
    right = np.array([0.0, -1.0, 0.0])
    up = np.array([-np.sin(p), 0.0, np.cos(p)])
    rot = np.stack([right, up, np.cross(right, up)], 1)
    return np.array([x, y, z], np.float32), rot.astype(np.float32)


def _terrain_bin(terrain: np.ndarray) -> tuple[bytes, float, float]:
    """MuJoCo's custom hfield file (int32 nrow, int32 ncol, float32 data, row 0 at −y), holding
    the heights normalised to 0..1; returns (bytes, z_min, z_range) [m]."""
    lo, span = float(terrain.min()), float(np.ptp(terrain))
    norm = (terrain - lo) / span if span > 0 else np.zeros_like(terrain)
    data = np.asarray(terrain.shape, np.int32).tobytes() + norm.astype(np.float32).tobytes()
    return data, lo, max(span, 1e-4)


def to_mjcf(field: F.Field, shape: F.FieldShape, name: str = "field") -> tuple[str, dict]:
    """MJCF text and its assets ({file name: bytes}) for ONE field (numpy or jax arrays, no batch
    axis); load with `mujoco.MjModel.from_xml_string(xml, assets)`. The world has a camera `eye`
    (`lane_camera`), a sun (no shadows: they alias in software rendering), a sky box and a
    soil material."""
    f = _host(field)
    order, new_row = _rows(f)
    hbin, z_lo, z_top = _terrain_bin(f.terrain)
    L, W = (float(s) for s in f.terrain_size)
    hfile = f"{name}_terrain.bin"
    prims = jax.tree.map(np.asarray, PL.plant_prims(f, shape))
    classes = [PL.MATERIAL_NAMES[m] + ("_capsule" if k == PL.CAPSULE else "")
               for k, m in zip(prims.kind, prims.material, strict=True)]
    cam_pos, cam_rot = lane_camera(f)

    out = [f'<mujoco model="{name}">',
           '  <compiler angle="degree" eulerseq="zyx"/>',
           f'  <statistic center="0 0 0" extent="{_f(0.5 * max(L, W), 1)}"/>',
           '  <visual>',
           '    <headlight ambient="0.35 0.35 0.35" diffuse="0.25 0.25 0.25" specular="0 0 0"/>',
           '    <map znear="0.0005" zfar="4"/>',
           '    <global offwidth="1280" offheight="960"/>',
           '  </visual>',
           '  <asset>',
           '    <texture name="sky" type="skybox" builtin="gradient" rgb1="0.55 0.72 0.92" '
           'rgb2="0.95 0.97 1" width="256" height="1536"/>',
           f'    <texture name="soil" type="2d" builtin="flat" rgb1="{_v(SOIL_RGB, 2)}" '
           'rgb2="0.38 0.29 0.19" mark="random" random="0.3" width="256" height="256"/>',
           '    <material name="soil" texture="soil" texrepeat="2 2" texuniform="true" '
           'reflectance="0"/>',
           f'    <hfield name="terrain" file="{hfile}" size="{_v([L / 2, W / 2], 6)} '
           f'{_f(z_top, 6)} {HFIELD_BASE}"/>']
    for mat, rgb in PLANT_RGB.items():
        out.append(f'    <material name="{mat}" rgba="{_v(rgb, 2)} 1" specular="0.1"/>')
    out += [f'    <material name="stone" rgba="{_v(STONE_RGB, 2)} 1"/>',
            f'    <material name="branch" rgba="{_v(BRANCH_RGB, 2)} 1"/>',
            '  </asset>', '  <default>',
            '    <default class="plant"><geom contype="0" conaffinity="0" group="1"/>']
    for cls in dict.fromkeys(classes):
        typ = "capsule" if cls.endswith("_capsule") else "ellipsoid"
        out.append(f'      <default class="{cls}"><geom type="{typ}" '
                   f'material="{cls.removesuffix("_capsule")}"/></default>')
    out += ['    </default>',
            '    <default class="stone"><geom type="sphere" material="stone" group="2"/></default>',
            '    <default class="branch"><geom type="capsule" material="branch" group="2"/>'
            '</default>', '  </default>', '  <worldbody>',
            '    <light name="sun" directional="true" castshadow="false" pos="0 0 40" '
            'dir="0.35 0.45 -1" diffuse="0.75 0.75 0.7" specular="0.1 0.1 0.1"/>',
            f'    <camera name="eye" pos="{_v(cam_pos)}" xyaxes="{_v(cam_rot[:, 0], 5)} '
            f'{_v(cam_rot[:, 1], 5)}" fovy="{EYE_FOVY}"/>',
            f'    <geom name="terrain" type="hfield" hfield="terrain" pos="0 0 {_f(z_lo, 6)}" '
            'material="soil" group="0"/>']
    euler = np.rad2deg(_euler_zyx(prims.rot))
    main_cls = max(set(classes), key=classes.count)
    for r in order:
        out.append(f'    <frame name="row_{new_row[r]}" childclass="{main_cls}">')
        for p in np.flatnonzero(f.plant_active[r]):
            for k, cls in enumerate(classes):
                size = prims.size[r, p, k]
                size = size if prims.kind[k] == PL.ELLIPSOID else size[[0, 2]]
                c = "" if cls == main_cls else f' class="{cls}"'
                out.append(f'<geom name="plant_r{new_row[r]}_p{p}_k{k}"{c} '
                           f'pos="{_v(prims.centre[r, p, k])}" euler="{_v(euler[r, p, k], 1)}" '
                           f'size="{_v(size)}"/>')
        out.append("    </frame>")
    n = {F.STONE: 0, F.BRANCH: 0}
    for i in np.flatnonzero(f.obst_active):
        kind, pos, (rad, half) = int(f.obst_kind[i]), f.obst_pos[i], f.obst_size[i]
        if kind == F.STONE:
            out.append(f'    <geom name="stone_{n[kind]}" class="stone" pos="{_v(pos)}" '
                       f'size="{_f(rad)}"/>')
        else:
            axis = [np.cos(f.obst_yaw[i]), np.sin(f.obst_yaw[i]), 0.0]
            out.append(f'    <geom name="branch_{n[kind]}" class="branch" pos="{_v(pos)}" '
                       f'zaxis="{_v(axis, 4)}" size="{_f(rad)} {_f(half)}"/>')
        n[kind] += 1
    out += ["  </worldbody>", "</mujoco>", ""]
    return "\n".join(out), {hfile: hbin}


def _png(img: np.ndarray) -> bytes:
    buf = io.BytesIO()
    Image.fromarray(img).save(buf, format="PNG", optimize=True)
    return buf.getvalue()


def heightmap(field: F.Field) -> tuple[np.ndarray, float, float]:
    """Gazebo heightmap of one field: a square 16-bit image of side 2^n + 1 (nearest to the
    grid's longer side), resampled from `field.terrain` with `field.terrain_height`; image row 0 is
    +y, column 0 is −x. Returns (uint16 [N, N], z_min [m], z_range [m]); height = z_min +
    pixel / 65535 · z_range."""
    f = _host(field)
    side = 2 ** int(np.round(np.log2(max(f.terrain.shape) - 1))) + 1
    u = np.linspace(-0.5, 0.5, side)
    x = u[None, :] * f.terrain_size[0]
    y = -u[:, None] * f.terrain_size[1]
    h = np.asarray(F.terrain_height(f.terrain, f.terrain_size, np.broadcast_to(x, (side, side)),
                                    np.broadcast_to(y, (side, side))), np.float64)
    lo, span = float(h.min()), float(np.ptp(h))
    norm = (h - lo) / span if span > 0 else np.zeros_like(h)
    return np.round(norm * 65535).astype(np.uint16), lo, max(span, 1e-4)


def _sdf_geom(kind: int, size: np.ndarray) -> str:
    if kind == PL.CAPSULE:
        return (f"<capsule><radius>{_f(size[0])}</radius><length>{_f(2 * size[2])}</length>"
                "</capsule>")
    return f"<ellipsoid><radii>{_v(size)}</radii></ellipsoid>"


def _sdf_item(name: str, pose: np.ndarray, geom: str, rgb=None) -> str:
    """A <visual> (with `rgb`) or else a <collision>; pose = (x, y, z, roll, pitch, yaw)."""
    body = f"<pose>{_v(pose)}</pose><geometry>{geom}</geometry>"
    if rgb is None:
        return f'<collision name="{name}">{body}</collision>'
    # diffuse only: Gazebo Sim's ogre2 ignores <ambient>
    return (f'<visual name="{name}">{body}<material><diffuse>{_v(rgb, 2)} 1</diffuse>'
            "</material></visual>")


SDF_COLLISIONS = ("footprint", "primitives", "none")


def to_sdf(field: F.Field, shape: F.FieldShape, name: str = "field",
           collisions: str = "footprint") -> tuple[str, dict]:
    """SDF 1.9 world (Gazebo Sim) of ONE field and its assets ({file name: bytes}): heightmap
    terrain, one static model per row whose link holds every plant primitive as a visual (names
    as in the MJCF), the obstacles (visual + collision) and a sun.

    Plant collisions: "footprint" (default) one per plant, `plant_r{row}_p{index}`: an ellipsoid
    centred at the base (a dome above ground) with the semi-axes of `plants.footprint` and the
    plant's height, i.e. the footprint the navigation metrics count as a collision;
    "primitives" every primitive, `<visual name>_collision` (a file about 1.7× as large);
    "none"."""
    if collisions not in SDF_COLLISIONS:
        raise ValueError(f"collisions: {collisions!r} is not one of {SDF_COLLISIONS}")
    f = _host(field)
    order, new_row = _rows(f)
    img, z_lo, z_rng = heightmap(f)
    hm, soil, normal = f"{name}_heightmap.png", f"{name}_soil.png", f"{name}_soil_normal.png"
    rng = np.random.default_rng(0)
    soil_img = np.clip(np.array(SOIL_RGB) * 255 * (1 + 0.25 * rng.standard_normal((64, 64, 1))),
                       0, 255).astype(np.uint8)
    assets = {hm: _png(img), soil: _png(soil_img),
              normal: _png(np.broadcast_to(np.array([128, 128, 255], np.uint8), (8, 8, 3)))}
    L, W = (float(s) for s in f.terrain_size)
    hgeom = (f"<uri>{hm}</uri><size>{_v([L, W], 4)} {_f(z_rng, 6)}</size>"
             f"<pos>0 0 {_f(z_lo, 6)}</pos>")
    out = ['<?xml version="1.0"?>', '<sdf version="1.9">', f'<world name="{name}">',
           '<scene><ambient>0.4 0.4 0.4 1</ambient><background>0.7 0.8 0.95 1</background>'
           '<shadows>true</shadows></scene>',
           '<light type="directional" name="sun"><cast_shadows>true</cast_shadows>'
           '<pose>0 0 40 0 0 0</pose><diffuse>0.8 0.8 0.75 1</diffuse>'
           '<specular>0.1 0.1 0.1 1</specular><direction>0.35 0.45 -1</direction></light>',
           '<model name="terrain"><static>true</static><link name="link">',
           f'<collision name="terrain_collision"><geometry><heightmap>{hgeom}</heightmap>'
           '</geometry></collision>',
           '<visual name="terrain"><geometry><heightmap><use_terrain_paging>false'
           f'</use_terrain_paging><texture><size>2</size><diffuse>{soil}</diffuse>'
           f'<normal>{normal}</normal></texture>{hgeom}</heightmap></geometry></visual>',
           '</link></model>']
    prims = jax.tree.map(np.asarray, PL.plant_prims(f, shape))
    pose = np.concatenate([prims.centre, _euler_zyx(prims.rot)[..., ::-1]], -1)
    foot = np.asarray(PL.footprint(shape.crop, f.plant_size))
    for r in order:
        row = new_row[r]
        out.append(f'<model name="row_{row}"><static>true</static><link name="plants">')
        for p in np.flatnonzero(f.plant_active[r]):
            for k, kind in enumerate(prims.kind):
                geom = _sdf_geom(kind, prims.size[r, p, k])
                rgb = PLANT_RGB[PL.MATERIAL_NAMES[prims.material[k]]]
                out.append(_sdf_item(f"plant_r{row}_p{p}_k{k}", pose[r, p, k], geom, rgb))
                if collisions == "primitives":
                    out.append(_sdf_item(f"plant_r{row}_p{p}_k{k}_collision", pose[r, p, k],
                                         geom))
            if collisions == "footprint":
                radii = np.r_[foot[r, p], f.plant_size[r, p, 2]]
                out.append(_sdf_item(f"plant_r{row}_p{p}", np.r_[f.plant_pos[r, p], 0, 0, 0],
                                     f"<ellipsoid><radii>{_v(radii)}</radii></ellipsoid>"))
        out.append("</link></model>")
    out.append('<model name="obstacles"><static>true</static><link name="link">')
    n = {F.STONE: 0, F.BRANCH: 0}
    for i in np.flatnonzero(f.obst_active):
        kind, (rad, half) = int(f.obst_kind[i]), f.obst_size[i]
        if kind == F.STONE:
            nm, rgb = f"stone_{n[kind]}", STONE_RGB
            pose_i = np.r_[f.obst_pos[i], 0, 0, 0]
            geom = f"<sphere><radius>{_f(rad)}</radius></sphere>"
        else:
            nm, rgb = f"branch_{n[kind]}", BRANCH_RGB
            pose_i = np.r_[f.obst_pos[i], 0, np.pi / 2, f.obst_yaw[i]]
            geom = _sdf_geom(PL.CAPSULE, np.array([rad, rad, half]))
        out += [_sdf_item(nm, pose_i, geom, rgb), _sdf_item(f"{nm}_collision", pose_i, geom)]
        n[kind] += 1
    out += ["</link></model>", "</world>", "</sdf>", ""]
    return "\n".join(out), assets


def plants_table(field: F.Field, shape: F.FieldShape) -> pd.DataFrame:
    """Active plants: row (0..R-1 by y), index (slot along the row), x, y, z (base centre on the
    terrain [m]), kind (crop), length, width, height [m], yaw [rad]."""
    f = _host(field)
    order, new_row = _rows(f)
    r, p = np.nonzero(f.plant_active[order])
    r = order[r]
    pos, size = f.plant_pos[r, p], f.plant_size[r, p]
    return pd.DataFrame({"row": new_row[r], "index": p, "x": pos[:, 0], "y": pos[:, 1],
                         "z": pos[:, 2], "kind": shape.crop, "length": size[:, 0],
                         "width": size[:, 1], "height": size[:, 2], "yaw": f.plant_yaw[r, p]})


def lanes_table(field: F.Field) -> pd.DataFrame:
    """Each lane between consecutive active rows: lane (i: between rows i and i+1), y of its
    centre line, x_start/x_end (the rows' ends), z_start/z_end (terrain height there), width
    (row to row) [m], default (1 for `field.robot_lane`)."""
    f = _host(field)
    order, _ = _rows(f)
    y = 0.5 * (f.row_y[order[1:]] + f.row_y[order[:-1]])
    x0, x1 = (np.full_like(y, v) for v in f.row_x)
    z = [np.asarray(F.terrain_height(f.terrain, f.terrain_size, x, y)) for x in (x0, x1)]
    default = np.zeros(len(y), int)
    lane = int(F.robot_lane(f))
    hit = np.flatnonzero((order[:-1] == lane) & (order[1:] == lane + 1))
    default[hit] = 1
    return pd.DataFrame({"lane": np.arange(len(y)), "y": y, "x_start": x0, "x_end": x1,
                         "z_start": z[0], "z_end": z[1],
                         "width": np.diff(f.row_y[order]), "default": default})


def export(field: F.Field, shape: F.FieldShape, out_dir: str | Path, name: str,
           sdf_collisions: str = "footprint", gzip_sdf: bool = False) -> dict[str, Path]:
    """Write `<name>.xml` (+ `<name>_terrain.bin`), `<name>.sdf` (+ heightmap and soil PNGs;
    `<name>.sdf.gz` with `gzip_sdf`), `<name>_plants.csv` and `<name>_lanes.csv` into `out_dir`.
    Returns {what: path} with keys xml, sdf, plants, lanes and every asset file name."""
    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    paths: dict[str, Path] = {}
    for key, (text, assets) in (("xml", to_mjcf(field, shape, name)),
                                ("sdf", to_sdf(field, shape, name, sdf_collisions))):
        paths[key] = out / f"{name}.{key}"
        if key == "sdf" and gzip_sdf:
            paths[key] = out / f"{name}.sdf.gz"
            paths[key].write_bytes(gzip.compress(text.encode(), mtime=0))
        else:
            paths[key].write_text(text)
        for fname, data in assets.items():
            paths[fname] = out / fname
            paths[fname].write_bytes(data)
    for key, table in (("plants", plants_table(field, shape)), ("lanes", lanes_table(field))):
        paths[key] = out / f"{name}_{key}.csv"
        table.to_csv(paths[key], index=False, float_format="%.4f")
    return paths


def resolve(preset: str, sets: dict[str, float]) -> tuple[F.FieldParams, F.FieldShape]:
    """Validated params of `preset` with overrides, and the smallest static shape that holds
    them (so overrides that need more rows or plants still work). Raises ValueError naming the
    offending key."""
    params = F.make_params(preset, **sets)
    F.validate(params, F.FieldShape(crop=preset, max_rows=10**6, max_plants_per_row=10**6,
                                    obstacle_slots=10**6))
    shape = F.fit_shape(params, preset)
    F.validate(params, shape)
    return params, shape


def snapshot(xml_path: str | Path, png_path: str | Path, width: int = 960,
             height: int = 540) -> None:
    """Render the `eye` camera of an exported MJCF to a 256-colour PNG with MuJoCo's renderer
    (headless: set MUJOCO_GL=osmesa or egl before the first mujoco import)."""
    import mujoco

    m = mujoco.MjModel.from_xml_path(str(xml_path))
    d = mujoco.MjData(m)
    mujoco.mj_forward(m, d)
    renderer = mujoco.Renderer(m, height, width, max_geom=m.ngeom + 100)
    try:
        renderer.update_scene(d, camera="eye")
        img = Image.fromarray(renderer.render()).quantize(256, Image.Quantize.MEDIANCUT)
        img.save(png_path, optimize=True)
    finally:
        renderer.close()


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(prog="python -m mjxrow.worlds", description=__doc__.split("\n")[0])
    which = ap.add_mutually_exclusive_group(required=True)
    which.add_argument("--preset", choices=crops.names(), help="the preset to export")
    which.add_argument("--all", action="store_true", help="export every preset")
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--out", default="worlds", help="output folder")
    ap.add_argument("--set", action="append", metavar="KEY=VALUE", dest="sets",
                    help="override a field parameter (repeatable), e.g. --set d_rr=2.0")
    ap.add_argument("--sdf-collisions", choices=SDF_COLLISIONS, default="footprint",
                    help="plant collisions in the SDF (see to_sdf)")
    ap.add_argument("--gzip-sdf", action="store_true",
                    help="write <preset>.sdf.gz (gunzip before opening in Gazebo)")
    ap.add_argument("--picture", metavar="PNG", help="also render the `eye` view (one preset; "
                    "needs MuJoCo's offscreen GL: MUJOCO_GL=egl on a GPU, or osmesa with "
                    "libosmesa6)")
    args = ap.parse_args(argv)
    if args.picture and args.all:
        ap.error("--picture takes one preset, not --all")
    presets = crops.names() if args.all else (args.preset,)
    try:
        sets = parse_sets(args.sets)
        resolved = {p: resolve(p, sets) for p in presets}
        check_out_dir(args.out, "--out")
        if args.picture:
            check_out_file(args.picture, "--picture")
    except ValueError as e:
        print(f"error: {e}", file=sys.stderr)
        return 2
    from tqdm import tqdm

    generate = jax.jit(F.generate, static_argnums=1)
    for preset, (params, shape) in tqdm(resolved.items(), desc="export",
                                        disable=len(resolved) < 2):
        fld = generate(params, shape, jax.random.key(args.seed))
        paths = export(fld, shape, args.out, preset, args.sdf_collisions, args.gzip_sdf)
        kb = sum(p.stat().st_size for p in paths.values()) / 1024
        tqdm.write(f"{preset}: {int(fld.plant_active.sum())} plants in {int(fld.n_rows)} rows, "
                   f"{len(paths)} files, {kb:.0f} KiB → {Path(args.out) / preset}.xml")
        if args.picture:
            snapshot(paths["xml"], args.picture)
    return 0


if __name__ == "__main__":
    sys.exit(main())
