"""Controllers on hand-made masks and poses, against hand-computed commands."""

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from mjxrow import control as C
from mjxrow.control.segzeros import heading_reference
from mjxrow.field.lanes import straight_lane

H, W = 4, 40
PAPER = C.seg_params("zeros")
HOLD01 = C.seg_params("zeros", heading_alpha=0.1)  # on_end "straight", short heading EMA


def mask_with_free(*spans, h=H, w=W):
    """Plants everywhere except the column spans [a, b) given."""
    m = np.ones((h, w), bool)
    for a, b in spans:
        m[:, a:b] = False
    return jnp.asarray(m)


def obs(mask=None, depth=None, pose=(0.0, 0.0, 0.0), lane_y=0.0):
    return C.Obs(pose=jnp.asarray(pose, jnp.float32), lane=straight_lane(lane_y, 20.0),
                 goal=jnp.asarray([20.0, lane_y]),
                 cam_pos=jnp.zeros(3), cam_rot=jnp.eye(3), mask=mask, depth=depth)


seg_command = jax.jit(C.seg_command)
seg_act = jax.jit(C.seg_act)


def test_free_runs():
    free = jnp.array([1, 1, 0, 1, 1, 1, 0, 0, 1], bool)
    assert C.free_runs(free).tolist() == [0, 2, 0, 0, 0, 3, 0, 0, 1]


def test_free_lane_left_turns_left():
    # free columns 14..21: x_c = 18, d/(w/2) = −0.1 → ω = 0.3, v = 0.99 → clipped 0.5
    cmd, end = seg_command(PAPER, mask_with_free((14, 22)))
    np.testing.assert_allclose(np.asarray(cmd), [0.5, 0.3], atol=1e-6)
    assert not bool(end)
    cmd, _ = seg_command(PAPER, mask_with_free((18, 26)))  # right of centre: turn right
    np.testing.assert_allclose(np.asarray(cmd), [0.5, -0.3], atol=1e-6)
    # far left: x_c = 4, d/(w/2) = −0.8: ω = 2.4 → clipped 1 rad/s, v = 1 − 0.64 = 0.36
    cmd, _ = seg_command(PAPER, mask_with_free((0, 8)))
    np.testing.assert_allclose(np.asarray(cmd), [0.36, 1.0], atol=1e-6)


def test_centred_lane_goes_straight():
    cmd, end = seg_command(PAPER, mask_with_free((15, 25)))
    assert float(cmd[1]) == 0.0 and float(cmd[0]) == pytest.approx(0.5)
    assert not bool(end)
    # unclipped speed law: v = v_max·(1 − d²/(w/2)²) with v_max = 1, d/(w/2) = −0.5 → 0.75
    slow = C.seg_params("zeros", v_limit=5.0)
    cmd, _ = seg_command(slow, mask_with_free((6, 14)))
    assert float(cmd[0]) == pytest.approx(0.75)


def test_end_of_row():
    for m in (mask_with_free(), mask_with_free((0, W))):  # all plant; all free (> 0.8·w)
        cmd, end = seg_command(PAPER, m)
        assert bool(end)
        np.testing.assert_allclose(np.asarray(cmd), [0.5, 0.0])  # on_end="straight"
    _, end = seg_command(PAPER, mask_with_free((0, 32)))  # exactly 0.8·w is still a lane
    assert not bool(end)
    cmd, end = seg_command(C.seg_params("zeros", on_end="stop"), mask_with_free())
    assert bool(end) and np.asarray(cmd).tolist() == [0.0, 0.0]


def test_end_of_row_holds_the_in_row_heading():
    lane, end_mask = mask_with_free((15, 25)), mask_with_free()  # centred lane; row end
    # heading EMA factor 0.1 (the default, 0.005, averages over ~13 s)
    state = C.seg_init(HOLD01)
    assert not bool(state.has_ref)
    state, cmd = seg_act(HOLD01, state, obs(lane, pose=(0.0, 0.0, 0.1)))  # first yaw taken
    assert float(state.yaw_ref) == pytest.approx(0.1) and bool(state.has_ref)
    np.testing.assert_allclose(np.asarray(cmd), [0.5, 0.0], atol=1e-6)
    state, _ = seg_act(HOLD01, state, obs(lane, pose=(0.0, 0.0, 0.2)))  # EMA: 0.1 + 0.1·0.1
    assert float(state.yaw_ref) == pytest.approx(0.11, abs=1e-6)
    # the row ends: the reference freezes, ω = −3·(0.2 − 0.11) = −0.27 turns back to it
    state, cmd = seg_act(HOLD01, state, obs(end_mask, pose=(0.0, 0.0, 0.2)))
    assert bool(state.end_of_row) and float(state.yaw_ref) == pytest.approx(0.11, abs=1e-6)
    np.testing.assert_allclose(np.asarray(cmd), [0.5, -0.27], atol=1e-5)
    state, cmd = seg_act(HOLD01, state, obs(end_mask, pose=(0.0, 0.0, -0.5)))  # 1.83 → 1.0
    np.testing.assert_allclose(np.asarray(cmd), [0.5, 1.0], atol=1e-6)
    assert float(state.yaw_ref) == pytest.approx(0.11, abs=1e-6)
    # "hold" keeps the last command instead; no reference yet: straight with ω = 0
    hold = C.seg_params("zeros", on_end="hold")
    s2, _ = seg_act(hold, C.seg_init(hold), obs(mask_with_free((14, 22))))
    _, cmd = seg_act(hold, s2, obs(end_mask, pose=(0.0, 0.0, 0.3)))
    np.testing.assert_allclose(np.asarray(cmd), [0.5, 0.3], atol=1e-6)
    _, cmd = seg_act(HOLD01, C.seg_init(HOLD01), obs(end_mask, pose=(0.0, 0.0, 0.3)))
    np.testing.assert_allclose(np.asarray(cmd), [0.5, 0.0], atol=1e-6)


def test_heading_reference_across_pi():
    # ref 3.1, yaw −3.1 (0.0832 rad further on, across ±π): ref 3.1 + 0.1·0.0832, not a jump
    state = C.seg_init(HOLD01).replace(yaw_ref=jnp.float32(3.1), has_ref=jnp.bool_(True))
    ref = heading_reference(HOLD01, state, jnp.float32(-3.1), jnp.bool_(False))
    assert float(ref) == pytest.approx(3.1 + 0.1 * (2 * np.pi - 6.2), abs=1e-5)
    assert float(C.wrap_angle(jnp.float32(3 * np.pi / 2))) == pytest.approx(-np.pi / 2)
    with pytest.raises(ValueError, match="heading_alpha"):
        C.seg_params("zeros", heading_alpha=0.0)


def test_three_column_gap_is_ignored():
    _, end = seg_command(PAPER, mask_with_free((5, 8)))  # only a 3-column gap
    assert bool(end)
    # a 3-column gap far left and a 6-column lane centred at x_c = 23: steer right, ω = −0.45
    cmd, end = seg_command(PAPER, mask_with_free((1, 4), (20, 26)))
    assert not bool(end)
    np.testing.assert_allclose(np.asarray(cmd), [0.5, -0.45], atol=1e-6)
    cmd, _ = seg_command(PAPER, mask_with_free((5, 9)))  # 4 columns count: x_c = 7
    np.testing.assert_allclose(np.asarray(cmd)[1], 1.0)  # −3·(7 − 20)/20 = 1.95 → 1.0
    # the longest run wins over a shorter one
    cmd, _ = seg_command(PAPER, mask_with_free((2, 8), (22, 30)))  # x_c = 26
    np.testing.assert_allclose(np.asarray(cmd)[1], -0.9, atol=1e-6)


def test_public_variant_law_and_ema():
    p = C.seg_params("zeros", "public", n_frames=1)
    # free 6..13: x_c = 10, d/(w/2) = −0.5, K = 0.25: ω = 3·0.25 = 0.75, v = 0.75 → 0.5
    m = mask_with_free((6, 14))
    state = C.seg_init(p)
    state, cmd = seg_act(p, state, obs(m))
    np.testing.assert_allclose(np.asarray(cmd), [0.25, 0.375], atol=1e-6)  # α = 0.5 from 0
    state, cmd = seg_act(p, state, obs(m))
    np.testing.assert_allclose(np.asarray(cmd), [0.375, 0.5625], atol=1e-6)
    cmd, _ = seg_command(p, mask_with_free((26, 34)))  # x_c = 30: same magnitude, turn right
    np.testing.assert_allclose(np.asarray(cmd), [0.5, -0.75], atol=1e-6)


def test_public_variant_or_of_three_frames():
    p = C.seg_params("zeros", "public", ema_alpha=1.0, image_hw=(H, W))
    a = mask_with_free((0, 24))  # plants in columns 24..39
    b = mask_with_free((8, 40))  # plants in columns 0..7
    empty = mask_with_free((0, W))
    state = C.seg_init(p)
    state, _ = seg_act(p, state, obs(a))
    # a | b: free 8..23, x_c = 16, d/(w/2) = −0.2, K = 0.04, ω = +0.12 (b alone would give −0.12)
    state, cmd = seg_act(p, state, obs(b))
    np.testing.assert_allclose(np.asarray(cmd)[1], 0.12, atol=1e-6)
    state, cmd = seg_act(p, state, obs(empty))  # a | b | empty: the same
    np.testing.assert_allclose(np.asarray(cmd)[1], 0.12, atol=1e-6)
    state, cmd = seg_act(p, state, obs(empty))  # a dropped: b | empty | empty
    np.testing.assert_allclose(np.asarray(cmd)[1], -0.12, atol=1e-6)
    state, _ = seg_act(p, state, obs(empty))  # only empty masks left
    assert bool(state.end_of_row)


def test_depth_cut():
    p = C.seg_params("zeros", "public", n_frames=1, ema_alpha=1.0)
    m = mask_with_free((10, 30))
    depth = np.full((H, W), 2.0, np.float32)
    depth[:, 30:] = 6.0  # the right plants are beyond 5 m: ignored
    cmd, _ = seg_command(p, m, jnp.asarray(depth))
    # free 10..39: x_c = 25, d/(w/2) = 0.25, K = 0.0625: ω = −0.1875
    np.testing.assert_allclose(np.asarray(cmd)[1], -0.1875, atol=1e-6)
    cmd, _ = seg_command(p, m, jnp.full((H, W), 2.0))
    assert float(cmd[1]) == 0.0


def test_segmin():
    p = C.seg_params("min")
    cmd, end = seg_command(p, mask_with_free((10, 30)))
    assert not bool(end) and float(cmd[1]) == 0.0
    # free 5..24; after an 11-wide average the minimum spans 10..19: x_c = 15 → ω = 0.75
    cmd, _ = seg_command(p, mask_with_free((5, 25)))
    np.testing.assert_allclose(np.asarray(cmd), [0.5, 0.75], atol=1e-6)
    _, end = seg_command(p, mask_with_free((0, W)))  # no plant at all
    assert bool(end)


def test_vmap_over_a_batch_of_masks():
    masks = jnp.stack([mask_with_free((14, 22)), mask_with_free((18, 26)),
                       mask_with_free()])
    cmd, end = jax.vmap(seg_command, in_axes=(None, 0))(PAPER, masks)
    np.testing.assert_allclose(np.asarray(cmd)[:, 1], [0.3, -0.3, 0.0], atol=1e-6)
    assert np.asarray(end).tolist() == [False, False, True]


def test_oracle_steers_back_to_the_centre_line():
    p = C.oracle_params(lookahead=1.0)
    # 0.3 m left of the line: target (√0.91, −0.3), κ = 2·(−0.3)/1 → ω = 0.5·(−0.6) = −0.3
    cmd = C.pursuit_command(p, jnp.array([3.0, 1.3, 0.0]), straight_lane(1.0, 20.0))
    np.testing.assert_allclose(np.asarray(cmd), [0.5, -0.3], atol=1e-6)
    cmd = C.pursuit_command(p, jnp.array([3.0, 0.7, 0.0]), straight_lane(1.0, 20.0))
    np.testing.assert_allclose(np.asarray(cmd), [0.5, 0.3], atol=1e-6)
    cmd = C.pursuit_command(p, jnp.array([3.0, 1.0, 0.2]), straight_lane(1.0, 20.0))  # left
    assert float(cmd[1]) < 0
    cmd = C.pursuit_command(p, jnp.array([3.0, 1.0, 0.0]), straight_lane(1.0, 20.0))
    assert float(cmd[1]) == 0.0


def test_oracle_converges_on_a_unicycle():
    p = C.oracle_params()
    policy = C.as_policy("oracle")
    assert policy is C.as_policy("oracle")
    dt = 1.0 / 15.0

    def body(pose, _):
        _, cmd = policy(p, (), obs(pose=pose, lane_y=1.0), None)
        v, w = cmd[0], cmd[1]
        pose = pose + dt * jnp.stack([v * jnp.cos(pose[2]), v * jnp.sin(pose[2]), w])
        return pose, pose[1]

    _, y = jax.jit(lambda p0: jax.lax.scan(body, p0, None, length=300))(
        jnp.array([0.0, 1.4, -0.3]))
    y = np.asarray(y)
    assert abs(y[-1] - 1.0) < 0.01
    assert np.max(np.abs(y - 1.0)) < 0.45  # no wild overshoot


def test_with_perception_feeds_the_mask_controller():
    def perceive(p, o, key):  # stands in for render → segment
        return p["mask"], None

    policy = C.with_perception("segzeros", perceive)
    params = ({"mask": mask_with_free((14, 22))}, PAPER)
    state = policy.init(params)
    state, cmd = jax.jit(policy.act)(params, state, obs(), jax.random.key(0))
    np.testing.assert_allclose(np.asarray(cmd), [0.5, 0.3], atol=1e-6)
    assert not bool(state.end_of_row)
    with pytest.raises(ValueError, match="mask"):
        C.seg_act(PAPER, C.seg_init(PAPER), obs())
