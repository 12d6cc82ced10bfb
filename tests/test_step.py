"""One control step for the evaluator and the training environment: the same field, start and
commands driven through `rollout.episode` (the sweep's loop) and through `env.Env.step` give the
same end event at the same step, the same commands and events, and the same trajectory and
metrics, because both call `rollout.step.step`. The two are different XLA programs (a loop of
chunks against one jitted step), which may round differently: poses and velocities agree to
1e-5, not to the bit.

The commands are exact in both units (v = v_max, ω = ±ω_max / 8: powers of two of the
limits), so the environment's action scaling adds no rounding of its own."""

import jax
import jax.numpy as jnp
import numpy as np

from mjxrow import control
from mjxrow import env as mjxrow_env
from mjxrow.rollout import episode as rollout_episode
from mjxrow.rollout import metrics as rollout_metrics
from mjxrow.rollout.config import build_run

TINY = {"preset": "vineyard", "controller.name": "oracle", "field.terrain_length": 14.0,
        "field.row_length": 10.0, "field.terrain_width": 5.0, "field.stone_density": 0.0,
        "field.branch_density": 0.0, "field.terrain_dh": 0.05, "camera.width": 16,
        "camera.height": 16, "sim.path_length": 3.0, "episode.max_time": 10.0,
        "render.shadows": False}
FRACTIONS = jnp.array([[1.0, 0.125], [1.0, 0.125], [1.0, -0.125], [1.0, -0.125]], jnp.float32)


def _act(params, state, obs, key):
    """The fraction of the limits `params` for step `state` (cycling through FRACTIONS)."""
    del obs, key
    return state + 1, FRACTIONS[state % FRACTIONS.shape[0]] * params


REPLAY = control.Policy(init=lambda params: jnp.int32(0), act=_act)


def test_episode_and_env_share_the_step():
    run = build_run(TINY)
    env = mjxrow_env.Env(run, mjxrow_env.EnvConfig(randomize=mjxrow_env.Randomize(
        ranges=(("d_RR", 2.7, 2.7),), start_progress=0.0, start_offset_std=0.0,
        start_yaw_std_deg=0.0)))
    s = jax.jit(jax.vmap(env.reset))(jax.random.split(jax.random.key(5), 1))
    step = jax.jit(jax.vmap(env.step))
    for t in range(env.n_steps):
        s = step(s, FRACTIONS[t % FRACTIONS.shape[0]][None])
        if np.all(np.asarray(s.done) > 0):
            break
    ours = s.data.log
    theirs = rollout_episode.compiled(REPLAY, env.episode)(
        env.mx, s.data.field, s.data.lane, jax.random.split(jax.random.key(2), 1),
        rollout_episode.batch_noise(None, 1), env.limits)
    n = int(np.asarray(theirs.steps)[0])
    assert n == int(np.asarray(ours.steps)[0]) and n < env.n_steps  # an end before the timeout
    assert int(np.asarray(ours.reason)[0]) != rollout_metrics.RUNNING
    np.testing.assert_array_equal(ours.reason, theirs.reason)
    for k in ("cmd", "alive", "event"):
        np.testing.assert_array_equal(getattr(ours, k)[:, :n], getattr(theirs, k)[:, :n], err_msg=k)
    for k in ("pose", "vel"):
        np.testing.assert_allclose(getattr(ours, k)[:, :n], getattr(theirs, k)[:, :n], atol=1e-5,
                                   err_msg=k)
    np.testing.assert_allclose(ours.start, theirs.start, atol=1e-6)
    a, b = (rollout_metrics.summarise(log, env.dt) for log in (ours, theirs))
    for k in a:
        np.testing.assert_allclose(a[k], b[k], rtol=1e-4, atol=1e-5, err_msg=k)

