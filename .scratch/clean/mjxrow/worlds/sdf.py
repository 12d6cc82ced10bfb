"""Gazebo worlds of ONE generated field, in two flavours from one exporter:

- "sim": Gazebo Sim (Garden, Harmonic), SDF 1.9: ellipsoids and capsules as such, a 16-bit
  heightmap, the physics, user-command, scene-broadcaster and sensors systems;
- "classic": Gazebo Classic 11, SDF 1.6 (no geometry of SDF ≥ 1.8): every ellipsoid a
  unit-sphere mesh (`meshes/sphere.dae`) scaled to its semi-axes, every capsule a cylinder and
  two spheres, an 8-bit heightmap (Gazebo 11 misreads 16-bit ones), an ODE physics block.

Layout written under an export folder (model:// URIs only, so the world opens from any working
directory once `models/` is on the resource path, `GAZEBO_MODEL_PATH` for Classic,
`GZ_SIM_RESOURCE_PATH` for Sim):

    <name>.sdf | <name>_classic.world      the world: sun, scene, physics, the two includes
    models/<field>/model.config, model.sdf  the field: ONE static model, links `terrain`,
                                            `row_{i}` (plants), `weeds` (when there are
                                            any), `obstacles`
    models/<field>/materials/textures/      heightmap.png, soil.png, soil_normal.png
    models/<field>/meshes/sphere.dae        (classic)
    models/<robot>/model.config, model.sdf  the robot (gzrobot), included at the start pose

with <field> = `<name>_field` and <robot> = `<name>_robot` (`_classic` appended for Classic).
Visual names follow the MJCF (`plant_r{row}_p{index}_k{k}`, `weed_{i}_k{k}`; a Classic capsule's
end spheres add `_end0`, `_end1`). Weeds are visuals only (no collision), in the MJCF's colours
(`mjcf.weed_rgb`). Materials have ambient and diffuse colours.
"""

from __future__ import annotations

import io

import jax
import numpy as np
from PIL import Image

from mjxrow import field as mjxrow_field
from mjxrow.crops import prims as crops_prims
from mjxrow.worlds import gzrobot, scene
from mjxrow.worlds.mjcf import BRANCH_RGB, PLANT_RGB, SOIL_RGB, STONE_RGB, weed_rgb

FLAVOURS = ("sim", "classic")
SDF_COLLISIONS = ("footprint", "primitives", "none")
VERSION = {"sim": "1.9", "classic": "1.6"}
SPAWN_LIFT = 0.01  # m, the robot is included this far above its resting pose
SIM_SYSTEMS = ("physics", "user-commands", "scene-broadcaster", "sensors")
# ODE's quick-step solver in Classic: no over-relaxation (Gazebo's default 1.3 makes the robot's
# light wheels under its heavy chassis weave and veer off its lane on rough terrain) and
# Coulomb's friction cone (the default box lets a wheel take μ·N along and across at once:
# skid turns 12 % faster than MuJoCo's); measured in docs/gazebo.md
CLASSIC_SOR = 1.0
CLASSIC_FRICTION = "cone_model"
PHYSICS = {
    "classic": '<physics name="default_physics" default="true" type="ode"><max_step_size>0.001'
               "</max_step_size><real_time_factor>1</real_time_factor><real_time_update_rate>"
               "1000</real_time_update_rate><ode><solver><type>quick</type><iters>50</iters>"
               f"<sor>{CLASSIC_SOR:g}</sor><friction_model>{CLASSIC_FRICTION}</friction_model>"
               "</solver><constraints><cfm>0</cfm><erp>0.2</erp>"
               "<contact_max_correcting_vel>100</contact_max_correcting_vel>"
               "<contact_surface_layer>0.001</contact_surface_layer></constraints></ode>"
               "</physics>",
    "sim": '<physics name="1ms" type="ignored"><max_step_size>0.001</max_step_size>'
           "<real_time_factor>1</real_time_factor></physics>"}


def names(name: str, flavour: str) -> dict[str, str]:
    """File and model names of one world: {'world', 'field', 'robot'}."""
    if flavour not in FLAVOURS:
        raise ValueError(f"gazebo: {flavour!r} is not one of {FLAVOURS}")
    sfx = "_classic" if flavour == "classic" else ""
    world = f"{name}_classic.world" if flavour == "classic" else f"{name}.sdf"
    return {"world": world, "field": f"{name}_field{sfx}", "robot": f"{name}_robot{sfx}"}


def png(img: np.ndarray) -> bytes:
    buf = io.BytesIO()
    Image.fromarray(img).save(buf, format="PNG", optimize=True)
    return buf.getvalue()


def heightmap(field: mjxrow_field.Field, bits: int = 16) -> tuple[np.ndarray, float, float]:
    """Gazebo heightmap of one field: a square `bits`-bit (8 or 16) image of side 2^n + 1
    (nearest to the grid's longer side), resampled from `field.terrain` with
    `field.terrain_height`; image row 0 is +y, column 0 is −x. Returns (uint8|uint16 [N, N],
    z_min [m], z_range [m]); height = z_min + pixel / (2^bits − 1) · z_range."""
    f = scene.host(field)
    side = 2 ** int(np.round(np.log2(max(f.terrain.shape) - 1))) + 1
    u = np.linspace(-0.5, 0.5, side)
    x = np.broadcast_to(u[None, :] * f.terrain_size[0], (side, side))
    y = np.broadcast_to(-u[:, None] * f.terrain_size[1], (side, side))
    h = np.asarray(mjxrow_field.terrain_height(f.terrain, f.terrain_size, x, y), np.float64)
    lo, span = float(h.min()), float(np.ptp(h))
    norm = (h - lo) / span if span > 0 else np.zeros_like(h)
    top = 2 ** bits - 1
    return np.round(norm * top).astype(np.uint8 if bits == 8 else np.uint16), lo, max(span, 1e-4)


def unit_sphere_dae(n_lat: int = 8, n_lon: int = 12) -> str:
    """COLLADA 1.4.1 mesh of a unit sphere (radius 1 m, smooth normals, z up), n_lat × n_lon
    quads split into triangles: scaled per visual into an ellipsoid."""
    th = np.linspace(0.0, np.pi, n_lat + 1)
    ph = np.linspace(0.0, 2 * np.pi, n_lon + 1)[:-1]
    v = np.stack([np.outer(np.sin(th), np.cos(ph)), np.outer(np.sin(th), np.sin(ph)),
                  np.outer(np.cos(th), np.ones_like(ph))], -1).reshape(-1, 3)
    tris = []
    for i in range(n_lat):
        for j in range(n_lon):
            a, b = i * n_lon + j, i * n_lon + (j + 1) % n_lon
            c, d = a + n_lon, b + n_lon
            if i > 0:
                tris.append((a, c, b))
            if i < n_lat - 1:
                tris.append((b, c, d))
    idx = " ".join(f"{k} {k}" for t in tris for k in t)
    pts = scene.nums(v, 5)
    n = len(v)
    src = "".join(
        f'<source id="{s}"><float_array id="{s}-a" count="{3 * n}">{pts}</float_array>'
        f'<technique_common><accessor source="#{s}-a" count="{n}" stride="3"><param name="X" '
        'type="float"/><param name="Y" type="float"/><param name="Z" type="float"/></accessor>'
        "</technique_common></source>" for s in ("pos", "nrm"))
    return ('<?xml version="1.0" encoding="utf-8"?>\n<COLLADA xmlns="http://www.collada.org/'
            '2005/11/COLLADASchema" version="1.4.1"><asset><unit name="meter" meter="1"/>'
            "<up_axis>Z_UP</up_axis></asset><library_geometries><geometry id=\"sphere\">"
            f'<mesh>{src}<vertices id="vtx"><input semantic="POSITION" source="#pos"/>'
            f'</vertices><triangles count="{len(tris)}"><input semantic="VERTEX" source="#vtx" '
            'offset="0"/><input semantic="NORMAL" source="#nrm" offset="1"/>'
            f"<p>{idx}</p></triangles></mesh></geometry></library_geometries>"
            '<library_visual_scenes><visual_scene id="scene"><node id="sphere" name="sphere">'
            '<instance_geometry url="#sphere"/></node></visual_scene></library_visual_scenes>'
            '<scene><instance_visual_scene url="#scene"/></scene></COLLADA>\n')


def _material(rgb) -> str:
    c = scene.nums(rgb, 2) + " 1"
    return (f"<material><ambient>{c}</ambient><diffuse>{c}</diffuse>"
            "<specular>0.1 0.1 0.1 1</specular></material>")


class _Writer:
    """Visual / collision elements of one flavour; `mesh` is the unit-sphere URI (classic)."""

    def __init__(self, flavour: str, mesh: str):
        self.flavour, self.mesh = flavour, mesh

    def item(self, name: str, pose: np.ndarray, geom: str, rgb=None) -> str:
        """A <visual> (with `rgb`) or else a <collision>; pose = (x, y, z, roll, pitch, yaw)."""
        body = (f"<pose>{scene.nums(pose[:3])} {scene.nums(pose[3:], 4)}</pose>"
                f"<geometry>{geom}</geometry>")
        if rgb is None:
            return f'<collision name="{name}">{body}</collision>'
        return f'<visual name="{name}">{body}{_material(rgb)}</visual>'

    def ellipsoid(self, name: str, pose: np.ndarray, radii: np.ndarray, rgb=None) -> str:
        if self.flavour == "sim":
            return self.item(
                name, pose, f"<ellipsoid><radii>{scene.nums(radii)}</radii></ellipsoid>", rgb
            )
        return self.item(name, pose, f"<mesh><uri>{self.mesh}</uri><scale>{scene.nums(radii)}"
                                     "</scale></mesh>", rgb)

    def capsule(self, name: str, centre: np.ndarray, rot: np.ndarray, radius: float,
                half: float, rgb=None) -> list[str]:
        """A capsule of axis rot[:, 2] (Sim), or a cylinder and two end spheres (Classic)."""
        pose = np.r_[centre, scene.euler_zyx(rot)[::-1]]
        if self.flavour == "sim":
            return [self.item(name, pose, f"<capsule><radius>{scene.num(radius)}</radius><length>"
                              f"{scene.num(2 * half)}</length></capsule>", rgb)]
        ball = f"<sphere><radius>{scene.num(radius)}</radius></sphere>"
        out = [self.item(name, pose, f"<cylinder><radius>{scene.num(radius)}</radius><length>"
                         f"{scene.num(2 * half)}</length></cylinder>", rgb)]
        for i, s in enumerate((-1.0, 1.0)):
            out.append(self.item(f"{name}_end{i}", np.r_[centre + s * half * rot[:, 2], 0, 0, 0],
                                 ball, rgb))
        return out


def field_sdf(field: mjxrow_field.Field, shape: mjxrow_field.FieldShape, model: str, flavour: str,
              collisions: str = "footprint") -> tuple[str, dict[str, bytes]]:
    """The field as ONE static model `model` (module doc) and its files (paths relative to the
    model folder). Plant collisions: "footprint" (default) one per plant, `plant_r{row}_p{index}`:
    an ellipsoid centred at the base (a dome above ground) with the semi-axes of
    `crops.prims.footprint` and the plant's height, the footprint the navigation metrics count
    as a collision (turned along the row, `Field.plant_heading`); "primitives" every primitive
    (`<visual name>_collision`); "none". Weeds: visuals only."""
    if collisions not in SDF_COLLISIONS:
        raise ValueError(f"sdf_collisions: {collisions!r} is not one of {SDF_COLLISIONS}")
    f = scene.host(field)
    order, new_row = scene.active_rows(f)
    bits = 8 if flavour == "classic" else 16
    img, z_lo, z_rng = heightmap(f, bits)
    tex = "materials/textures"
    rng = np.random.default_rng(0)
    soil_img = np.clip(np.array(SOIL_RGB) * 255 * (1 + 0.25 * rng.standard_normal((64, 64, 1))),
                       0, 255).astype(np.uint8)
    files = {f"{tex}/heightmap.png": png(img), f"{tex}/soil.png": png(soil_img),
             f"{tex}/soil_normal.png": png(np.broadcast_to(np.array([128, 128, 255], np.uint8),
                                                           (8, 8, 3)))}
    uri = f"model://{model}"
    w = _Writer(flavour, f"{uri}/meshes/sphere.dae")
    if flavour == "classic":
        files["meshes/sphere.dae"] = unit_sphere_dae().encode()
    L, W = (float(s) for s in f.terrain_size)
    hgeom = (
        f"<uri>{uri}/{tex}/heightmap.png</uri><size>{scene.nums([L, W], 4)} {scene.num(z_rng, 6)}"
        f"</size><pos>0 0 {scene.num(z_lo, 6)}</pos>"
    )
    out = ['<?xml version="1.0"?>', f'<sdf version="{VERSION[flavour]}">',
           f'<model name="{model}"><static>true</static><link name="terrain">',
           f'<collision name="terrain_collision"><geometry><heightmap>{hgeom}</heightmap>'
           '</geometry></collision><visual name="terrain"><geometry><heightmap>'
           '<use_terrain_paging>false'
           f"</use_terrain_paging><texture><size>2</size><diffuse>{uri}/{tex}/soil.png</diffuse>"
           f"<normal>{uri}/{tex}/soil_normal.png</normal></texture>{hgeom}</heightmap>"
           "</geometry></visual></link>"]
    prims = jax.tree.map(np.asarray, crops_prims.plant_prims(f, shape))
    pose = np.concatenate([prims.centre, scene.euler_zyx(prims.rot)[..., ::-1]], -1)
    foot = np.asarray(crops_prims.footprint(shape.crop, f.plant_size))
    for r in order:
        row = new_row[r]
        out.append(f'<link name="row_{row}">')
        for p in np.flatnonzero(f.plant_active[r]):
            for k, kind in enumerate(prims.kind):
                nm, size = f"plant_r{row}_p{p}_k{k}", prims.size[r, p, k]
                rgb = PLANT_RGB[crops_prims.MATERIAL_NAMES[prims.material[k]]]
                for c in ((rgb,) + ((None,) if collisions == "primitives" else ())):
                    suffix = "" if c is not None else "_collision"
                    if kind == crops_prims.CAPSULE:
                        out += w.capsule(nm + suffix, prims.centre[r, p, k], prims.rot[r, p, k],
                                         size[0], size[2], c)
                    else:
                        out.append(w.ellipsoid(nm + suffix, pose[r, p, k], size, c))
            if collisions == "footprint":
                radii = np.r_[foot[r, p], f.plant_size[r, p, 2]]
                out.append(w.ellipsoid(f"plant_r{row}_p{p}",
                                       np.r_[f.plant_pos[r, p], 0, 0, f.plant_heading[r, p]],
                                       radii))
        out.append("</link>")
    active = np.flatnonzero(f.weed_active)
    if len(active):
        weeds = jax.tree.map(np.asarray, crops_prims.weed_prims(f))
        w_pose = np.concatenate([weeds.centre, scene.euler_zyx(weeds.rot)[..., ::-1]], -1)
        colour = weed_rgb(f.weed_phase)
        out.append('<link name="weeds">')
        for i in active:
            rgb = crops_prims.WEED_PALETTE[colour[i]]
            out += [w.ellipsoid(f"weed_{i}_k{k}", w_pose[i, k], weeds.size[i, k], rgb)
                    for k in range(weeds.centre.shape[1])]
        out.append("</link>")
    out.append('<link name="obstacles">')
    n = {mjxrow_field.STONE: 0, mjxrow_field.BRANCH: 0}
    for i in np.flatnonzero(f.obst_active):
        kind, (rad, half) = int(f.obst_kind[i]), f.obst_size[i]
        for c in (None, STONE_RGB if kind == mjxrow_field.STONE else BRANCH_RGB):
            nm = ("stone" if kind == mjxrow_field.STONE else "branch") + f"_{n[kind]}"
            nm += "_collision" if c is None else ""
            if kind == mjxrow_field.STONE:
                out.append(w.item(nm, np.r_[f.obst_pos[i], 0, 0, 0],
                                  f"<sphere><radius>{scene.num(rad)}</radius></sphere>", c))
            else:
                yaw = f.obst_yaw[i]
                rot = np.array([[0, -np.sin(yaw), np.cos(yaw)], [0, np.cos(yaw), np.sin(yaw)],
                                [-1, 0, 0]])  # Rz(yaw) Ry(π/2): the axis (z) lies along yaw
                out += w.capsule(nm, f.obst_pos[i], rot, rad, half, c)
        n[kind] += 1
    out += ["</link></model>", "</sdf>", ""]
    return "\n".join(out), files


def model_config(model: str, flavour: str, description: str) -> str:
    return (f'<?xml version="1.0"?>\n<model>\n  <name>{model}</name>\n  <version>1.0</version>\n'
            f'  <sdf version="{VERSION[flavour]}">model.sdf</sdf>\n  <author><name>mjxrow</name>'
            f"</author>\n  <description>{description}</description>\n</model>\n")


def world_sdf(name: str, flavour: str, start: scene.Start) -> str:
    """The world file: scene, sun, physics (and Gazebo Sim's systems), the field included and
    the robot included at `start` (raised by SPAWN_LIFT). Gazebo Classic's world is named
    "default" (its tools and plugins address the first world they find, and a camera sensor
    advertises under "default" before the world's name is known); Gazebo Sim's is `name`."""
    nm = names(name, flavour)
    pose = start.xyz_rpy + np.r_[0, 0, SPAWN_LIFT, 0, 0, 0]
    systems = "" if flavour == "classic" else "".join(
        f'<plugin filename="gz-sim-{s}-system" name="gz::sim::systems::'
        f'{s.title().replace("-", "")}">'
        + ("<render_engine>ogre2</render_engine>" if s == "sensors" else "") + "</plugin>"
        for s in SIM_SYSTEMS)
    return "\n".join([
        '<?xml version="1.0"?>', f'<sdf version="{VERSION[flavour]}">',
        f'<world name="{"default" if flavour == "classic" else name}">',
        PHYSICS[flavour], systems,
        "<scene><ambient>0.4 0.4 0.4 1</ambient><background>0.7 0.8 0.95 1</background>"
        "<shadows>true</shadows></scene>",
        '<light type="directional" name="sun"><cast_shadows>true</cast_shadows>'
        "<pose>0 0 40 0 0 0</pose><diffuse>0.8 0.8 0.75 1</diffuse>"
        "<specular>0.1 0.1 0.1 1</specular><direction>0.35 0.45 -1</direction></light>",
        f"<include><uri>model://{nm['field']}</uri><name>field</name></include>",
        f"<include><uri>model://{nm['robot']}</uri><name>robot</name>"
        f"<pose>{scene.nums(pose[:3], 4)} {scene.nums(pose[3:], 5)}</pose></include>",
        "</world>", "</sdf>", ""])


def gazebo_files(
    field: mjxrow_field.Field,
    shape: mjxrow_field.FieldShape,
    name: str,
    flavour: str,
    robot: scene.Robot,
    start: scene.Start,
    collisions: str = "footprint",
) -> dict[str, bytes]:
    """Every file of one flavour's export (module doc): {path relative to the export folder:
    bytes}."""
    nm = names(name, flavour)
    model, files = field_sdf(field, shape, nm["field"], flavour, collisions)
    out = {f"models/{nm['field']}/{k}": v for k, v in files.items()}
    what = {"sim": "Gazebo Sim", "classic": "Gazebo Classic 11"}[flavour]
    out[f"models/{nm['field']}/model.sdf"] = model.encode()
    out[f"models/{nm['field']}/model.config"] = model_config(
        nm["field"], flavour, f"mjxrow {shape.crop} field '{name}' for {what}").encode()
    out[f"models/{nm['robot']}/model.sdf"] = gzrobot.robot_sdf(
        shape, robot, flavour, nm["robot"]).encode()
    out[f"models/{nm['robot']}/model.config"] = model_config(
        nm["robot"], flavour, f"mjxrow Jackal-like robot with its camera, for {what}").encode()
    out[nm["world"]] = world_sdf(name, flavour, start).encode()
    return out
