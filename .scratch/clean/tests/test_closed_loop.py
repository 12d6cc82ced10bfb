"""The perception loop (closed_loop): one cached policy per architecture, the segmenter's
weights as traced params (shared by the batch, never baked into the program), hand-computed
SegZeros commands from a stand-in segmenter whose mask is a column ramp."""

import flax.linen as nn
import jax
import jax.numpy as jnp
import numpy as np
import pytest

from mjxrow import control as K
from mjxrow import field as F
from mjxrow import render
from mjxrow.field.lanes import straight_lane
from mjxrow.physics import sim
from mjxrow.policies import perception as CL
from mjxrow.rollout import build as B
from mjxrow.rollout import episode as E
from mjxrow.rollout import step as rollout_step

N = 2
INTR = render.Intrinsics(40, 8, 42.0)
FLAT = dict(terrain_length=10.0, row_length=6.0, terrain_width=10.0, terrain_dh=0.0,
            stone_density=0.0, branch_density=0.0, p_missing=0.0)
GAINS = K.seg_params("zeros", omega_gain=1.0)  # |ω| = |d|/(w/2): no clipping below 1 rad/s


class Ramp(nn.Module):
    """Stand-in segmenter: logit w·(column − c) at every pixel, so with threshold 0.5 the
    plants are the columns right of c (w > 0) or left of it (w < 0)."""

    scale: float = 1.0  # another value is another architecture

    @nn.compact
    def __call__(self, rgb, train=False):
        w = self.param("w", nn.initializers.ones, ())
        c = self.param("c", nn.initializers.zeros, ())
        cols = jnp.arange(rgb.shape[2], dtype=jnp.float32)
        return jnp.broadcast_to(self.scale * w * (cols - c), rgb.shape[:3])


def weights(w, c):
    return {"params": {"w": jnp.float32(w), "c": jnp.float32(c)}}


# On a 40-column image: w = +1, c = 23.5: plants in columns 24..39, the free run 0..23 has its
# centre at x_c = 12, d/(w/2) = (12 − 20)/20 = −0.4: ω = +0.4 (turn left), v = 1 − 0.16 → 0.5.
# w = −1, c = 15.5: plants in 0..15, free 16..39, x_c = 28, d/(w/2) = +0.4: ω = −0.4.
LEFT, RIGHT = weights(1.0, 23.5), weights(-1.0, 15.5)


@pytest.fixture(scope="module")
def world():
    params = jax.tree.map(lambda x: jnp.broadcast_to(x, (N,)), F.make_params("vineyard", **FLAT))
    shape = F.fit_shape(params, "vineyard")
    gen = B.generate_fn()
    fields = gen(params, shape, jax.random.split(jax.random.key(0), N))
    return shape, fields


def test_one_policy_per_architecture(world):
    shape, _ = world
    a = CL.perception_policy("segzeros", shape, INTR, "learned", Ramp())
    assert a is CL.perception_policy("segzeros", shape, INTR, "learned", Ramp())
    assert a is not CL.perception_policy("segzeros", shape, INTR, "learned", Ramp(scale=2.0))
    gt = CL.perception_policy("segzeros", shape, INTR)
    assert gt is CL.perception_policy("segzeros", shape, INTR, "ground_truth")
    assert gt is not a
    with pytest.raises(ValueError, match="source: unknown 'lidar'"):
        CL.perception_policy("segzeros", shape, INTR, "lidar")
    with pytest.raises(ValueError, match="controller: 'oracle' takes no mask"):
        CL.perception_policy("oracle", shape, INTR)
    with pytest.raises(ValueError, match="segmenter: source 'learned' needs a segmenter"):
        CL.perception_policy("segmin", shape, INTR, "learned")
    with pytest.raises(ValueError, match="threshold: must lie in"):
        CL.perception_params("sunny", 1.5)


def test_weights_are_params_of_one_compiled_step(world):
    shape, fields = world
    field = jax.tree.map(lambda x: x[0], fields)
    y = field.lane_y[F.robot_lane(field)]
    cam_pos = jnp.stack([field.row_x[1] - 3.0, y, jnp.float32(0.4)])
    obs = K.Obs(pose=jnp.stack([cam_pos[0], y, jnp.float32(0.0)]),
                lane=straight_lane(y, field.row_x[1]), goal=jnp.stack([field.row_x[1], y]),
                cam_pos=cam_pos, cam_rot=render.camera_rot(jnp.float32(0.0), -0.17),
                field=field)
    policy = CL.perception_policy("segzeros", shape, INTR, "learned", Ramp())
    traces = []

    def act(params, state, obs, key):
        traces.append(1)
        return policy.act(params, state, obs, key)

    act = jax.jit(act)
    for w, omega in ((LEFT, 0.4), (RIGHT, -0.4)):
        params = (CL.perception_params("sunny", 0.5, w), GAINS)
        state, cmd = act(params, policy.init(params), obs, jax.random.key(0))
        np.testing.assert_allclose(np.asarray(cmd), [0.5, omega], atol=1e-5)
        assert not bool(state.end_of_row)
    assert len(traces) == 1  # new weights: same compiled step
    # the threshold is traced too: no sigmoid exceeds 1, so no plant pixel; the free run is the
    # whole width (> 0.8·w): end of the row, drive straight on
    params = (CL.perception_params("sunny", 1.0, LEFT), GAINS)
    state, cmd = act(params, policy.init(params), obs, jax.random.key(0))
    assert bool(state.end_of_row) and np.asarray(cmd).tolist() == [0.5, 0.0]
    assert len(traces) == 1


def test_rollout_takes_weights_as_shared_arguments(world):
    """Lowering the batched rollout for two checkpoints of one architecture traces once, and
    the weights are arguments of the program, not constants in it."""
    shape, fields = world
    cfg = rollout_step.EpisodeConfig(crop="vineyard", max_time=5 / 15,
                                     sim=sim.SimConfig(path_length=3.0))
    _, mx = sim.make_model(shape, cfg.sim)
    policy = CL.perception_policy("segzeros", shape, INTR, "learned", Ramp())
    keys = jax.random.split(jax.random.key(1), N)
    gains = E.stack_params([GAINS] * N)
    fn = E.compiled(policy, cfg, CL.PARAMS_AXES)
    traces0 = E.TRACES
    texts = []
    for w in (weights(1.0, 123.25), weights(-1.0, 77.75)):
        perc = E.stack_params([CL.perception_params(c, 0.5, w) for c in ("sunny", "cloudy")],
                              CL.PARAMS_AXES[0])
        assert perc.variables is w and perc.threshold.shape == (N,)  # shared, not stacked
        args = E.rollout_args(mx, fields, None, keys, (perc, gains), CL.PARAMS_AXES)
        texts.append(fn.lower(*args).as_text())
    assert E.TRACES == traces0 + 1
    assert texts[0] == texts[1]
    assert "123.25" not in texts[0] and "1.232500e+02" not in texts[0]
