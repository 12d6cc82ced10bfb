"""The Jackal-like robot as a Gazebo model (SDF), for Gazebo Classic 11 ("classic", SDF 1.6)
and Gazebo Sim ("sim", SDF 1.9).

It is translated from the closed loop's own MJCF robot (`physics.sim.model_xml`, built by
`physics.robot.mjcf_body`), so every number is the simulator's: the chassis box (size, offset,
mass; it collides in Gazebo, where plants are solid), four SPHERE wheels (radius, mass,
friction, position) on revolute joints about the chassis y axis, and the camera `front`
(pose, vertical fov → horizontal fov for the image's aspect, image size, 15 Hz).

The wheel drive is MuJoCo's (`wheel_dynamics`): the wheel joints' motor armature
(`RobotConfig.armature`, 0.05 kg·m², 26× a 0.5 kg sphere wheel's own inertia) is added to the
wheel link's inertia about its axle (SDF has no armature; half of it about the two other axes,
as a disc's), the joints' effort limit is the
motor torque limit `wheel_torque` and their damping `wheel_damping`. With the armature, a
joint velocity controller with MuJoCo's gain kv = 30 N·m·s/rad is stable in Gazebo's explicit
PID at 1 ms (kv · dt / inertia = 0.58 < 2; without it, 15.6). docs/gazebo.md: what drives the
exported robot off its lane in Gazebo Classic (ODE's over-relaxation, `sdf.PHYSICS`) and how
its straight and turning runs compare with MuJoCo's.

Joints are named `left_front`, `right_front`, `left_rear`, `right_rear` (the names Gazebo
Classic's `libSkidSteerDrivePlugin.so` looks for). Driving:
- Classic: the skid-steer plugin listens on `~/<model>/vel_cmd` (gazebo.msgs.Pose: position.x
  = v, yaw of the orientation = turn); without a publisher, each wheel can be given a velocity
  target through the model's joint controller, e.g.
  `gz joint -m robot -j left_front --vel-t 5.1 --vel-p 30` (the closed loop's actuator: torque
  = kv · (target − speed), kv = `RobotConfig.kv`, limited to the joint's effort limit), or by
  `libJointControlPlugin.so` (experiments/gazebo_check.sh).
- Sim: `gz-sim-diff-drive-system` on `/model/<model>/cmd_vel` (gz.msgs.Twist), with the
  closed loop's effective track (track · turn_factor) as wheel separation.
"""

from __future__ import annotations

import xml.etree.ElementTree as ET

import numpy as np

from mjxrow import field
from mjxrow.physics import robot as physics_robot
from mjxrow.physics import sim
from mjxrow.worlds import scene

CAMERA_HZ = 15.0  # Hz, camera update rate (the closed loop's control rate)
CAMERA_CLIP = (0.05, 60.0)  # m, near and far clip


def _floats(el: ET.Element, key: str, default: str) -> np.ndarray:
    return np.array(el.get(key, default).split(), float)


def _inertia(mass: float, diag: np.ndarray) -> str:
    ixx, iyy, izz = diag
    return (f"<inertial><mass>{mass:.6g}</mass><inertia><ixx>{ixx:.6g}</ixx><ixy>0</ixy>"
            f"<ixz>0</ixz><iyy>{iyy:.6g}</iyy><iyz>0</iyz><izz>{izz:.6g}</izz></inertia>"
            "</inertial>")


def _material(rgba: np.ndarray) -> str:
    c = scene.nums(rgba, 3)
    return (f"<material><ambient>{c}</ambient><diffuse>{c}</diffuse>"
            "<specular>0.1 0.1 0.1 1</specular></material>")


def camera_sensor(robot: scene.Robot, flavour: str, cam: ET.Element) -> str:
    """`<sensor type="camera">` from the MJCF camera `cam` (pos, xyaxes in the chassis frame):
    Gazebo cameras look along their +x with +z up, so the frame is (forward, left, up) =
    (−z, −x, y) of MuJoCo's camera axes."""
    xy = _floats(cam, "xyaxes", "1 0 0 0 1 0").reshape(2, 3)
    right, up = xy[0] / np.linalg.norm(xy[0]), xy[1] / np.linalg.norm(xy[1])
    rot = np.stack([np.cross(up, right), -right, up], 1)  # columns: forward, left, up
    pose = np.r_[_floats(cam, "pos", "0 0 0"), scene.euler_zyx(rot)[::-1]]
    w, h = robot.image
    topic = "<topic>front/image</topic>" if flavour == "sim" else ""
    near, far = CAMERA_CLIP
    return (f'<sensor name="front" type="camera"><pose>{scene.nums(pose, 5)}</pose>'
            f"<always_on>1</always_on><update_rate>{CAMERA_HZ:g}</update_rate>"
            f"<visualize>false</visualize>{topic}<camera><horizontal_fov>{robot.hfov:.6f}"
            f"</horizontal_fov><image><width>{w}</width><height>{h}</height>"
            f"<format>R8G8B8</format></image><clip><near>{near}</near><far>{far}</far></clip>"
            "</camera></sensor>")


def wheel_dynamics(cfg: physics_robot.RobotConfig) -> dict[str, float]:
    """The wheels' drive numbers in Gazebo, from the MuJoCo robot `cfg` (module doc):
    `iyy` [kg·m²] the wheel link's inertia about its axle (a solid sphere's 0.4·m·r² plus the
    joint armature), `ixx` = `izz` [kg·m²] the sphere's plus half the armature (the armature as
    a disc on the axle: a link's moments must obey ixx + izz ≥ iyy), `effort` [N·m] the joints'
    torque limit (`wheel_torque`; absent when that is 0: unlimited) and `damping` [N·m·s/rad]."""
    own = 0.4 * cfg.wheel_mass * cfg.wheel_radius ** 2
    rotor = cfg.armature / 2  # a disc's moments about its diameters: valid for sdformat
    out = {"ixx": own + rotor, "iyy": own + cfg.armature, "izz": own + rotor,
           "damping": cfg.wheel_damping}
    if cfg.wheel_torque > 0:
        out["effort"] = cfg.wheel_torque
    return out


def _drive_plugin(flavour: str, robot: scene.Robot, radius: float) -> str:
    if flavour == "classic":
        return '<plugin name="skid_steer" filename="libSkidSteerDrivePlugin.so"/>'
    sep = robot.robot.track * robot.robot.turn_factor
    joints = "".join(f"<{s}_joint>{s}_{e}</{s}_joint>" for s in ("left", "right")
                     for e in ("front", "rear"))
    return ('<plugin filename="gz-sim-diff-drive-system" name="gz::sim::systems::DiffDrive">'
            f"{joints}<wheel_separation>{sep:.6g}</wheel_separation>"
            f"<wheel_radius>{radius:.6g}</wheel_radius><odom_publish_frequency>15"
            "</odom_publish_frequency></plugin>")


def robot_sdf(shape: field.FieldShape, robot: scene.Robot, flavour: str, name: str) -> str:
    """SDF text (a `<model name=name>`, with its `<sdf>` root) of the robot (module doc)."""
    root = ET.fromstring(sim.model_xml(shape, robot.sim, robot.robot))
    body = root.find("./worldbody/body[@name='chassis']")
    box = body.find("geom[@type='box']") if body is not None else None
    cam = body.find("camera") if body is not None else None
    wheels = body.findall("body") if body is not None else []
    if box is None or cam is None or len(wheels) != 4:
        raise ValueError("robot: sim.model_xml's chassis lacks its box, camera or 4 wheels")
    half, pos = _floats(box, "size", "0 0 0"), _floats(box, "pos", "0 0 0")
    mass = float(box.get("mass"))
    ext = 2 * half
    diag = mass / 12 * np.array([ext[1] ** 2 + ext[2] ** 2, ext[0] ** 2 + ext[2] ** 2,
                                 ext[0] ** 2 + ext[1] ** 2])
    geom = f"<geometry><box><size>{scene.nums(ext, 4)}</size></box></geometry>"
    rgba = _floats(box, "rgba", "0.85 0.65 0.1 1")
    links = [f'<link name="chassis"><inertial><pose>{scene.nums(pos, 4)} 0 0 0</pose>'
             + _inertia(mass, diag).removeprefix("<inertial>")
             + f'<collision name="chassis_collision"><pose>{scene.nums(pos, 4)} 0 0 0</pose>{geom}'
             f'</collision><visual name="chassis"><pose>{scene.nums(pos, 4)} 0 0 0</pose>{geom}'
             f"{_material(rgba)}</visual>{camera_sensor(robot, flavour, cam)}</link>"]
    joints, radius = [], 0.0
    dyn = wheel_dynamics(robot.robot)
    effort = f"<effort>{dyn['effort']:.6g}</effort>" if "effort" in dyn else ""
    for wb in wheels:
        g, j = wb.find("geom"), wb.find("joint")
        at = _floats(wb, "pos", "0 0 0")
        radius = float(g.get("size").split()[0])
        m = float(g.get("mass"))
        mu = float(g.get("friction", "1").split()[0])
        jname = ("left" if at[1] > 0 else "right") + ("_front" if at[0] > 0 else "_rear")
        sphere = f"<geometry><sphere><radius>{radius:.6g}</radius></sphere></geometry>"
        links.append(
            f'<link name="wheel_{jname}"><pose>{scene.nums(at, 4)} 0 0 0</pose>'
            f"{_inertia(m, np.array([dyn['ixx'], dyn['iyy'], dyn['izz']]))}"
            f'<collision name="collision">{sphere}<surface><friction><ode><mu>{mu:g}</mu>'
            f"<mu2>{mu:g}</mu2></ode></friction></surface></collision>"
            f'<visual name="visual">{sphere}{_material(_floats(g, "rgba", "0.1 0.1 0.1 1"))}'
            "</visual></link>")
        joints.append(f'<joint name="{jname}" type="revolute"><parent>chassis</parent>'
                      f"<child>wheel_{jname}</child><axis><xyz>"
                      f'{scene.nums(_floats(j, "axis", "0 0 1"))}</xyz><dynamics><damping>'
                      f"{dyn['damping']:.6g}</damping></dynamics><limit><lower>-1e16</lower>"
                      f"<upper>1e16</upper>{effort}</limit></axis></joint>")
    version = "1.6" if flavour == "classic" else "1.9"
    return "\n".join([f'<?xml version="1.0"?>\n<sdf version="{version}">',
                      f'<model name="{name}">', *links, *joints,
                      _drive_plugin(flavour, robot, radius), "</model>", "</sdf>", ""])
