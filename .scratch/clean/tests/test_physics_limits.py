"""The robot's drive limits and the checks around the physics: the default physics step agrees
with a 5× finer one on hard manoeuvres, the configured wheel friction is the one used, no
episode starts inside an obstacle, the terrain patch holds the field's relief, the lane kind
is explicit.

Manoeuvre tolerances (default step 9.52 ms against 1.90 ms, mjxrow.physics.manoeuvres): before
the wheel servos were integrated consistently with the contacts the two steps differed by 11°
of pitch in a stop, 9.6 cm of hop and 5 rad/s of yaw rate in a flipped turn, and the coarse
step flipped the robot on both slopes. With the servo fixed they agree within 1° (pitch), 2 mm
(stop distance), 0.15 rad/s (yaw rate) and 1.2 cm (distances) (measured on CPU). The bounds
below sit 2-5× above that, room for float32 on other devices and jax versions, and 5-10× below
the artefacts they guard against.
"""

from __future__ import annotations

import dataclasses
import math
import re

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from mjxrow import field as F
from mjxrow.field.generate import LANE_MODES, PATH_LENGTH
from mjxrow.physics import manoeuvres as MV
from mjxrow.physics import robot as R
from mjxrow.physics import sim as S
from mjxrow.rollout import build as RB

CFG = S.SimConfig()


NAMES = MV.MANOEUVRES + (MV.HOLD,)


@pytest.fixture(scope="module")
def manoeuvres():
    """The manoeuvres in MuJoCo C on the simulator's model (mjxrow.physics.manoeuvres.run_c:
    worlds built by the MJX code, stepped as sim.step does), 3 s each at the default step,
    at a fifth of it, and at the default step with wheel friction 0.3."""
    fine = dataclasses.replace(CFG, dt=CFG.physics_dt / 5)
    assert fine.substeps == 5 * CFG.substeps
    runs = (("coarse", CFG, NAMES, None), ("fine", fine, NAMES, None),
            ("mu03", CFG, ("stop",), 0.3))
    return {k: MV.figures(MV.run_c(c, seconds=3.0, names=names, friction=mu))
            for k, c, names, mu in runs}


def test_ramp_and_servo_hand_computed():
    cfg = R.RobotConfig()  # max_accel 20 m/s², max_alpha 25 rad/s², kv 30, 5 N·m
    t = np.asarray(R.ramp(jnp.zeros(2), jnp.array([3.0, -0.1]), cfg, 0.01))
    np.testing.assert_allclose(t, [0.2, -0.1], atol=1e-6)  # 20·0.01; ω within 25·0.01
    t = np.asarray(R.ramp(jnp.array([0.45, 0.0]), jnp.array([3.0, 0.0]), cfg, 0.01))
    np.testing.assert_allclose(t, [0.5, 0.0], atol=1e-6)  # clipped to v_max first
    free = R.RobotConfig(max_accel=0.0, max_alpha=0.0)
    np.testing.assert_allclose(R.ramp(jnp.zeros(2), jnp.array([0.3, 0.7]), free, 0.01),
                               [0.3, 0.7], atol=1e-6)
    tau, stiff = R.servo(jnp.array([0.01, 10.0, -10.0, 0.0]), jnp.zeros(4), cfg)
    # 5·tanh(30·e/5): ≈ kv·e for small errors, ±5 N·m for large ones
    np.testing.assert_allclose(tau, [5.0 * math.tanh(0.06), 5.0, -5.0, 0.0], rtol=1e-5)
    np.testing.assert_allclose(stiff, [30.0 * (1 - math.tanh(0.06) ** 2), 0.0, 0.0, 30.0],
                               rtol=1e-5, atol=1e-5)
    tau, stiff = R.servo(jnp.array([10.0]), jnp.zeros(1), R.RobotConfig(wheel_torque=0.0))
    np.testing.assert_allclose([tau[0], stiff[0]], [300.0, 30.0])  # unlimited
    with pytest.raises(ValueError, match="robot.max_accel"):
        R.RobotConfig(max_accel=-1.0)


def test_model_has_motors_with_the_torque_limit_and_wheel_priority():
    shape = F.FieldShape(max_rows=4, max_plants_per_row=8, terrain_cells=(16, 16),
                         obstacle_slots=1)
    m, _ = S.make_model(shape, CFG, R.RobotConfig(friction=0.3, wheel_torque=4.0))
    np.testing.assert_allclose(m.actuator_forcerange, np.tile([-4.0, 4.0], (4, 1)))
    wheels = [m.geom(f"wheel_{n}").id for n in R.WHEELS]
    assert (m.geom_priority[wheels] == 1).all() and (m.geom_priority[m.geom("terrain").id] == 0)
    np.testing.assert_allclose(m.geom_friction[wheels, 0], 0.3)
    np.testing.assert_allclose(m.dof_armature[S.wheel_dofs(m)], 0.05)


def test_default_step_agrees_with_a_fine_step(manoeuvres):
    c, f = manoeuvres["coarse"], manoeuvres["fine"]
    for name in MV.MANOEUVRES:
        assert c[name]["flipped"] == 0 and f[name]["flipped"] == 0, name
    # a start from rest settles within 1 s without overshoot
    for fig in (c, f):
        assert fig["start"]["overshoot_pct"] < 2.0 and fig["start"]["settle_s"] <= 1.0
    assert abs(c["start"]["settle_s"] - f["start"]["settle_s"]) <= 0.1 + 1e-9
    # a stop from 0.5 m/s: no nose dive, the same braking distance
    assert max(c["stop"]["pitch_deg"], f["stop"]["pitch_deg"]) < 2.0
    assert abs(c["stop"]["stop_cm"] - f["stop"]["stop_cm"]) < 1.0
    assert 0.0 < f["stop"]["stop_cm"] < 10.0
    # ω flipped every control period: no hop, the same wiggle
    assert max(c["flip_turn"]["hop_cm"], f["flip_turn"]["hop_cm"]) < 1.0
    assert abs(c["flip_turn"]["yaw_rate"] - f["flip_turn"]["yaw_rate"]) < 0.4
    assert abs(c["flip_turn"]["dist_m"] - f["flip_turn"]["dist_m"]) < 0.05
    # 25° down, 30° up: the chassis stays on the slope's plane and covers the same ground
    for name in ("descent", "climb"):
        assert abs(c[name]["pitch_deg"] - f[name]["pitch_deg"]) < 2.0, name
        assert max(c[name]["pitch_deg"], f[name]["pitch_deg"]) < 6.0, name
        assert abs(c[name]["dist_m"] - f[name]["dist_m"]) < 0.05, name
        # commanded 0.75 m; uphill the 5 N·m motors reach 0.48 m/s after 0.6 s: 0.49 m
        assert c[name]["dist_m"] > 0.4, name


def test_configured_friction_is_used(manoeuvres):
    """A stop from 0.5 m/s on flat ground: at wheel friction 0.3 the tyres slip and the robot
    needs at least v²/(2·0.3·g) = 4.2 cm; at 1.0 the motors stop it in about half that. The
    terrain keeps friction 1: without the wheels' priority MuJoCo would use max(0.3, 1) and
    both would stop alike. Standing on a 20° slope at friction 1 (tan 20° = 0.36 < 1) the
    robot holds (the servo's speed error lets it creep ~1 cm/s)."""
    c, lo = manoeuvres["coarse"]["stop"], manoeuvres["mu03"]["stop"]
    assert c["flipped"] == 0 and lo["flipped"] == 0
    assert lo["stop_cm"] > 100.0 * MV.V ** 2 / (2 * 0.3 * 9.81) - 0.3, lo
    assert lo["stop_cm"] > 1.5 * c["stop_cm"], (lo, c)
    for k in ("coarse", "fine"):
        hold = manoeuvres[k][MV.HOLD]
        assert hold["flipped"] == 0 and abs(hold["slide_cm"]) < 5.0, (k, hold)


# fields of the obstacle and lane tests: one generate compile (same shape, same batch)
LANES = dict(terrain_length=30.0, row_length=24.0, terrain_width=20.0, rows_per_group=3,
             stone_density=0.0, branch_density=0.0)
DENSE = {**LANES, "stone_density": 30.0, "branch_density": 16.0}
N = 8


def _fields(params: list, path_length: float = PATH_LENGTH) -> F.Field:
    """N fields of `params` (repeated), keys 0..N-1, on the shape of LANES and DENSE."""
    shape = F.fit_shape(F.stack_params([F.make_params("zucchini", **DENSE, d_rr=1.2)]),
                        "zucchini")
    batch = F.stack_params([params[i % len(params)] for i in range(N)])
    return RB.generate_fn()(batch, shape, jax.random.split(jax.random.key(3), N), path_length)


def test_no_obstacle_at_any_start():
    """8 fields dense with stones and branches (about 170 each): no obstacle (capsule: segment +
    radius) comes within the robot's footprint + 0.2 m of the start, on any lane, at the
    default and at a shorter path length."""
    rc = R.RobotConfig()
    for path_length in (PATH_LENGTH, 11.0):
        fields = _fields([F.make_params("zucchini", **DENSE)], path_length)
        act = np.asarray(fields.obst_active)
        assert act.sum(1).min() >= 100  # dense
        x0 = np.asarray(fields.row_x[:, 1]) - path_length
        pos, size = np.asarray(fields.obst_pos), np.asarray(fields.obst_size)
        yaw = np.asarray(fields.obst_yaw)
        t = np.linspace(-1.0, 1.0, 21)
        px = pos[..., None, 0] + t * size[..., None, 1] * np.cos(yaw)[..., None]  # [n, S, 21]
        gap = np.abs(px - x0[:, None, None]) - size[..., None, 0] - 0.5 * rc.length
        gap = np.where(act[..., None], gap, np.inf)  # along x, across every lane
        assert gap.min() > 0.2, (path_length, gap.min())


def test_patch_z_is_checked_and_fitted(manoeuvres):
    steep = F.make_params("zucchini", slope_x=0.25, terrain_dh=0.5)
    np.testing.assert_allclose(S.patch_relief(steep, CFG), 0.5 + 0.25 * 24.0)  # 6.5 m
    with pytest.raises(ValueError, match=r"sim\.patch_z: 4 m .* 6\.50 m at field\.slope_x=0\.25"):
        S.check_params(steep, CFG)
    fitted = S.fit_patch_z(steep, CFG)
    assert fitted.patch_z == 7.0 and S.fit_patch_z(F.make_params("zucchini"), CFG) is CFG
    S.check_params(steep, fitted)
    # 30° climb (relief 0.58 · 24 m = 13.9 m): the default 4 m range is refused; with the
    # fitted one the physics heightfield (MuJoCo C copy of sim.world_model's) is the field's
    # plane, not a flattened one
    climb = F.make_params("zucchini", **MV.FIELD, slope_x=MV.slope("climb"))
    with pytest.raises(ValueError, match=r"sim\.patch_z: 4 m .* at field\.slope_x=0\.577"):
        S.check_params(climb, CFG)
    cfg = MV.sim_config(CFG)
    S.check_params(climb, cfg)
    mc, _ = MV.c_world("climb")
    ny, nx = cfg.patch_cells
    h = mc.hfield_data.reshape(ny, nx) * mc.hfield_size[0, 2]
    grade = np.diff(h, axis=1) / (cfg.patch_size[0] / (nx - 1))
    np.testing.assert_allclose(grade, MV.slope("climb"), atol=2e-3)
    assert np.ptp(h) == pytest.approx(MV.slope("climb") * cfg.patch_size[0], rel=1e-3)


def test_lane_choice_is_explicit():
    base = LANES
    fields = _fields([F.make_params("zucchini", **base, d_rr=d) for d in (1.8, 1.2)])
    widths = np.asarray(fields.lane_width)
    all_lanes = {m: np.asarray(jax.vmap(lambda f, m=m: F.robot_lane(f, mode=m))(fields))
                 for m in LANE_MODES}
    via_sim = np.asarray(jax.vmap(lambda f: S.lane_of(f, S.SimConfig(lane="in_group")))(fields))
    for i, d_rr in enumerate((1.8, 1.2)):
        rpg = 3
        lanes = {m: int(v[i]) for m, v in all_lanes.items()}
        assert (lanes["in_group"] + 1) % rpg != 0 and (lanes["between_groups"] + 1) % rpg == 0
        assert float(widths[i, lanes["in_group"]]) == pytest.approx(d_rr, abs=1e-5)
        assert float(widths[i, lanes["between_groups"]]) == pytest.approx(3.6, abs=1e-5)
        # auto: in-group while it fits (1.8 − 0.9 ≥ 0.53), between groups at 1.2 (0.3 m free)
        assert lanes["auto"] == lanes["in_group" if d_rr == 1.8 else "between_groups"]
        assert int(via_sim[i]) == lanes["in_group"]
    narrow = F.make_params("zucchini", **base, d_rr=1.2)
    S.check_lane(narrow, S.SimConfig(lane="between_groups"))
    S.check_lane(narrow, S.SimConfig())
    with pytest.raises(ValueError, match=r"sim\.lane: the in_group lane is 0\.30 m wide .* "
                                         r"field\.d_rr=1\.2 .* needs 0\.53 m"):
        S.check_lane(narrow, S.SimConfig(lane="in_group"))
    with pytest.raises(ValueError, match=r"sim\.lane: in_group needs rows_per_group > 1"):
        S.check_lane(F.make_params("pear"), S.SimConfig(lane="in_group"))
    with pytest.raises(ValueError, match=r"sim\.lane: between_groups needs two row groups"):
        S.check_lane(F.make_params("zucchini", **{**base, "terrain_width": 12.0}),
                     S.SimConfig(lane="between_groups"))
    with pytest.raises(ValueError, match="sim.lane: must be one of"):
        S.SimConfig(lane="widest")


@pytest.mark.parametrize("sets, message", [
    (["field.d_rr=1.2", "sim.lane=in_group"], r"sim\.lane: the in_group lane is 0\.30 m wide"),
    (["field.d_rr=[1.2, 1.8]"],
     r"sim\.lane: 'auto' drives the between_groups lane \(cell field\.d_rr=1\.2\) but the "
     r"in_group lane \(cell field\.d_rr=1\.8"),
    (["field.slope_x=0.25"], r"sim\.patch_z: 4 m cannot hold .* field\.slope_x=0\.25"),
])
def test_impossible_physics_requests_exit_2(sets, message, tmp_path, capsys):
    """The episode CLI and the sweep loader reject them before building anything: one line
    naming the key, exit 2."""
    from mjxrow import episode
    from mjxrow.sweep import config as C

    argv = ["--preset", "zucchini", "--out", str(tmp_path)]
    if not any("[" in s for s in sets):  # one run: the episode CLI
        assert episode.main(argv + [a for s in sets for a in ("--set", s)]) == 2
        err = capsys.readouterr().err.strip()
        assert "\n" not in err and re.search(message, err), err
    with pytest.raises(C.ConfigError, match=message):
        C.from_dict({"preset": "zucchini", "controller": {"name": "oracle"}}, ".", sets)
    assert (tmp_path / "episodes.csv").exists() is False
