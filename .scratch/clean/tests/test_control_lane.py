"""SegZeros' end-of-row "lane" mode: follow the line driven inside the row (odometry), against
hand-computed commands; inside the row identical to "straight"."""

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from mjxrow import control as C
from mjxrow.field.lanes import straight_lane
from mjxrow.sweep import config as CFG

H, W = 4, 40
LANE = C.seg_params("zeros", on_end="lane", lane_alpha=0.02, lane_xy_alpha=0.1,
                    lane_k_yaw=1.5, lane_k_lat=1.0)
STRAIGHT = C.seg_params("zeros", on_end="straight")


def mask_with_free(*spans):
    m = np.ones((H, W), bool)
    for a, b in spans:
        m[:, a:b] = False
    return jnp.asarray(m)


ROW, END = mask_with_free((15, 25)), mask_with_free()  # a centred lane; the row's end


def obs(mask, pose):
    return C.Obs(pose=jnp.asarray(pose, jnp.float32), lane=straight_lane(0.0, 20.0),
                 goal=jnp.asarray([20.0, 0.0]),
                 cam_pos=jnp.zeros(3), cam_rot=jnp.eye(3), mask=mask)


seg_act = jax.jit(C.seg_act)
lane_command = jax.jit(C.lane_command)


def omega(pose, lane_yaw=0.0, lane_xy=(0.0, 0.0), params=LANE):
    return float(lane_command(params, jnp.asarray(pose, jnp.float32), jnp.float32(lane_yaw),
                              jnp.asarray(lane_xy, jnp.float32)))


def test_lane_command_signs():
    # line y = 0 driven towards +x: left of it (y > 0) turns right, right of it turns left
    assert omega((5.0, 0.3, 0.0)) == pytest.approx(-0.3)  # −1.0·0.3
    assert omega((5.0, -0.3, 0.0)) == pytest.approx(0.3)
    assert omega((5.0, 0.0, 0.0)) == 0.0  # on the line, heading along it
    assert omega((-7.0, 0.0, 0.0), lane_xy=(3.0, 0.0)) == 0.0  # anywhere along it
    assert omega((5.0, 0.0, 0.1)) == pytest.approx(-0.15)  # heading left: −1.5·0.1
    assert omega((5.0, 0.3, -0.2)) == pytest.approx(0.0, abs=1e-6)  # converging: the terms cancel
    assert omega((5.0, 2.0, 0.0)) == -1.0  # clipped to omega_limit
    # line x = 1 driven towards +y (yaw π/2): its left is −x
    assert omega((0.7, 4.0, np.pi / 2), np.pi / 2, (1.0, 0.0)) == pytest.approx(-0.3, abs=1e-6)
    assert omega((1.3, 4.0, np.pi / 2), np.pi / 2, (1.0, 0.0)) == pytest.approx(0.3, abs=1e-6)
    # line y = 0 driven towards −x (yaw π), its left is −y; the robot's yaw reads −π + 0.1
    # (0.1 rad left of the line's direction) and it is at y = −0.3: ω = −1.5·0.1 − 1.0·0.3
    assert omega((-5.0, -0.3, -np.pi + 0.1), np.pi) == pytest.approx(-0.45, abs=1e-5)


def test_lane_estimate_and_freeze():
    state = C.seg_init(LANE)
    state, cmd = seg_act(LANE, state, obs(ROW, (0.0, 0.2, 0.1)))  # the first pose is taken
    np.testing.assert_allclose(np.asarray(state.lane_xy), [0.0, 0.2], atol=1e-7)
    assert float(state.lane_yaw) == pytest.approx(0.1) and bool(state.has_ref)
    np.testing.assert_allclose(np.asarray(cmd), [0.5, 0.0], atol=1e-6)  # in the row: SegZeros
    state, _ = seg_act(LANE, state, obs(ROW, (1.0, -0.8, -0.4)))  # EMAs: yaw 0.02, xy 0.1
    np.testing.assert_allclose(np.asarray(state.lane_xy), [0.1, 0.1], atol=1e-6)
    assert float(state.lane_yaw) == pytest.approx(0.1 - 0.02 * 0.5, abs=1e-6)
    assert float(state.yaw_ref) == pytest.approx(0.1 - float(LANE.heading_alpha) * 0.5, abs=1e-6)
    frozen = (np.asarray(state.lane_xy), float(state.lane_yaw), float(state.yaw_ref))
    # the row ends: the line freezes; ω = −1.5·(0 − 0.09) − 1.0·e_lat, e_lat of (2, 0.1)
    # from the line through (0.1, 0.1) with direction 0.09 rad
    state, cmd = seg_act(LANE, state, obs(END, (2.0, 0.1, 0.0)))
    assert bool(state.end_of_row)
    np.testing.assert_allclose(np.asarray(state.lane_xy), frozen[0])
    assert (float(state.lane_yaw), float(state.yaw_ref)) == frozen[1:]
    e_lat = -np.sin(0.09) * 1.9
    np.testing.assert_allclose(np.asarray(cmd), [0.5, 1.5 * 0.09 - e_lat], atol=1e-5)
    state, _ = seg_act(LANE, state, obs(END, (3.0, 1.0, 0.5)))
    np.testing.assert_allclose(np.asarray(state.lane_xy), frozen[0])
    assert float(state.lane_yaw) == frozen[1]
    # no line measured yet: straight on with ω = 0
    _, cmd = seg_act(LANE, C.seg_init(LANE), obs(END, (0.0, 0.5, 0.3)))
    np.testing.assert_allclose(np.asarray(cmd), [0.5, 0.0], atol=1e-6)


def _drive(params, masks, poses):
    def body(state, x):
        state, cmd = C.seg_act(params, state, obs(*x))
        return state, (cmd, state.end_of_row)

    return jax.jit(lambda m, p: jax.lax.scan(body, C.seg_init(params), (m, p)))(masks, poses)


def test_inside_the_row_identical_to_straight():
    rng = np.random.default_rng(0)
    n = 40
    spans = rng.integers(0, 20, n)
    masks = jnp.stack([mask_with_free((a, a + 12)) if i < 30 else END
                       for i, a in enumerate(spans)])
    poses = jnp.asarray(np.c_[np.linspace(0, 3, n), rng.normal(0, 0.2, n),
                              rng.normal(0, 0.1, n)], jnp.float32)
    _, (cmd_l, end_l) = _drive(LANE, masks, poses)
    _, (cmd_s, end_s) = _drive(STRAIGHT, masks, poses)
    cmd_l, cmd_s, end = np.asarray(cmd_l), np.asarray(cmd_s), np.asarray(end_l)
    assert np.array_equal(end, np.asarray(end_s)) and not end[:30].any() and end[30:].all()
    assert np.array_equal(cmd_l[:30], cmd_s[:30])  # bit for bit inside the row
    assert np.all(cmd_l[30:, 0] == 0.5) and not np.allclose(cmd_l[30:, 1], cmd_s[30:, 1])


def test_lane_converges_on_a_unicycle():
    # the row ended with the robot 0.3 m left of the line y = 0.1 and heading 0.1 rad away
    state = C.seg_init(LANE).replace(lane_yaw=jnp.float32(0.0),
                                     lane_xy=jnp.asarray([0.0, 0.1], jnp.float32),
                                     has_ref=jnp.bool_(True))
    dt = 1.0 / 15.0

    def body(carry, _):
        state, pose = carry
        state, cmd = C.seg_act(LANE, state, obs(END, pose))
        v, w = cmd[0], cmd[1]
        pose = pose + dt * jnp.stack([v * jnp.cos(pose[2]), v * jnp.sin(pose[2]), w])
        return (state, pose), pose

    _, poses = jax.jit(lambda s, p: jax.lax.scan(body, (s, p), None, length=150))(
        state, jnp.asarray([0.0, 0.4, 0.1], jnp.float32))
    y = np.asarray(poses)[:, 1]  # 10 s, 5 m
    assert abs(y[-1] - 0.1) < 0.01
    assert np.min(y) > 0.1 - 0.02  # (nearly) no overshoot: damping 1.06
    assert abs(y[60] - 0.1) < 0.1  # after 4 s (2 m)


def test_vmap_over_worlds():
    p = LANE
    states = jax.vmap(lambda _: C.seg_init(p))(jnp.arange(3))
    states = states.replace(has_ref=jnp.ones(3, bool), lane_yaw=jnp.zeros(3),
                            lane_xy=jnp.zeros((3, 2)), end_of_row=jnp.ones(3, bool))
    poses = jnp.asarray([[5.0, 0.3, 0.0], [5.0, -0.3, 0.0], [5.0, 0.0, 0.0]])
    o = jax.vmap(lambda pose: obs(END, pose))(poses)
    _, cmd = jax.jit(jax.vmap(C.seg_act, in_axes=(None, 0, 0)))(p, states, o)
    np.testing.assert_allclose(np.asarray(cmd)[:, 1], [-0.3, 0.3, 0.0], atol=1e-6)


def test_lane_params_and_config():
    for kw in (dict(lane_alpha=0.0), dict(lane_alpha=1.5)):
        with pytest.raises(ValueError, match="lane_alpha"):
            C.seg_params("zeros", **kw)
    with pytest.raises(ValueError, match="lane_xy_alpha"):
        C.seg_params("zeros", lane_xy_alpha=0.0)
    with pytest.raises(ValueError, match="lane_k_lat"):
        C.seg_params("zeros", lane_k_lat=-1.0)
    assert "lane" in C.ON_END
    cfg = CFG.from_dict({"controller": {"on_end": "lane"}})
    assert cfg.controller.on_end == "lane"
    with pytest.raises(CFG.ConfigError, match="controller.on_end"):
        CFG.from_dict({"controller": {"on_end": "lanes"}})
