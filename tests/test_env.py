"""The training environment: reset / step under jit and vmap on a tiny field, a new world per
reset, one control step shared with the evaluator (the same commands through both give the same
episode), an oracle episode of the environment ending where `rollout.episode` ends it with the
same metrics, reward signs on hand-made states, the randomisation ranges' checks, and the
wrappers on a toy environment (Brax conventions: truncation, steps, auto-reset to a new world).

One tiny configuration (vineyard, 2 rows of 11 plants, 16 × 16 images, no shadows) and one
compiled reset and step serve the module."""

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from mjxrow import control
from mjxrow import env as E
from mjxrow import field as F
from mjxrow.env import randomize as RZ
from mjxrow.env import reward as RW
from mjxrow.field.lanes import straight_lane
from mjxrow.rollout import episode as EP
from mjxrow.rollout import metrics as M
from mjxrow.rollout.config import build_run

TINY = {"preset": "vineyard", "controller.name": "oracle", "field.terrain_length": 14.0,
        "field.row_length": 10.0, "field.terrain_width": 5.0, "field.stone_density": 0.0,
        "field.branch_density": 0.0, "field.terrain_dh": 0.05, "camera.width": 16,
        "camera.height": 16, "sim.path_length": 3.0, "episode.max_time": 10.0,
        "render.shadows": False}
RANGES = (("d_RR", 2.5, 2.9), ("terrain_dh", 0.0, 0.1))


@pytest.fixture(scope="module")
def tiny():
    run = build_run(TINY)
    env = E.Env(run, E.EnvConfig(randomize=E.Randomize(ranges=RANGES, start_progress=0.0,
                                                      start_offset_std=0.0,
                                                      start_yaw_std_deg=0.0)))
    return env, jax.jit(jax.vmap(env.reset)), jax.jit(jax.vmap(env.step))


def test_reset_step_jit_vmap(tiny):
    env, reset, step = tiny
    assert env.shape.max_rows >= 2 and env.n_steps == 150
    s = reset(jax.random.split(jax.random.key(0), 2))
    assert s.obs["image"].shape == (2, 16, 16, 3) and s.obs["image"].dtype == jnp.uint8
    assert s.obs["proprio"].shape == (2, 4)
    np.testing.assert_array_equal(s.obs["proprio"], 0.0)  # at rest, no previous action
    # every reset draws its own world: the sampled row spacing differs and lies in its range
    d = np.asarray(s.data.field.params.d_RR)
    assert d[0] != d[1] and np.all((d >= 2.5) & (d <= 2.9))
    np.testing.assert_allclose(s.data.field.lane_width[np.arange(2), s.data.lane], d,
                               rtol=1e-5)
    t = np.asarray(s.info["teacher_action"])
    np.testing.assert_allclose(t[:, 0], 1.0)  # the oracle drives at v_max
    assert np.all(np.abs(t) <= 1.0)
    s2 = step(s, jnp.tile(jnp.array([1.0, 0.0]), (2, 1)))
    assert s2.obs["image"].shape == (2, 16, 16, 3)
    np.testing.assert_array_equal(s2.done, 0.0)
    np.testing.assert_array_equal(s2.data.t, 1)
    assert np.all(np.asarray(s2.data.sim.data.qpos[:, 0]) > np.asarray(s.data.sim.data.qpos[:, 0]))
    np.testing.assert_allclose(s2.obs["proprio"][:, 2:], [[1.0, 0.0]] * 2)  # previous action
    assert np.all(np.isfinite(np.asarray(s2.reward)))
    for k in RW.TERMS:
        assert f"reward/{k}" in s2.metrics


def _scatters(jaxpr, out):
    """(origin file, eqn) of every scatter in `jaxpr` and its sub-jaxprs; the origin is the
    first frame outside JAX (the line that indexed)."""
    for e in jaxpr.eqns:
        if e.primitive.name.startswith("scatter"):
            frames = [f.file_name for f in e.source_info.traceback.frames
                      if "/jax/" not in f.file_name and "/jaxlib/" not in f.file_name]
            out.append((frames[0] if frames else "", e))
        for p in e.params.values():
            for q in p if isinstance(p, (list, tuple)) else [p]:
                sub = getattr(q, "jaxpr", q)
                if hasattr(sub, "eqns"):
                    _scatters(sub, out)
    return out


def test_training_step_scatters_unique_indices(tiny):
    # Under XLA's deterministic ops (the GPU default) a scatter that may repeat an index
    # becomes a serial loop over its updates. Every scatter of the project's own code in the
    # training step (the auto-reset merge of every state leaf, the renderer's deep pass, the
    # obstacle and contact slots) has unique indices, integer adds (exact in any order) aside;
    # with that the step runs at 0.97x its speed without deterministic ops (H100, B = 2,048).
    env = E.AutoResetWrapper(E.VmapWrapper(E.EpisodeWrapper(tiny[0])), 4, 2)
    st = jax.eval_shape(env.reset, jax.random.key(0))
    jaxpr = jax.make_jaxpr(env.step)(st, jnp.zeros((4, 2))).jaxpr
    ours = [(f, e) for f, e in _scatters(jaxpr, []) if "/mjxrow/" in f]
    assert len(ours) > 100  # the merge of every leaf, the obstacles, the log, ...
    bad = [(f, e.primitive.name, e.invars[0].aval) for f, e in ours
           if not e.params["unique_indices"]
           and not (e.primitive.name == "scatter-add"
                    and jnp.issubdtype(e.invars[0].aval.dtype, jnp.integer))]
    assert not bad, bad


@pytest.mark.slow  # minutes of CPU compilation (trainer / episode programs)
def test_episode_matches_rollout_episode(tiny):
    """The oracle driving the environment ends its episode at the step and with the reason
    and metrics that rollout.episode gives for the same field and start."""
    env, reset, step = tiny
    s = reset(jax.random.split(jax.random.key(1), 2))
    for _ in range(env.n_steps):
        s = step(s, s.info["teacher_action"])
        if np.all(np.asarray(s.done) > 0):
            break
    assert np.all(np.asarray(s.done) > 0)
    fields = s.data.field
    policy = control.as_policy("oracle")
    run = env.run
    ref = EP.compiled(policy, env.episode, 0)(
        env.mx, fields, s.data.lane, jax.random.split(jax.random.key(2), 2),
        EP.batch_noise(None, 2), EP.stack_params([run.controller_params()] * 2))
    assert list(np.asarray(ref.reason)) == [M.GOAL, M.GOAL]
    np.testing.assert_array_equal(s.data.log.reason, ref.reason)
    assert np.all(np.abs(np.asarray(s.data.t) - np.asarray(ref.steps)) <= 1)
    ours = M.summarise(s.data.log, env.dt)
    theirs = M.summarise(ref, env.dt)
    for k in ("success", "mae", "cha", "omega_std"):
        np.testing.assert_allclose(ours[k], theirs[k], atol=2e-3, err_msg=k)
    np.testing.assert_array_equal(s.metrics["nav/success"], 1.0)
    np.testing.assert_allclose(s.metrics["nav/mae"], ours["mae"])
    # a done world stays as it is when stepped again (until a wrapper resets it)
    again = step(s, jnp.zeros((2, 2)))
    np.testing.assert_array_equal(again.data.t, s.data.t)
    np.testing.assert_array_equal(again.reward, 0.0)


def test_reward_toward_goal_beats_away(tiny):
    env, reset, step = tiny
    s = reset(jax.random.split(jax.random.key(3), 2))
    fwd = step(s, jnp.tile(jnp.array([1.0, 0.0]), (2, 1)))
    back = step(s, jnp.tile(jnp.array([-1.0, 0.0]), (2, 1)))
    assert np.all(np.asarray(fwd.reward) > np.asarray(back.reward))
    assert np.all(np.asarray(fwd.metrics["reward/progress"]) > 0)
    assert np.all(np.asarray(back.metrics["reward/progress"]) < 0)


def test_reward_terms_on_hand_made_states():
    cfg = RW.RewardConfig()
    lane_y, dt = straight_lane(1.0, 20.0), 1.0 / 15
    p0 = jnp.array([0.0, 1.0, 0.0])
    toward = RW.terms(p0, jnp.array([0.03, 1.0, 0.0]), lane_y, jnp.int32(M.RUNNING), dt)
    away = RW.terms(p0, jnp.array([-0.03, 1.0, 0.0]), lane_y, jnp.int32(M.RUNNING), dt)
    assert RW.total(cfg, toward) > RW.total(cfg, away)
    np.testing.assert_allclose(toward["progress"], 0.03, rtol=1e-5)
    p = jnp.array([0.03, 1.0, 0.0])
    none = RW.total(cfg, RW.terms(p0, p, lane_y, jnp.int32(M.RUNNING), dt))
    hit = RW.total(cfg, RW.terms(p0, p, lane_y, jnp.int32(M.COLLISION), dt))
    goal = RW.total(cfg, RW.terms(p0, p, lane_y, jnp.int32(M.GOAL), dt))
    fail = RW.total(cfg, RW.terms(p0, p, lane_y, jnp.int32(M.MISSED_GOAL), dt))
    np.testing.assert_allclose(none - hit, cfg.w_collision, rtol=1e-5)
    assert hit < none < goal and fail < none
    off = RW.terms(p0, jnp.array([0.03, 1.2, 0.0]), lane_y, jnp.int32(M.RUNNING), dt)
    np.testing.assert_allclose(off["lateral"], -0.2 * dt, rtol=1e-5)  # 0.2 m off for dt
    turned = RW.terms(p0, jnp.array([0.03, 1.0, -0.3]), lane_y, jnp.int32(M.RUNNING), dt)
    np.testing.assert_allclose(turned["heading"], -0.3 * dt, rtol=1e-5)
    nan = RW.terms(p0, jnp.full(3, jnp.nan), lane_y, jnp.int32(M.SIM_ERROR), dt)
    assert all(np.isfinite(float(v)) for v in nan.values()) and float(nan["failure"]) == -1


def test_randomize_ranges_checked_and_sampled():
    base = F.make_params("vineyard", terrain_width=5.0, terrain_length=14.0, row_length=10.0)
    shape = F.fit_shape(RZ.corner_params(base, RANGES), "vineyard")
    RZ.check_ranges(base, RANGES, shape)
    with pytest.raises(ValueError, match=r"env.randomize.ranges: terrain_width: .* d_RR=3.5"):
        RZ.check_ranges(base, (("d_RR", 2.5, 3.5),), shape)
    with pytest.raises(ValueError, match="env.randomize.ranges: 'd_xx'"):
        E.Randomize(ranges=(("d_xx", 0.0, 1.0),))
    with pytest.raises(ValueError, match="env.randomize.ranges.d_RR: need lo <= hi"):
        E.Randomize(ranges=(("d_RR", 3.0, 2.0),))
    ps = jax.vmap(lambda k: RZ.sample_params(base, RANGES, k))(
        jax.random.split(jax.random.key(0), 256))
    d = np.asarray(ps.d_RR)
    assert d.min() >= 2.5 and d.max() <= 2.9 and d.max() - d.min() > 0.3
    np.testing.assert_array_equal(ps.d_pp, base.d_pp)  # not ranged: the run's value
    # every preset's default ranges are valid fields in the preset's own shape fitting
    for preset in RZ.RANGES:
        b = F.make_params(preset)
        r = RZ.default_ranges(preset)
        RZ.check_ranges(b, r, F.fit_shape(RZ.corner_params(b, r), preset))


# ---------------------------------------------------------------------------------------------
# Wrappers on a toy environment: x grows by the action each step; the episode ends at x ≥ 3.


class _Toy:
    def reset(self, rng):
        x0 = jax.random.uniform(rng)
        z = jnp.float32(0.0)
        return E.State(data={"x": x0, "x0": x0}, obs={"x": x0}, reward=z, done=z,
                       metrics={"x": x0}, info={"teacher_action": jnp.zeros(2),
                                                "truncation": z})

    def reset_world(self, rng):
        return self.reset(rng)

    def observe(self, state):
        return state.replace(obs={"x": state.data["x"]})

    def advance(self, state, action):
        x = state.data["x"] + action[0]
        done = (x >= 3.0).astype(jnp.float32)
        return state.replace(data={**state.data, "x": x}, reward=action[0], done=done,
                             metrics={"x": x})

    def expired(self, state):
        return state.replace(data={**state.data, "x": jnp.full_like(state.data["x"], 3.0)})

    def step(self, state, action):
        return self.observe(self.advance(state, action))


@pytest.mark.parametrize("max_resets", [None, 1, 2])  # all, overflow, the gathered few
def test_wrappers_truncate_and_reset_to_new_worlds(max_resets):
    B = 4
    env = E.AutoResetWrapper(E.VmapWrapper(E.EpisodeWrapper(_Toy(), episode_length=5)), B,
                             max_resets)
    s = jax.jit(env.reset)(jax.random.key(0))
    x0 = np.asarray(s.data["x0"])
    step = jax.jit(env.step)
    # worlds 0, 1 step by 1 (done at the 3rd step), worlds 2, 3 by 0 (truncated at the 5th)
    a = jnp.array([[1.0, 0], [1.0, 0], [0.0, 0], [0.0, 0]])
    seen = []
    for _ in range(5):
        s = step(s, a)
        seen.append((np.asarray(s.done).copy(), np.asarray(s.info["truncation"]).copy(),
                     np.asarray(s.info["steps"]).copy(), np.asarray(s.data["x0"]).copy()))
    done3, trunc3, steps3, x03 = seen[2]
    np.testing.assert_array_equal(done3, [1, 1, 0, 0])
    np.testing.assert_array_equal(trunc3, 0)
    np.testing.assert_array_equal(steps3, [0, 0, 3, 3])  # the new episodes start at 0
    assert np.all(x03[:2] != x0[:2]) and np.all(x03[2:] == x0[2:])  # new worlds
    np.testing.assert_array_equal(s.obs["x"], s.data["x"])  # observed after the resets
    done5, trunc5, _, _ = seen[4]
    np.testing.assert_array_equal(done5, [0, 0, 1, 1])
    np.testing.assert_array_equal(trunc5, [0, 0, 1, 1])  # time limit: truncation


@pytest.mark.parametrize("max_resets", [None, 1])
def test_a_first_step_replaces_every_blank_world(max_resets):
    """`blank` has `reset`'s tree and shapes, zeros but for the clock and the keys; the first
    step ends every blank episode and resets every world to a new one (observed after the
    resets, steps 0), in one pass or several; the next step goes on as after `reset`."""
    B = 3
    env = E.AutoResetWrapper(E.VmapWrapper(E.EpisodeWrapper(_Toy(), episode_length=5)), B,
                             max_resets)
    key = jax.random.key(1)
    b = jax.jit(env.blank)(key)
    r = jax.eval_shape(env.reset, key)
    assert jax.tree.structure(b) == jax.tree.structure(r)
    assert [(x.shape, x.dtype) for x in jax.tree.leaves(b)] == \
        [(x.shape, x.dtype) for x in jax.tree.leaves(r)]
    np.testing.assert_array_equal(b.obs["x"], 0.0)
    s = jax.jit(env.step)(b, jnp.zeros((B, 2)))
    np.testing.assert_array_equal(s.done, 1.0)
    np.testing.assert_array_equal(s.info["steps"], 0)
    x0 = np.asarray(s.data["x0"])
    assert np.all((x0 > 0) & (x0 < 1)) and len(set(x0.tolist())) == B  # new worlds, each its own
    np.testing.assert_array_equal(s.obs["x"], x0)
    s2 = jax.jit(env.step)(s, jnp.full((B, 2), 0.5))
    np.testing.assert_array_equal(s2.done, 0.0)
    np.testing.assert_array_equal(s2.info["steps"], 1)
    np.testing.assert_allclose(s2.data["x"], x0 + 0.5)


def test_an_expired_world_ends_at_its_next_step(tiny):
    """`Env.expired` sets the episode clock to its time limit: the next step ends each episode
    (the blank worlds a trainer's first rollout replaces rely on it, whatever they hold)."""
    env, reset, step = tiny
    s = env.expired(reset(jax.random.split(jax.random.key(0), 2)))
    np.testing.assert_array_equal(s.data.t, env.n_steps)
    s = step(s, jnp.zeros((2, 2)))
    np.testing.assert_array_equal(s.done, 1.0)
    np.testing.assert_array_equal(s.data.log.reason, M.TIMEOUT)


FRACTIONS = jnp.array([[1.0, 0.125], [1.0, 0.125], [1.0, -0.125], [1.0, -0.125]], jnp.float32)


def _act(params, state, obs, key):
    """The fraction of the limits `params` for step `state` (cycling through FRACTIONS)."""
    del obs, key
    return state + 1, FRACTIONS[state % FRACTIONS.shape[0]] * params


REPLAY = control.Policy(init=lambda params: jnp.int32(0), act=_act)


def test_episode_and_env_share_the_step(tiny):
    """The same field, start and commands driven through `rollout.episode` (the sweep's loop)
    and through `Env.step` give the same end event at the same step, the same commands and
    events, and the same trajectory and metrics: both call `rollout.step.step`. The commands
    are exact in both units (v = v_max, ω = ±ω_max / 8: powers of two of the limits), so the
    environment's action scaling adds no rounding of its own. The two are different XLA
    programs (a loop of chunks against one jitted step), which may round differently: poses
    agree to 1e-5 m and velocities to 1e-4 m/s, not to the bit."""
    env, reset, step = tiny
    s = reset(jax.random.split(jax.random.key(5), 2))
    for t in range(env.n_steps):
        s = step(s, jnp.tile(FRACTIONS[t % FRACTIONS.shape[0]], (2, 1)))
        if np.all(np.asarray(s.done) > 0):
            break
    ours = s.data.log
    theirs = EP.compiled(REPLAY, env.episode)(
        env.mx, s.data.field, s.data.lane, jax.random.split(jax.random.key(2), 2),
        EP.batch_noise(None, 2), env.limits)
    np.testing.assert_array_equal(ours.steps, theirs.steps)
    assert np.all(np.asarray(ours.steps) < env.n_steps)  # ends before the timeout
    assert np.all(np.asarray(ours.reason) != M.RUNNING)
    np.testing.assert_array_equal(ours.reason, theirs.reason)
    n = int(np.max(np.asarray(ours.steps)))
    alive = np.asarray(ours.alive)[:, :n]
    np.testing.assert_array_equal(alive, np.asarray(theirs.alive)[:, :n])
    for k in ("cmd", "event"):
        np.testing.assert_array_equal(np.where(alive[..., None] if k == "cmd" else alive,
                                               getattr(ours, k)[:, :n], 0),
                                      np.where(alive[..., None] if k == "cmd" else alive,
                                               getattr(theirs, k)[:, :n], 0), err_msg=k)
    for k, atol in (("pose", 1e-5), ("vel", 1e-4)):
        np.testing.assert_allclose(getattr(ours, k)[:, :n], getattr(theirs, k)[:, :n], atol=atol,
                                   err_msg=k)
    np.testing.assert_allclose(ours.start, theirs.start, atol=1e-6)
    a, b = (M.summarise(log, env.dt) for log in (ours, theirs))
    for k in a:
        np.testing.assert_allclose(a[k], b[k], rtol=1e-4, atol=1e-5, err_msg=k)


class _PoolToy(_Toy):
    """The toy whose reset takes x0 from `given` (a pooled field) where it is not NaN."""

    def reset_world(self, rng, given=None):
        s = self.reset(rng)
        if given is None:
            return s
        x0 = jnp.where(jnp.isnan(given[0]), s.data["x0"], given[0])
        return s.replace(data={"x": x0, "x0": x0})


@pytest.mark.parametrize("max_resets", [64, 32])  # the whole batch, the gathered few
def test_pool_puts_its_share_into_every_batch_of_resets(max_resets):
    """A pool of searched values (here x0 = -10 - row) goes into the given share of a reset
    batch, exactly for the whole batch (16 of 64) and to the rounding of share · n for the
    worlds that end together; an empty pool, or share 0, leaves every reset to the draw."""
    B = 64
    pool = RZ.make_pool(np.array([[-10.0], [-11.0], [-12.0]]), size=8, share=0.25)
    assert int(pool.count) == 3 and np.isnan(np.asarray(pool.values)[3:]).all()
    env = E.AutoResetWrapper(E.VmapWrapper(E.EpisodeWrapper(_PoolToy())), B, max_resets)
    s = jax.jit(env.reset)(jax.random.key(0), pool)
    x0 = np.asarray(s.data["x0"])
    pooled = x0 <= -10.0
    assert pooled.sum() == 16 and set(np.unique(x0[pooled])) <= {-10.0, -11.0, -12.0}
    assert len(np.unique(x0[pooled])) > 1  # random rows of the pool
    assert np.all(x0[~pooled] >= 0.0)  # the others drawn (uniform in [0, 1))
    # half the worlds end at once (x ≥ 3): ⌊0.25 · 32 + u⌋ = 8 of their resets are pooled
    step = jax.jit(env.step)
    a = jnp.where(jnp.arange(B)[:, None] % 2 == 0, jnp.array([20.0, 0.0]), 0.0)
    s2 = step(s, a, pool)
    new = np.asarray(s2.done) > 0
    assert new.sum() == 32
    assert (np.asarray(s2.data["x0"])[new] <= -10.0).sum() == 8
    for empty in (RZ.make_pool(np.zeros((0, 1)), 8, 0.25),
                  RZ.make_pool(np.array([[-10.0]]), 8, 0.0)):
        assert np.all(np.asarray(jax.jit(env.reset)(jax.random.key(1), empty).data["x0"])
                      >= 0.0)
    with pytest.raises(ValueError, match="share: must lie in"):
        RZ.make_pool(np.zeros((1, 1)), 4, 1.5)


def test_a_pooled_reset_takes_its_field_values_and_its_sun(tiny):
    """A reset's `given` row (`pool_keys`: the ranged field values, then the sun's azimuth)
    replaces those draws where it is not NaN: the field value, and the sun turned to the
    azimuth at the elevation drawn; an all-NaN row is the plain draw."""
    env = tiny[0]
    assert RZ.pool_keys(env.ranges) == ("field.d_RR", "field.terrain_dh",
                                        "perception.sun_azimuth")
    reset = jax.jit(env.reset_world)
    key = jax.random.key(5)
    drawn, nan = reset(key), reset(key, jnp.full(3, jnp.nan))
    for a, b in zip(jax.tree.leaves((drawn.data.field, drawn.data.cond)),
                    jax.tree.leaves((nan.data.field, nan.data.cond)), strict=True):
        np.testing.assert_array_equal(a, b)
    given = reset(key, jnp.array([2.6, jnp.nan, 80.0]))
    np.testing.assert_allclose(given.data.field.params.d_RR, 2.6)
    np.testing.assert_array_equal(given.data.field.params.terrain_dh,
                                  drawn.data.field.params.terrain_dh)
    sun, sun0 = np.asarray(given.data.cond.sun_dir), np.asarray(drawn.data.cond.sun_dir)
    assert np.degrees(np.arctan2(sun[1], sun[0])) == pytest.approx(80.0, abs=1e-3)
    assert sun[2] == pytest.approx(sun0[2]) and np.linalg.norm(sun) == pytest.approx(1.0)
    np.testing.assert_array_equal(given.data.cond.sun_rgb, drawn.data.cond.sun_rgb)


def test_the_shadow_strength_is_drawn_in_its_range():
    """`shadow_strength` (lo, hi): each reset's cast shadows at a strength uniform in it; the
    default (1, 1) keeps full shadows and every other draw as it was; out of [0, 1] refused."""
    key = jax.random.key(4)
    full = RZ.sample_condition(RZ.Randomize(), key)
    keys = jax.random.split(key, 64)
    drawn = jax.vmap(lambda k: RZ.sample_condition(RZ.Randomize(shadow_strength=(0.2, 0.6)),
                                                   k))(keys)
    s = np.asarray(drawn.shadow)
    assert float(full.shadow) == 1.0 and s.min() >= 0.2 and s.max() <= 0.6 and s.std() > 0.05
    np.testing.assert_array_equal(drawn.sun_dir[0], np.asarray(
        RZ.sample_condition(RZ.Randomize(), keys[0]).sun_dir))  # the other draws unchanged
    for bad in ((0.5, 0.2), (-0.1, 1.0), (0.0, 1.5)):
        with pytest.raises(ValueError, match=r"^env.randomize.shadow_strength: need \[lo, hi\]"):
            RZ.Randomize(shadow_strength=bad)


def test_given_values_replace_the_draw_within_the_ranges():
    base = F.make_params("vineyard", terrain_width=5.0, terrain_length=14.0, row_length=10.0)
    key = jax.random.key(3)
    drawn = RZ.sample_params(base, RANGES, key)
    given = RZ.sample_params(base, RANGES, key, jnp.array([2.6, jnp.nan]))
    np.testing.assert_allclose(given.d_RR, 2.6)
    np.testing.assert_array_equal(given.terrain_dh, drawn.terrain_dh)  # NaN: drawn
    clipped = RZ.sample_params(base, RANGES, key, jnp.array([9.0, -1.0]))
    np.testing.assert_allclose([clipped.d_RR, clipped.terrain_dh], [2.9, 0.0])
