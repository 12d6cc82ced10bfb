"""The MJX model of the robot driving one lane of a field (impl "jax"): one MuJoCo model per
static configuration (`SimConfig`, the field shape), every world's data written into model arrays.
`mjxrow.physics.sim` re-exports every name here and in `world` and adds the state, `reset`
and `step`.

- `make_model(shape, sim_cfg, robot_cfg) -> (mujoco.MjModel, mjx.Model)`: the robot, a
  heightfield PATCH, obstacle geoms and a few obstacle CONTACT slots.
- `model_axes(mx)`: `in_axes` for a model batched by `world.world_model` under vmap.

Every world's patch and obstacles are written into the model by `mjxrow.physics.world`
(`world_model`, `refresh_contacts`, `world_mjmodel`), which also says how the terrain patch and
the obstacle slots work.

Time. The physics step is `sim_cfg.dt` rounded DOWN so that a control period holds a whole number
of steps: substeps = ceil(1 / (control_hz · dt)), physics_dt = 1 / (control_hz · substeps). With
the defaults (dt 0.01 s, 15 Hz) that is 7 substeps of 9.52 ms per 66.7 ms control period.

Speed and stability choices (measured on CPU with MuJoCo C as reference; see
mjxrow.bench.physics for the throughput stage):
- `implicitfast` with wheel armature 0.05: stable on |ΔH| 0.3 m with 10 % slopes along and across
  the lane on every preset (no NaN, no flip while on the patch). Euler damping is disabled
  (implicitfast does not use it); wheel-joint damping is zero; the velocity actuators' gain is
  integrated implicitly.
- Newton solver, `iterations` 4, `ls_iterations` 4: against a converged solve (100/50) the
  trajectory differs by ≤ 4 cm over 6 s of rough-terrain driving, the same as with 8 line-search
  iterations and 35 % cheaper; 2 or 1 iterations drift by decimetres to metres (rejected).
- dt ≈ 0.01 s: a time-step study against dt = 0.002 s gives ≤ 4-20 cm of open-loop drift over
  6 s (mostly yaw in skid turns) at 0.0095 s, twice that at 0.013 s; larger steps save episode
  time but not physics steps, so 7 substeps stay the default.
- Heightfield cells of 0.2 m: a wheel touches 8 prisms instead of 18 at 0.1 m (1.5× faster).
- Obstacle contact slots (`world`): 2 slots instead of 6 fixed obstacle geoms, 2.3× faster.
- Pyramidal friction cones, condim 3, dense Jacobian (nv = 10), no broadphase (few pairs).
"""

from __future__ import annotations

import dataclasses
import math
from typing import ClassVar

import jax
import mujoco
import numpy as np

from mjxrow import field as mjxrow_field
from mjxrow.field.generate import LANE_MODES
from mjxrow.physics import robot as physics_robot
from mjxrow.physics.quiet import mjx

TERRAIN = "terrain"  # name of the heightfield geom
_PARK_DEPTH = 100.0  # m below the patch where unused obstacle slots wait
_STONE_HALF = 1e-4  # m, capsule half length that makes a stone
_MAX_OBST = (0.1, 1.0)  # m, (radius, half length) bound compiled into the obstacle geoms


@dataclasses.dataclass(frozen=True)
class SimConfig:
    """Static simulation settings (hashable: one compile per distinct value)."""

    CHOICES: ClassVar[dict[str, tuple[str, ...]]] = {"lane": LANE_MODES}

    dt: float = 0.01  # s, largest physics step; shortened to fit the control period exactly
    control_hz: float = 15.0  # Hz, commands per second
    iterations: int = 4  # Newton solver iterations
    ls_iterations: int = 4  # line-search iterations
    path_length: float = 20.0  # m, start → row end along x
    patch_back: float = 2.0  # m of terrain patch behind the start
    patch_front: float = 2.0  # m of terrain patch beyond the row end
    patch_width: float = 6.0  # m, patch extent across the lane (y), centred on the lane
    patch_cell: float = 0.2  # m, largest heightfield cell
    patch_z: float = 4.0  # m, heightfield height range (static), must hold the patch's relief
    obstacle_slots: int = 1  # colliding obstacle slots, refilled near the wheels every period
    obstacle_candidates: int = 16  # obstacles per world on the patch (≤ shape.obstacle_slots)
    chassis_contacts: bool = False  # chassis box collides with terrain and obstacles
    max_speed: float = 20.0  # m/s or rad/s: any faster velocity counts as exploded (is_bad)
    max_tilt_deg: float = 75.0  # degrees: chassis tilt beyond this counts as flipped
    lane: str = "auto"  # lane kind driven: auto (the in-group lane when the robot fits,
    # else the lane between groups), in_group (between two rows of a group, d_rr), or
    # between_groups (d_RR); a kind no field can give is rejected naming field.d_rr / d_RR

    def __post_init__(self):
        for name in ("dt", "control_hz", "path_length", "patch_width", "patch_cell", "patch_z",
                     "max_speed", "max_tilt_deg"):
            if not getattr(self, name) > 0:
                raise ValueError(f"sim.{name}: must be positive, got {getattr(self, name)}")
        for name in ("patch_back", "patch_front"):
            if getattr(self, name) < 0:
                raise ValueError(f"sim.{name}: must be non-negative, got {getattr(self, name)}")
        for name in ("iterations", "ls_iterations", "obstacle_slots", "obstacle_candidates"):
            if int(getattr(self, name)) < 1:
                raise ValueError(f"sim.{name}: must be at least 1, got {getattr(self, name)}")
        if self.lane not in LANE_MODES:
            raise ValueError(f"sim.lane: must be one of {LANE_MODES}, got {self.lane!r}")

    @property
    def substeps(self) -> int:
        """Physics steps per control period."""
        return max(1, math.ceil(1.0 / (self.control_hz * self.dt) - 1e-9))

    @property
    def physics_dt(self) -> float:
        """s, the physics step actually used: 1 / (control_hz · substeps)."""
        return 1.0 / (self.control_hz * self.substeps)

    @property
    def patch_size(self) -> tuple[float, float]:
        """(length along x, width along y) of the terrain patch [m]."""
        return (self.path_length + self.patch_back + self.patch_front, self.patch_width)

    @property
    def patch_cells(self) -> tuple[int, int]:
        """(ny, nx) heightfield samples (MuJoCo nrow, ncol)."""
        lx, ly = self.patch_size
        def n(length):
            return math.ceil(length / self.patch_cell - 1e-9) + 1

        return (n(ly), n(lx))


# ---------------------------------------------------------------------------------------------
# Model


def model_xml(
    shape: mjxrow_field.FieldShape, sim_cfg: SimConfig, robot_cfg: physics_robot.RobotConfig
) -> str:
    """MJCF text of the physics model for `shape` (no assets: the heightfield starts flat)."""
    ny, nx = sim_cfg.patch_cells
    lx, ly = sim_cfg.patch_size
    n_obst, n_slots = _obstacle_counts(shape, sim_cfg)
    obst = "\n".join(
        f'    <geom name="obst_{i}" type="capsule" size="{_MAX_OBST[0]} {_MAX_OBST[1]}" '
        f'pos="0 0 {-_PARK_DEPTH - 3 * i}" contype="0" conaffinity="0" group="2" '
        f'rgba="0.5 0.45 0.4 1"/>'
        for i in range(n_obst)
    )
    obst += "".join(
        f'\n    <geom name="contact_{j}" type="capsule" size="{_MAX_OBST[0]} {_MAX_OBST[1]}" '
        f'pos="0 0 {-_PARK_DEPTH - 3 * (n_obst + j)}" contype="0" conaffinity="1" condim="3" '
        f'group="3" rgba="1 0 0 0.3"/>'
        for j in range(n_slots)
    )
    robot = physics_robot.mjcf_body(robot_cfg, pos=(0.0, 0.0, robot_cfg.wheel_radius + 0.01),
                                    chassis_contacts=sim_cfg.chassis_contacts)
    robot = "\n".join("    " + line for line in robot.splitlines())
    return f"""<mujoco model="mjxrow_{shape.crop}">
  <compiler angle="radian" autolimits="true"/>
  <option timestep="{sim_cfg.physics_dt:.9g}" integrator="implicitfast" solver="Newton"
          iterations="{sim_cfg.iterations}" ls_iterations="{sim_cfg.ls_iterations}"
          cone="pyramidal" jacobian="dense">
    <flag eulerdamp="disable"/>
  </option>
  <custom>
    {physics_robot.mjcf_numeric(robot_cfg)}
  </custom>
  <asset>
    <hfield name="patch" nrow="{ny}" ncol="{nx}"
            size="{lx / 2:.6g} {ly / 2:.6g} {sim_cfg.patch_z:.6g} 0.5"/>
  </asset>
  <worldbody>
    <light name="sun" pos="0 0 20" dir="0.3 0.2 -1" directional="true"/>
    <geom name="{TERRAIN}" type="hfield" hfield="patch" pos="0 0 -1" contype="0" conaffinity="1"
          condim="3" group="0" rgba="0.45 0.35 0.25 1"/>
{obst}
{robot}
  </worldbody>
  <actuator>
{physics_robot.mjcf_actuators(robot_cfg)}
  </actuator>
</mujoco>
"""


def make_model(
    shape: mjxrow_field.FieldShape,
    sim_cfg: SimConfig | None = None,
    robot_cfg: physics_robot.RobotConfig | None = None,
) -> tuple[mujoco.MjModel, mjx.Model]:
    """Compile the physics model for a static shape (host; once per shape and configs).

    Returns the MuJoCo C model (flat patch, obstacles parked) and its MJX model (impl "jax").
    The robot's limits and geometry travel inside the model (a `<numeric>`), so `step` and
    `reset` need only the model."""
    sim_cfg = sim_cfg or SimConfig()
    robot_cfg = robot_cfg or physics_robot.RobotConfig()
    m = mujoco.MjModel.from_xml_string(model_xml(shape, sim_cfg, robot_cfg))
    mx = mjx.put_model(m, impl="jax", device=jax.local_devices()[0])  # this process's own
    return m, mx


def robot_numbers(mx: mjx.Model | mujoco.MjModel) -> dict[str, float]:
    """The robot's numbers baked into a model (robot.NUMERIC_KEYS → float; static)."""
    i = mjx.name2id(mx, mujoco.mjtObj.mjOBJ_NUMERIC, physics_robot.NUMERIC)
    if i < 0:
        raise ValueError(
            f"model: no <numeric name={physics_robot.NUMERIC!r}>; build it with sim.make_model"
        )
    adr = int(mx.numeric_adr[i])
    vals = np.asarray(mx.numeric_data)[adr: adr + len(physics_robot.NUMERIC_KEYS)]
    return {k: float(v) for k, v in zip(physics_robot.NUMERIC_KEYS, vals, strict=True)}


def _obstacle_counts(shape: mjxrow_field.FieldShape, sim_cfg: SimConfig) -> tuple[int, int]:
    """(obstacle geoms per world, colliding contact slots)."""
    k = min(sim_cfg.obstacle_candidates, shape.obstacle_slots)
    return k, min(sim_cfg.obstacle_slots, k)


def _geom_ids(mx: mjx.Model | mujoco.MjModel) -> tuple[int, np.ndarray, np.ndarray]:
    """(terrain geom id, obstacle geom ids [K], contact-slot geom ids [J]) (static)."""

    def series(prefix):
        ids, i = [], 0
        while (g := mjx.name2id(mx, mujoco.mjtObj.mjOBJ_GEOM, f"{prefix}_{i}")) >= 0:
            ids.append(g)
            i += 1
        return np.asarray(ids, np.int32)

    return mjx.name2id(mx, mujoco.mjtObj.mjOBJ_GEOM, TERRAIN), series("obst"), series("contact")


def _wheel_body_ids(mx: mjx.Model | mujoco.MjModel) -> np.ndarray:
    return np.array(
        [mjx.name2id(mx, mujoco.mjtObj.mjOBJ_BODY, f"wheel_{n}") for n in physics_robot.WHEELS]
    )


def wheel_dofs(mx: mjx.Model | mujoco.MjModel) -> np.ndarray:
    """int [4]: the wheel joints' qvel indices, robot.WHEELS order (static)."""
    ids = [mjx.name2id(mx, mujoco.mjtObj.mjOBJ_JOINT, f"wheel_{n}") for n in physics_robot.WHEELS]
    return np.asarray(mx.jnt_dofadr)[ids]


# arrays world_model writes: batched along axis 0 by model_axes
WORLD_FIELDS = ("hfield_data", "geom_pos", "geom_quat", "geom_size")


def model_axes(mx: mjx.Model) -> mjx.Model:
    """vmap `in_axes` for models made by vmapping `world_model`: 0 on WORLD_FIELDS, None on
    everything else."""
    axes = jax.tree.map(lambda _: None, mx)
    return axes.tree_replace({k: 0 for k in WORLD_FIELDS})
