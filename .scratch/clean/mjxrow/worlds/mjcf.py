"""MJCF (MuJoCo and its viewer) of ONE generated field, optionally with the robot at the start
of a lane, driven as the closed loop drives it.

Geom names: terrain `terrain`, plant primitives `plant_r{row}_p{index}_k{k}` (row 0..R-1 by
increasing u, the rows' lateral field coordinate (y on straight rows), index = the plant's slot
along its row, k = primitive of `crops.prims.plant_prims`), weed primitives `weed_{i}_k{k}`
(i = the weed's slot, k = primitive of `crops.prims.weed_prims`), obstacles `stone_{i}` /
`branch_{i}` (counted per kind). Groups: terrain 0, plants and weeds 1, obstacles 2. Plants and
weeds never collide (contype = conaffinity = 0); the robot's wheels touch the terrain and the
obstacles. A weed's primitives all have its colour, `weed_rgb` of its phase (geom `rgba` and
material `weed_{dark,light,yellow}`, from `crops.prims.WEED_PALETTE`).

The robot is `physics.sim.model_xml`'s own: its `<option>` (time step, integrator, solver),
`<custom>` numbers, chassis body (free joint, sphere wheels, camera `front`) and wheel
actuators, taken from that model's text, so the viewer runs the closed loop's physics; the
closed loop's `<motor>`s, which it drives with its own implicit servo (`robot.servo`), become
MuJoCo `<velocity>` actuators of the same gain and torque limit, so the viewer's sliders set
wheel speeds. The
actuators get a `ctrlrange` of the largest wheel speed a command within the robot's limits
asks for (so the viewer's control panel has sliders of that range; the closed loop never leaves
it), and keyframes `start` (at rest), `forward` (v_max straight on), `left` / `right` (v_max/2
turning at omega_max/2): the viewer's "Load key" sets both the pose and the wheel commands.
"""

from __future__ import annotations

import xml.etree.ElementTree as ET
from pathlib import Path

import jax
import numpy as np

from mjxrow import field as mjxrow_field
from mjxrow.crops import prims as crops_prims
from mjxrow.field import lanes as field_lanes
from mjxrow.physics import robot as physics_robot
from mjxrow.physics import sim
from mjxrow.worlds import scene

PLANT_RGB = {"leaf": (0.23, 0.50, 0.14), "stem": (0.42, 0.60, 0.22), "trunk": (0.36, 0.25, 0.16),
             "canopy": (0.17, 0.40, 0.12), "fruit": (0.85, 0.75, 0.25)}
STONE_RGB, BRANCH_RGB, SOIL_RGB = (0.50, 0.48, 0.45), (0.40, 0.29, 0.18), (0.45, 0.34, 0.23)
EYE_FOVY = 45.0  # deg, vertical field of view of the `eye` camera
SUN_DIR = (0.35, 0.45, -1.0)  # direction of the `sun` light's rays (downwards)
HFIELD_BASE = 0.5  # m, thickness of the MuJoCo heightfield below its lowest sample
KEYS = {"start": (0.0, 0.0), "forward": (1.0, 0.0), "left": (0.5, 0.5), "right": (0.5, -0.5)}
WEED_CLASSES = ("weed_dark", "weed_light", "weed_yellow")  # = crops.prims.WEED_PALETTE's order


def weed_rgb(phase: np.ndarray) -> np.ndarray:
    """int [...]: the index into `crops.prims.WEED_PALETTE` (and WEED_CLASSES) of weeds of
    phase `phase` [...] in [0, 1): the palette split into equal thirds of the phase."""
    n = len(crops_prims.WEED_PALETTE)
    return np.minimum((np.asarray(phase) * n).astype(int), n - 1)


def lane_camera(field: mjxrow_field.Field, height: float = 1.0, back: float = 1.0,
                pitch_deg: float = -15.0) -> tuple[np.ndarray, np.ndarray]:
    """A camera on the centre line of the default lane (`field.robot_lane`), `back` metres
    (along the lane) before the rows, `height` metres above the terrain, looking along the lane
    (+x on straight rows) pitched by `pitch_deg` (negative = down). Returns (cam_pos float32 [3],
    cam_rot float32 [3, 3]) in MuJoCo's convention (columns: right, up, backwards)."""
    f = scene.host(field)
    ln = field_lanes.lane(f, int(mjxrow_field.robot_lane(f)))
    s = f.row_x[0] - np.float32(back)
    x, y = (float(v) for v in field_lanes.point(ln, s))
    yaw = float(field_lanes.heading(ln.bend, s, ln.u))
    z = float(mjxrow_field.terrain_height(f.terrain, f.terrain_size, x, y)) + height
    p, c, sn = np.deg2rad(pitch_deg), np.cos(yaw), np.sin(yaw)
    right = np.array([sn, -c, 0.0])
    up = np.array([-np.sin(p) * c, -np.sin(p) * sn, np.cos(p)])
    rot = np.stack([right, up, np.cross(right, up)], 1)
    return np.array([x, y, z], np.float32), rot.astype(np.float32)


def terrain_bin(terrain: np.ndarray) -> tuple[bytes, float, float]:
    """MuJoCo's custom hfield file (int32 nrow, int32 ncol, float32 data, row 0 at −y), holding
    the heights normalised to 0..1; returns (bytes, z_min, z_range) [m]."""
    lo, span = float(terrain.min()), float(np.ptp(terrain))
    norm = (terrain - lo) / span if span > 0 else np.zeros_like(terrain)
    data = np.asarray(terrain.shape, np.int32).tobytes() + norm.astype(np.float32).tobytes()
    return data, lo, max(span, 1e-4)


def robot_parts(
    shape: mjxrow_field.FieldShape, robot: scene.Robot, start: scene.Start
) -> dict[str, str]:
    """MJCF pieces of the robot from `sim.model_xml`: {'option', 'custom', 'body', 'actuator',
    'keys'} (XML text), the chassis placed at `start.qpos` and the actuators given a
    `ctrlrange` (module doc)."""
    root = ET.fromstring(sim.model_xml(shape, robot.sim, robot.robot))
    body = root.find("./worldbody/body[@name='chassis']")
    parts = {k: root.find(k) for k in ("option", "custom", "actuator")}
    if body is None or any(v is None for v in parts.values()):
        raise ValueError("robot: sim.model_xml has no chassis body, option, custom or actuator")
    body.set("pos", scene.nums(start.qpos[:3], 6))
    body.set("quat", scene.nums(start.qpos[3:], 6))
    corners = np.array([[a, b] for a in (-1, 1) for b in (-1, 1)])
    lim = np.array([robot.robot.v_max, robot.robot.omega_max])
    top = float(np.max(np.abs(physics_robot.wheel_speeds(corners * lim, robot.robot))))
    # the closed loop drives <motor>s with its own implicit servo (robot.servo); the viewer gets
    # MuJoCo's velocity actuators with the same gain and torque limit, integrated implicitly
    parts["option"].set("integrator", "implicitfast")
    for act in parts["actuator"]:
        act.tag = "velocity"
        act.set("kv", f"{robot.robot.kv:.6g}")
        act.set("ctrlrange", f"{-top:.6g} {top:.6g}")
    nq = 7 + len(physics_robot.WHEELS)
    qpos = scene.nums(np.r_[start.qpos, np.zeros(nq - 7)], 6)
    keys = [f'    <key name="{k}" qpos="{qpos}" ctrl="'
            f'{scene.nums(physics_robot.wheel_speeds(np.array(c) * lim, robot.robot), 4)}"/>'
            for k, c in KEYS.items()]
    text = {k: ET.tostring(v, encoding="unicode").strip() for k, v in parts.items()}
    return {**text, "body": ET.tostring(body, encoding="unicode").strip(),
            "keys": "\n".join(["  <keyframe>", *keys, "  </keyframe>"])}


def to_mjcf(
    field: mjxrow_field.Field,
    shape: mjxrow_field.FieldShape,
    name: str = "field",
    robot: scene.Robot | None = None,
    start: scene.Start | None = None,
) -> tuple[str, dict]:
    """MJCF text and its assets ({file name: bytes}) for ONE field (numpy or jax arrays, no batch
    axis); load with `mujoco.MjModel.from_xml_string(xml, assets)`. The world has a camera `eye`
    (`lane_camera`), a sun (no shadows: they alias in software rendering), a sky box and a
    soil material; with `robot`, the robot at `start` (default: `scene.default_start`)."""
    f = scene.host(field)
    order, new_row = scene.active_rows(f)
    hbin, z_lo, z_top = terrain_bin(f.terrain)
    L, W = (float(s) for s in f.terrain_size)
    hfile = f"{name}_terrain.bin"
    prims = jax.tree.map(np.asarray, crops_prims.plant_prims(f, shape))
    weeds = jax.tree.map(np.asarray, crops_prims.weed_prims(f))
    weed_cls = [WEED_CLASSES[c] for c in weed_rgb(f.weed_phase)]
    classes = [crops_prims.MATERIAL_NAMES[m] + ("_capsule" if k == crops_prims.CAPSULE else "")
               for k, m in zip(prims.kind, prims.material, strict=True)]
    cam_pos, cam_rot = lane_camera(f)
    parts = {}
    if robot is not None:
        parts = robot_parts(shape, robot, start or scene.default_start(f, shape, robot))

    out = [f'<mujoco model="{name}">',
           '  <compiler angle="radian" eulerseq="zyx" autolimits="true"/>']
    if parts:
        out += ["  " + parts["option"], "  " + parts["custom"]]
    out += [f'  <statistic center="0 0 0" extent="{scene.num(0.5 * max(L, W), 1)}"/>',
            '  <visual>',
            '    <headlight ambient="0.35 0.35 0.35" diffuse="0.25 0.25 0.25" specular="0 0 0"/>',
            '    <map znear="0.0005" zfar="4"/>',
            '    <global offwidth="1280" offheight="960"/>',
            '  </visual>',
            '  <asset>',
            '    <texture name="sky" type="skybox" builtin="gradient" rgb1="0.55 0.72 0.92" '
            'rgb2="0.95 0.97 1" width="256" height="1536"/>',
            f'    <texture name="soil" type="2d" builtin="flat" rgb1="{scene.nums(SOIL_RGB, 2)}" '
            'rgb2="0.38 0.29 0.19" mark="random" random="0.3" width="256" height="256"/>',
            '    <material name="soil" texture="soil" texrepeat="2 2" texuniform="true" '
            'reflectance="0"/>',
            f'    <hfield name="terrain" file="{hfile}" size="{scene.nums([L / 2, W / 2], 6)} '
            f'{scene.num(z_top, 6)} {HFIELD_BASE}"/>']
    for mat, rgb in PLANT_RGB.items():
        out.append(f'    <material name="{mat}" rgba="{scene.nums(rgb, 2)} 1" specular="0.1"/>')
    for cls, rgb in zip(WEED_CLASSES, crops_prims.WEED_PALETTE, strict=True):
        out.append(f'    <material name="{cls}" rgba="{scene.nums(rgb, 2)} 1" specular="0.1"/>')
    out += [f'    <material name="stone" rgba="{scene.nums(STONE_RGB, 2)} 1"/>',
            f'    <material name="branch" rgba="{scene.nums(BRANCH_RGB, 2)} 1"/>',
            '  </asset>', '  <default>',
            '    <default class="plant"><geom contype="0" conaffinity="0" group="1"/>']
    for cls in dict.fromkeys(classes):
        typ = "capsule" if cls.endswith("_capsule") else "ellipsoid"
        out.append(f'      <default class="{cls}"><geom type="{typ}" '
                   f'material="{cls.removesuffix("_capsule")}"/></default>')
    out += ["    </default>",
            '    <default class="weed"><geom type="ellipsoid" contype="0" conaffinity="0" '
            'group="1"/>']
    for cls, rgb in zip(WEED_CLASSES, crops_prims.WEED_PALETTE, strict=True):
        out.append(f'      <default class="{cls}"><geom material="{cls}" '
                   f'rgba="{scene.nums(rgb, 2)} 1"/></default>')
    out += [
        "    </default>",
        '    <default class="stone"><geom type="sphere" material="stone" group="2"/></default>',
        '    <default class="branch"><geom type="capsule" material="branch" group="2"/></default>',
        "  </default>",
        "  <worldbody>",
        '    <light name="sun" directional="true" castshadow="false" pos="0 0 40" '
        f'dir="{scene.nums(SUN_DIR)}" diffuse="0.75 0.75 0.7" specular="0.1 0.1 0.1"/>',
        f'    <camera name="eye" pos="{scene.nums(cam_pos)}" '
        f'xyaxes="{scene.nums(cam_rot[:, 0], 5)} '
        f'{scene.nums(cam_rot[:, 1], 5)}" fovy="{EYE_FOVY}"/>',
        f'    <geom name="terrain" type="hfield" hfield="terrain" pos="0 0 {scene.num(z_lo, 6)}" '
        'material="soil" group="0"/>',
    ]
    euler = scene.euler_zyx(prims.rot)
    main_cls = max(set(classes), key=classes.count)
    for r in order:
        out.append(f'    <frame name="row_{new_row[r]}" childclass="{main_cls}">')
        for p in np.flatnonzero(f.plant_active[r]):
            for k, cls in enumerate(classes):
                size = prims.size[r, p, k]
                size = size if prims.kind[k] == crops_prims.ELLIPSOID else size[[0, 2]]
                c = "" if cls == main_cls else f' class="{cls}"'
                out.append(f'<geom name="plant_r{new_row[r]}_p{p}_k{k}"{c} '
                           f'pos="{scene.nums(prims.centre[r, p, k])}" '
                           f'euler="{scene.nums(euler[r, p, k], 4)}" size="{scene.nums(size)}"/>')
        out.append("    </frame>")
    active = np.flatnonzero(f.weed_active)
    if len(active):
        w_euler = scene.euler_zyx(weeds.rot)
        out.append('    <frame name="weeds" childclass="weed">')
        for i in active:
            for k in range(weeds.centre.shape[1]):
                out.append(f'<geom name="weed_{i}_k{k}" class="{weed_cls[i]}" '
                           f'pos="{scene.nums(weeds.centre[i, k])}" '
                           f'euler="{scene.nums(w_euler[i, k], 4)}" '
                           f'size="{scene.nums(weeds.size[i, k])}"/>')
        out.append("    </frame>")
    n = {mjxrow_field.STONE: 0, mjxrow_field.BRANCH: 0}
    for i in np.flatnonzero(f.obst_active):
        kind, pos, (rad, half) = int(f.obst_kind[i]), f.obst_pos[i], f.obst_size[i]
        if kind == mjxrow_field.STONE:
            out.append(f'    <geom name="stone_{n[kind]}" class="stone" pos="{scene.nums(pos)}" '
                       f'size="{scene.num(rad)}"/>')
        else:
            axis = [np.cos(f.obst_yaw[i]), np.sin(f.obst_yaw[i]), 0.0]
            out.append(f'    <geom name="branch_{n[kind]}" class="branch" pos="{scene.nums(pos)}" '
                       f'zaxis="{scene.nums(axis, 4)}" size="{scene.num(rad)} {scene.num(half)}"/>')
        n[kind] += 1
    if parts:
        out.append("\n".join("    " + line for line in parts["body"].splitlines()))
    out.append("  </worldbody>")
    if parts:
        out += ["  " + parts["actuator"], parts["keys"]]
    out += ["</mujoco>", ""]
    return "\n".join(out), {hfile: hbin}


def snapshot(xml_path: str | Path, png_path: str | Path, width: int = 960, height: int = 540,
             camera: str = "eye") -> None:
    """Render `camera` of an exported MJCF to a 256-colour PNG with MuJoCo's renderer
    (headless: set MUJOCO_GL=osmesa or egl before the first mujoco import)."""
    import mujoco
    from PIL import Image

    m = mujoco.MjModel.from_xml_path(str(xml_path))
    d = mujoco.MjData(m)
    mujoco.mj_forward(m, d)
    renderer = mujoco.Renderer(m, height, width, max_geom=m.ngeom + 100)
    try:
        renderer.update_scene(d, camera=camera)
        img = Image.fromarray(renderer.render()).quantize(256, Image.Quantize.MEDIANCUT)
        img.save(png_path, optimize=True)
    finally:
        renderer.close()
