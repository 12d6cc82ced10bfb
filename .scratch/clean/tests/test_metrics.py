"""Metrics on hand-made trajectories against hand-computed values; exact footprint overlap."""

import math

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from mjxrow import field as F
from mjxrow.field.lanes import straight_lane
from mjxrow.rollout import aggregate as A
from mjxrow.rollout import metrics as M

DT = 1.0 / 15.0
summarise = jax.jit(M.summarise, static_argnums=1)


def make_log(xy, yaw=0.0, cmd=(0.5, 0.0), lane_y=0.0, goal=(20.0, 0.0), reason=M.GOAL,
             alive=None, start=None):
    xy = np.asarray(xy, np.float32)
    T = len(xy)
    yaw = np.broadcast_to(np.asarray(yaw, np.float32), (T,))
    pose = np.concatenate([xy, yaw[:, None]], -1)
    cmd = np.broadcast_to(np.asarray(cmd, np.float32), (T, 2))
    alive = np.ones(T, bool) if alive is None else np.asarray(alive)
    steps = int(alive.sum())
    event = np.zeros(T, np.int32)
    event[steps - 1] = reason
    start = np.array([0.0, xy[0, 1], yaw[0]], np.float32) if start is None else start
    return M.Log(pose=jnp.asarray(pose), cmd=jnp.asarray(cmd), alive=jnp.asarray(alive),
                 event=jnp.asarray(event), start=jnp.asarray(start, jnp.float32),
                 goal=jnp.asarray(goal, jnp.float32), lane=straight_lane(lane_y, goal[0]),
                 reason=jnp.asarray(reason, jnp.int32), steps=jnp.asarray(steps, jnp.int32))


def straight(offset=0.0, n=100, lane_y=1.0, **kw):
    x = np.linspace(0.2, 20.0, n)
    return make_log(np.stack([x, np.full(n, lane_y + offset)], -1), lane_y=lane_y,
                    goal=(20.0, lane_y), **kw)


def test_straight_on_centre_line():
    s = summarise(straight(0.0), DT)
    assert float(s["mae"]) == 0.0 and float(s["mse"]) == 0.0 and float(s["max_offset"]) == 0.0
    assert float(s["cha"]) == pytest.approx(0.0, abs=1e-6)  # the goal is dead ahead
    assert float(s["path_ratio"]) == pytest.approx(1.0, abs=1e-5)
    assert float(s["omega_std"]) == 0.0 and float(s["v_mean"]) == pytest.approx(0.5)
    assert bool(s["success"]) and not bool(s["collision"])
    assert float(s["time"]) == pytest.approx(100 * DT)


def test_constant_offset():
    s = summarise(straight(0.1), DT)
    assert float(s["mae"]) == pytest.approx(0.1, abs=1e-6)
    assert float(s["mse"]) == pytest.approx(0.01, abs=1e-6)
    assert float(s["max_offset"]) == pytest.approx(0.1, abs=1e-6)
    s = summarise(straight(-0.1), DT)  # right of the line: same magnitudes
    assert float(s["mae"]) == pytest.approx(0.1, abs=1e-6)


def test_cha_sign_and_value():
    # robot at the origin heading +x, goal 10 m ahead and 1 m to the left
    log = make_log([[0.0, 0.0]], goal=(10.0, 1.0))
    assert float(summarise(log, DT)["cha"]) == pytest.approx(math.atan2(1.0, 10.0), rel=1e-5)
    log = make_log([[0.0, 0.0]], goal=(10.0, -1.0))
    assert float(summarise(log, DT)["cha"]) < 0
    # heading +y (yaw 90°), goal at +x: it lies to the robot's right
    log = make_log([[0.0, 0.0]], yaw=math.pi / 2, goal=(5.0, 0.0))
    assert float(summarise(log, DT)["cha"]) == pytest.approx(-math.pi / 2, rel=1e-5)


def test_path_ratio_and_omega_std():
    # start (0, 0) → (3, 4) → (6, 0): length 10, displacement 6
    log = make_log([[3.0, 4.0], [6.0, 0.0]], cmd=[[0.2, 1.0], [0.4, -1.0]],
                   start=np.zeros(3, np.float32))
    s = summarise(log, DT)
    assert float(s["path_ratio"]) == pytest.approx(10.0 / 6.0, rel=1e-5)
    assert float(s["omega_std"]) == pytest.approx(1.0)
    assert float(s["v_mean"]) == pytest.approx(0.3)


def test_steps_after_the_end_are_masked():
    n = 50
    log = straight(0.1, n=n)
    alive = np.arange(n) < 20
    pose = np.asarray(log.pose).copy()
    pose[20:] = [1e3, 7.0, 3.0]  # garbage after the end
    pose[25] = np.nan
    cmd = np.asarray(log.cmd).copy()
    cmd[20:] = 99.0
    log = log.replace(pose=jnp.asarray(pose), cmd=jnp.asarray(cmd), alive=jnp.asarray(alive),
                      reason=jnp.asarray(M.TIMEOUT), steps=jnp.asarray(20))
    s = summarise(log, DT)
    assert float(s["mae"]) == pytest.approx(0.1, abs=1e-6)
    assert float(s["max_offset"]) == pytest.approx(0.1, abs=1e-6)
    assert float(s["v_mean"]) == pytest.approx(0.5) and float(s["omega_std"]) == 0.0
    assert float(s["path_ratio"]) == pytest.approx(1.0, abs=1e-4)
    assert not bool(s["success"]) and np.isnan(float(s["time"]))


def test_batched_summary_and_reasons():
    logs = [straight(0.0, reason=M.GOAL), straight(0.2, reason=M.COLLISION)]
    batch = jax.tree.map(lambda *x: jnp.stack(x), *logs)
    s = summarise(batch, DT)
    np.testing.assert_allclose(np.asarray(s["mae"]), [0.0, 0.2], atol=1e-6)
    assert np.asarray(s["success"]).tolist() == [True, False]
    assert np.asarray(s["collision"]).tolist() == [False, True]
    assert A.reason_counts(s["reason"]) == dict(goal=1, collision=1, timeout=0, flipped=0,
                                                stuck=0, sim_error=0, off_patch=0,
                                                missed_goal=0)


def test_aggregate_mean_and_ci():
    x = np.array([1.0, 2.0, 3.0, 4.0])
    agg = A.aggregate({"mae": x, "time": np.array([1.0, np.nan, 3.0]),
                       "success": np.array([True, True, False, True]), "reason": x})
    # t_{0.975, 3} = 3.18245, s = 1.29099, √4 = 2
    half = 3.182446 * 1.290994 / 2
    assert agg["mae"]["mean"] == pytest.approx(2.5)
    assert agg["mae"]["lo"] == pytest.approx(2.5 - half, rel=1e-4)
    assert agg["mae"]["hi"] == pytest.approx(2.5 + half, rel=1e-4)
    assert agg["time"]["n"] == 2 and agg["time"]["mean"] == pytest.approx(2.0)
    # Wilson interval for 3/4 at z = 1.95996: (0.30064, 0.95441)
    assert agg["success"]["mean"] == pytest.approx(0.75)
    assert agg["success"]["lo"] == pytest.approx(0.30064, abs=1e-4)
    assert agg["success"]["hi"] == pytest.approx(0.95441, abs=1e-4)
    assert "reason" not in agg


HALF = jnp.array([0.254, 0.215])


@pytest.mark.parametrize("centre, axes, yaw, expected", [
    ((0.303, 0.0), (0.05, 0.05), 0.0, True),  # 0.254 + 0.05 > 0.303
    ((0.305, 0.0), (0.05, 0.05), 0.0, False),
    ((0.300, 0.0), (0.05, 0.05), math.pi / 2, False),  # turned: 0.215 + 0.05 < 0.300
    ((0.0, 0.300), (0.05, 0.05), math.pi / 2, True),  # now 0.254 + 0.05 > 0.300
    ((0.314, 0.275), (0.10, 0.10), 0.0, True),  # corner 0.0849 m from the centre
    ((0.314, 0.275), (0.08, 0.08), 0.0, False),  # boxes overlap, shapes do not
    ((0.0, 0.0), (0.01, 0.01), 0.3, True),  # ellipse inside the rectangle
    ((0.0, 0.0), (2.0, 2.0), 0.3, True),  # rectangle inside the ellipse
    ((0.0, 0.5), (0.5, 0.29), 0.0, True),  # flat ellipse: reaches y = 0.21 ... 0.215
    ((0.0, 0.5), (0.5, 0.28), 0.0, False),
])
def test_rect_ellipse_overlap(centre, axes, yaw, expected):
    hit = M.rect_ellipse_overlap(jnp.zeros(2), jnp.asarray(yaw), HALF, jnp.asarray(centre),
                                 jnp.asarray(axes))
    assert bool(hit) == expected


@pytest.fixture(scope="module")
def vineyard():
    params = F.make_params("vineyard", terrain_length=14.0, row_length=10.0, terrain_width=10.0,
                           plant_jitter=0.0, p_missing=0.0)
    shape = F.fit_shape(params, "vineyard")
    return jax.jit(F.generate, static_argnums=1)(params, shape, jax.random.key(0))


def test_collides_with_a_trunk_not_in_the_lane(vineyard):
    f = vineyard
    lane = int(F.robot_lane(f))
    ly = float(f.lane_y[lane])
    row = lane + 1  # the row left of the lane
    px, py = (float(v) for v in f.plant_pos[row, 4, :2])
    collides = jax.jit(M.collides, static_argnums=2)
    assert not bool(collides(jnp.array([px, ly, 0.0]), f, "vineyard"))
    # the footprint's left edge at 0.215 m; the trunk radius is 0.045 m
    assert bool(collides(jnp.array([px, py - 0.215 - 0.04, 0.0]), f, "vineyard"))
    assert not bool(collides(jnp.array([px, py - 0.215 - 0.05, 0.0]), f, "vineyard"))
    # between two trunks (1 m apart) a robot half as long fits through the row
    assert not bool(collides(jnp.array([px + 0.5, py, 0.0]), f, "vineyard"))
    assert not bool(collides(jnp.array([px + 0.5, py, math.pi / 2]), f, "vineyard"))
    assert bool(collides(jnp.array([px + 0.25, py, 0.0]), f, "vineyard"))


def test_failed_episodes_are_excluded_not_averaged():
    """An episode with no valid step, a flipped one and one whose last step is a sim_error with a
    finite exploded pose: flagged `excluded`, trajectory metrics NaN, so the cell's mean is the
    good episodes' and `n` counts them; the sim_error step's pose never enters a metric."""
    n = 40
    good = straight(0.1, n=n, reason=M.GOAL)
    empty = straight(0.0, n=n, reason=M.TIMEOUT, alive=np.zeros(n, bool))
    flipped = straight(0.3, n=n, reason=M.FLIPPED)
    exploded = straight(0.1, n=n, reason=M.SIM_ERROR)
    pose = np.asarray(exploded.pose).copy()
    pose[-1] = [pose[-2, 0], 35.0, 0.0]  # finite but exploded: 35 m sideways
    exploded = exploded.replace(pose=jnp.asarray(pose))
    collided = straight(0.2, n=n, reason=M.COLLISION)  # a failure, not a broken trajectory
    batch = jax.tree.map(lambda *x: jnp.stack(x), good, empty, flipped, exploded, collided)
    s = jax.tree.map(np.asarray, summarise(batch, DT))
    assert s["excluded"].tolist() == [False, True, True, True, False]
    for k in [m.name for m in M.METRICS.values() if m.trajectory]:
        assert np.isnan(s[k][1:4]).all(), k
        assert np.isfinite(s[k][[0, 4]]).all(), k
    # the same sim_error episode, not flagged: the exploded step would be out of its metrics
    kept = summarise(exploded.replace(reason=jnp.asarray(M.TIMEOUT)), DT)
    assert float(kept["max_offset"]) == pytest.approx(0.1, abs=1e-6)
    agg = A.aggregate(s)
    assert agg["mae"]["n"] == 2 and agg["mae"]["mean"] == pytest.approx(0.15, abs=1e-6)
    assert agg["excluded"]["mean"] == pytest.approx(3 / 5)


def test_intervals_stay_in_the_metric_range():
    """A t interval of a non-negative metric with a large spread would cross 0: clipped."""
    agg = A.aggregate({"mse": np.array([0.0, 0.0, 0.003]), "path_ratio": np.array([1.0, 1.0, 2.0]),
                       "cha": np.array([3.1, -3.1, 3.1])})
    assert agg["mse"]["lo"] == 0.0 and agg["mse"]["hi"] > 0.003
    assert agg["path_ratio"]["lo"] == 1.0
    assert -math.pi <= agg["cha"]["lo"] and agg["cha"]["hi"] <= math.pi
    for a in agg.values():
        assert a["lo"] <= a["mean"] <= a["hi"]
