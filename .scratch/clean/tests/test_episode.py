"""Batched episodes: one compiled call for 8 different fields, no retrace on new FieldParams,
the oracle drives a 20 m lane, every termination reason the flat field can provoke.

One policy and one static config serve the default tests, so the module compiles once."""

import dataclasses

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from mjxrow import control as C
from mjxrow import crops
from mjxrow import field as F
from mjxrow.physics import sim
from mjxrow.rollout import build as RB
from mjxrow.rollout import episode as E
from mjxrow.rollout import loop as L
from mjxrow.rollout import metrics as M
from mjxrow.rollout import step as rollout_step

B = 8
SHAPE = F.FieldShape(crop="vineyard", max_rows=8, max_plants_per_row=32, terrain_cells=(56, 112),
                     obstacle_slots=8)
FLAT = dict(terrain_length=26.0, row_length=22.0, terrain_width=12.0, terrain_dh=0.0,
            stone_density=0.0, branch_density=0.0, p_missing=0.0)
CFG = rollout_step.EpisodeConfig(crop="vineyard", max_time=640 / 15)  # 640 steps, 20 m, goal 0.40 m
ORACLE = C.oracle_params()


def _test_act(params, state, obs, key):
    """params = (oracle params, shared; per-episode dict): mode 0: the oracle; mode 1: hold
    heading yaw_target at speed v."""
    oracle_p, p = params
    _, oracle = C.oracle_act(oracle_p, state, obs)
    hold = jnp.stack([p["v"], jnp.clip(2.0 * (p["yaw"] - obs.pose[2]), -1.0, 1.0)])
    return state, jnp.where(p["mode"] == 0, oracle, hold)


POLICY = C.Policy(init=lambda p: (), act=_test_act)
AXES = (None, 0)  # oracle gains shared by the batch, the rest per episode


def policy_params(mode, v=0.0, yaw=0.0, oracle=ORACLE):
    def arr(x):
        return jnp.broadcast_to(jnp.asarray(x, jnp.float32), (B,))

    return oracle, {"mode": arr(mode), "v": arr(v), "yaw": arr(yaw)}


generate = RB.generate_fn()


def make_fields(seed, **varied):
    params = F.make_params("vineyard", **FLAT)
    params = jax.tree.map(lambda x: jnp.broadcast_to(x, (B,)), params).replace(
        **{k: jnp.asarray(v, jnp.float32) for k, v in varied.items()})
    F.validate(params, SHAPE)
    return generate(params, SHAPE, jax.random.split(jax.random.key(seed), B))


@pytest.fixture(scope="module")
def setup():
    _, mx = sim.make_model(SHAPE, CFG.sim)
    fields = make_fields(0, d_rr=np.linspace(2.4, 3.0, B), d_RR=np.linspace(2.4, 3.0, B),
                         d_pp=np.linspace(0.9, 1.2, B))
    traces0 = E.TRACES
    log = E.rollout(mx, fields, None, jax.random.split(jax.random.key(1), B), POLICY,
                    policy_params(0), CFG, params_axes=AXES)
    return mx, fields, jax.tree.map(np.asarray, log), E.TRACES - traces0


def test_eight_fields_in_one_call(setup):
    _, fields, log, traces = setup
    assert traces == 1
    assert log.pose.shape == (B, CFG.n_steps, 3) and log.reason.shape == (B,)
    widths = np.asarray(jax.vmap(lambda f: f.lane_width[F.robot_lane(f)])(fields))
    assert len(np.unique(np.round(widths, 4))) == B  # eight different fields
    # each episode starts 20 m before its lane's end, on its lane's centre line
    np.testing.assert_allclose(log.goal[:, 0] - log.start[:, 0], 20.0, atol=1e-4)
    np.testing.assert_allclose(log.start[:, 1], log.lane_y, atol=1e-4)


def test_oracle_drives_the_lane(setup):
    _, _, log, _ = setup
    s = jax.tree.map(np.asarray, E.summarise(log, CFG))
    assert s["success"].all(), M.REASONS[int(s["reason"][np.argmin(s["success"])])]
    assert not s["collision"].any()
    assert (s["mae"] < 0.05).all(), s["mae"]
    # 19.6 m at 0.5 m/s is 39.2 s; the robot needs a few tenths of a second to accelerate
    assert ((s["time"] > 39.2) & (s["time"] < 40.0)).all(), s["time"]
    assert (np.abs(s["path_ratio"] - 1.0) < 0.01).all()


# -m slow (.ci/slow): 35 s of CPU compilation of the unchunked loop
@pytest.mark.slow
def test_early_stop_matches_stepping_every_step(setup, monkeypatch):
    mx, fields, log, _ = setup
    assert (log.steps < CFG.n_steps - E.CHUNK).all()  # every episode ends chunks early
    monkeypatch.setattr(L, "CHUNK", CFG.n_steps)  # one chunk: a plain scan over every step
    args = E.rollout_args(mx, fields, None, jax.random.split(jax.random.key(1), B),
                          policy_params(0), AXES)
    one = lambda *a: E.episode(*a[:5], POLICY, a[5], CFG)  # noqa: E731
    full = jax.jit(jax.vmap(one, in_axes=(None, 0, 0, 0, 0, AXES)))(*args)
    full = jax.tree.map(np.asarray, full)
    for name in ("alive", "event", "reason", "steps"):
        np.testing.assert_array_equal(getattr(log, name), getattr(full, name))
    np.testing.assert_array_equal(log.pose, full.pose)  # NaN after the end in both
    alive = log.alive[..., None]
    np.testing.assert_array_equal(np.where(alive, log.cmd, 0), np.where(alive, full.cmd, 0))


def test_step_traced_once_and_prepare_once_per_episode(setup):
    """The batch's loop runs the vmapped step: the policy's act is traced once (not again for
    the output shapes, and the loops are never batched afterwards); its `prepare` runs outside
    the step loop, once per episode, and what it returns reaches every step."""
    mx, fields, _, _ = setup
    acts, prepares = [], []

    def prepare(params, field):  # traced once; the value differs per field
        prepares.append(1)
        return {"v": 0.1 * field.params.d_rr, "fields": 1}

    def act(params, state, obs, key):
        acts.append(1)
        return state, jnp.stack([obs.aux["v"], jnp.float32(0.0)])

    cfg = dataclasses.replace(CFG, max_time=2.0)  # 30 steps
    log = E.rollout(mx, fields, None, jax.random.split(jax.random.key(1), B),
                    C.Policy(lambda p: (), act, prepare), (), cfg)
    assert len(acts) == 1 and len(prepares) == 1
    assert np.asarray(log.alive).all()
    np.testing.assert_allclose(np.asarray(log.cmd[:, :, 0]),
                               np.broadcast_to(0.1 * np.asarray(fields.params.d_rr)[:, None],
                                               (B, 30)), rtol=1e-6)


def test_a_command_of_the_wrong_shape_is_named(setup):
    mx, fields, _, _ = setup
    act = lambda params, state, obs, key: (state, jnp.zeros(3))  # noqa: E731
    with pytest.raises(ValueError, match=r"command must be float \[2\].*\(3,\)"):
        E.rollout(mx, fields, None, jax.random.split(jax.random.key(1), B),
                  C.Policy(lambda p: (), act), (), dataclasses.replace(CFG, max_time=1.0))


def test_new_field_params_do_not_retrace(setup):
    mx, fields, log1, _ = setup
    traces0 = E.TRACES
    fields2 = make_fields(5, d_rr=np.linspace(3.0, 2.5, B), d_RR=np.linspace(3.0, 2.5, B),
                          plant_width=np.linspace(0.4, 0.7, B))
    log2 = E.rollout(mx, fields2, None, jax.random.split(jax.random.key(2), B), POLICY,
                     policy_params(0), CFG, params_axes=AXES)
    assert E.TRACES == traces0
    assert not np.allclose(np.asarray(log2.lane_y), log1.lane_y)
    assert np.asarray(log2.reason == M.GOAL).all()


def test_oracle_drives_curved_lanes_to_the_goal(setup):
    """Arcs bent either way and sinusoids: the same compiled program (curvature is traced)
    drives every lane's centre line to its goal, measured against the curve."""
    mx, _, _, _ = setup
    traces0 = E.TRACES
    fields = make_fields(9, row_curvature=[0.03, -0.03, 0.015, 0.0, 0.0, 0.02, -0.01, 0.0],
                         row_amplitude=[0.0, 0.0, 0.0, 0.3, 0.5, 0.3, 0.2, 0.0],
                         row_wavelength=[10.0, 10.0, 10.0, 12.0, 16.0, 14.0, 20.0, 10.0])
    log = E.rollout(mx, fields, None, jax.random.split(jax.random.key(3), B), POLICY,
                    policy_params(0), CFG, params_axes=AXES)
    assert E.TRACES == traces0
    log = jax.tree.map(np.asarray, log)
    s = jax.tree.map(np.asarray, E.summarise(log, CFG))
    assert s["success"].all(), [M.REASONS[int(r)] for r in s["reason"]]
    assert (s["mae"] < 0.06).all(), s["mae"]
    assert (s["heading_error"] < 0.06).all(), s["heading_error"]
    # the start lies on the centre line, along its direction; the arcs turn the robot
    _, off, direction = F.lanes.project(log.lane, log.start[:, :2])
    np.testing.assert_allclose(off, 0.0, atol=1e-4)
    np.testing.assert_allclose(log.start[:, 2], direction, atol=1e-4)
    assert abs(float(log.start[0, 2])) > 0.2
    # the straight field's lateral offset is measured as before: y − lane_y
    np.testing.assert_allclose(log.goal[7], [float(fields.row_x[7, 1]), log.lane_y[7]])


def test_new_shared_params_do_not_retrace(setup):
    """The shared part (None axis) is traced too: slower oracle gains, same compiled call.
    At 0.4 m/s the 42.7 s timeout comes after about 17 m, before the 20 m lane's end."""
    mx, fields, _, _ = setup
    traces0 = E.TRACES
    log = E.rollout(mx, fields, None, jax.random.split(jax.random.key(1), B), POLICY,
                    policy_params(0, oracle=C.oracle_params(v_max=0.4)), CFG, params_axes=AXES)
    assert E.TRACES == traces0
    log = jax.tree.map(np.asarray, log)
    assert (log.reason == M.TIMEOUT).all(), log.reason
    driven = log.pose[:, -1, 0] - log.start[:, 0]
    assert ((driven > 16.8) & (driven < 17.3)).all(), driven


def test_start_noise_per_episode(setup):
    """Per-episode start-pose noise in the same compiled call: with one key for every episode
    the draws are equal, so the start offsets scale with each episode's std exactly."""
    mx, fields, _, _ = setup
    lat = np.array([0.0, 0.05, 0.1, 0.2, 0.0, 0.0, 0.0, 0.1], np.float32)
    yaw = np.array([0.0, 0.0, 0.0, 0.0, 0.05, 0.1, 0.2, 0.1], np.float32)
    keys = jnp.stack([jax.random.key(7)] * B)
    traces0 = E.TRACES
    log = jax.tree.map(np.asarray, E.rollout(mx, fields, None, keys, POLICY, policy_params(0),
                                             CFG, params_axes=AXES,
                                             noise=sim.PoseNoise(jnp.asarray(lat),
                                                                 jnp.asarray(yaw))))
    assert E.TRACES == traces0
    dy, dyaw = log.start[:, 1] - log.lane_y, log.start[:, 2]
    z_lat, z_yaw = dy[3] / 0.2, dyaw[6] / 0.2
    assert abs(z_lat) > 0.05 and abs(z_yaw) > 0.05, (z_lat, z_yaw)
    np.testing.assert_allclose(dy, lat * z_lat, atol=2e-5)
    np.testing.assert_allclose(dyaw, yaw * z_yaw, atol=2e-5)
    assert (log.reason == M.GOAL).all(), log.reason  # the oracle recovers from every start
    with pytest.raises(ValueError, match="noise.lateral_std: must be finite and non-negative"):
        E.batch_noise(sim.pose_noise(-0.1, 0.0), B)
    with pytest.raises(ValueError, match=r"noise.heading_std: expected a scalar or shape \(8,\)"):
        E.batch_noise(sim.PoseNoise(jnp.float32(0.0), jnp.zeros(3)), B)
    assert E.batch_noise(None, B).lateral_std.tolist() == [0.0] * B


def test_params_axes_are_checked():
    params = ({"w": jnp.ones(3)}, {"g": jnp.ones(B)})
    E.check_params(params, (None, 0), B)
    E.check_params(params, None, B)
    with pytest.raises(ValueError, match=r"policy_params\[0\]\['w'\]: per-episode .* \(3,\)"):
        E.check_params(params, 0, B)
    with pytest.raises(ValueError, match=r"policy_params\[1\]\['g'\]: .* \(\)"):
        E.check_params(({"w": 1.0}, {"g": 2.0}), (None, 0), B)
    with pytest.raises(ValueError, match="params_axes: leaves must be None"):
        E.check_params(params, (None, 1), B)
    with pytest.raises(ValueError, match="not a prefix"):
        E.check_params(params, (None, 0, 0), B)
    # stacking per-episode parts, keeping the shared one as it is
    w = {"w": jnp.arange(3.0)}
    stacked = E.stack_params([(w, {"g": 1.0}), (w, {"g": 2.0})], (None, 0))
    assert stacked[0] is w and stacked[1]["g"].tolist() == [1.0, 2.0]


def test_termination_reasons(setup):
    mx, fields, _, _ = setup
    # ±0.25 rad: the 0.43 m wide swept band meets a trunk row over 0.43 / sin 0.25 = 1.74 m,
    # more than the trunk spacing (≤ 1.2 m), so it cannot slip between two trunks
    q = 0.25
    params = ORACLE, {"mode": jnp.array([1, 1, 1, 1, 1, 1, 0, 1], jnp.float32),
                      "v": jnp.array([0.0, -0.5, jnp.nan, 0.1, 0.5, 0.5, 0.0, 0.5], jnp.float32),
                      "yaw": jnp.array([0.0, 0.0, 0.0, 0.0, q, -q, 0.0, 0.035], jnp.float32)}
    traces0 = E.TRACES
    log = jax.tree.map(np.asarray, E.rollout(mx, fields, None,
                                             jax.random.split(jax.random.key(3), B), POLICY,
                                             params, CFG, params_axes=AXES))
    assert E.TRACES == traces0  # new policy params do not retrace either
    names = [M.REASONS[r] for r in log.reason]
    assert names == ["stuck", "off_patch", "sim_error", "timeout", "collision", "collision",
                     "goal", "missed_goal"]
    assert log.steps[0] == CFG.stuck_window  # not moving: caught at the first check
    assert log.steps[2] == 1 and log.steps[3] == CFG.n_steps
    # the slanted runs end touching a trunk row: half a lane width from the lane centre minus
    # the footprint's lateral reach (0.27 m at 0.25 rad) and the trunk radius (0.045 m)
    lanes = np.asarray(jax.vmap(F.robot_lane)(fields))
    for i, side in ((4, 1.0), (5, -1.0)):
        last = log.pose[i, log.steps[i] - 1]
        width = float(fields.lane_width[i, lanes[i]])
        dev = side * (last[1] - log.lane_y[i])
        assert 0.5 * width - 0.40 < dev < 0.5 * width, (dev, width)
    # masking: alive is a prefix of length steps, the event sits on its last step
    for i in range(B):
        assert log.alive[i, : log.steps[i]].all() and not log.alive[i, log.steps[i]:].any()
        assert log.event[i, log.steps[i] - 1] == log.reason[i]
        assert (np.delete(log.event[i], log.steps[i] - 1) == 0).all()
    s = jax.tree.map(np.asarray, E.summarise(jax.tree.map(jnp.asarray, log), CFG))
    # the sim_error run (its one step exploded) is excluded from the trajectory metrics; every
    # other run, failed or not, keeps them
    assert s["excluded"].tolist() == [False, False, True] + [False] * 5
    assert np.isnan(s["mae"][2]) and np.isfinite(np.delete(s["mae"], 2)).all()
    # heading 0.035 rad: 0.7 m beside the goal at the row's end, ended 0.4 m past its line
    last = log.pose[7, log.steps[7] - 1]
    goal_x = float(fields.row_x[7, 1])
    assert goal_x + 0.4 < last[0] < goal_x + 0.45, (last, goal_x)
    assert 0.55 < last[1] - log.lane_y[7] < 0.8, last
    assert s["success"].tolist() == [False] * 6 + [True, False]
    assert s["collision"].tolist() == [False] * 4 + [True] * 2 + [False] * 2


def test_cli_rejects_bad_input(tmp_path, capsys):
    from mjxrow import episode as cli

    cases = [["--set", "field.d_rr=-1"], ["--set", "nope=1"], ["--set", "field.d_rr=abc"],
             ["--set", "sim.path_length=80"], ["--n", "0"], ["--set", "camera.width=0"],
             ["--set", "episode.start_offset_std=-0.1"], ["--set", "episode.start_yaw_std=.nan"],
             ["--set", "field.d_rr=[2, 3]"],
             ["--controller", "segmin", "--perception", "learned", "--set",
              f"perception.checkpoint={tmp_path / 'no_such_checkpoint'}"]]
    for extra in cases:
        code = cli.main(["--preset", "vineyard", "--out", str(tmp_path), "--no-progress", *extra])
        assert code == 2, extra
        err = capsys.readouterr().err
        assert "error" in err and len(err.strip().splitlines()) == 1, err
    assert not (tmp_path / "episodes.csv").exists()


@pytest.mark.slow
@pytest.mark.parametrize("preset", crops.names())
def test_oracle_every_preset(preset):
    """The oracle drives a 20 m lane of each preset's default geometry on flat terrain."""
    n = 2
    params = F.make_params(preset, terrain_dh=0.0, stone_density=0.0, branch_density=0.0)
    params = jax.tree.map(lambda x: jnp.broadcast_to(x, (n,)), params)
    shape = F.fit_shape(params, preset)
    gen = RB.generate_fn()
    fields = gen(params, shape, jax.random.split(jax.random.key(0), n))
    cfg = rollout_step.EpisodeConfig(crop=preset)
    _, mx = sim.make_model(shape, cfg.sim)
    log = E.rollout(mx, fields, None, jax.random.split(jax.random.key(1), n),
                    C.as_policy("oracle"), C.oracle_params(), cfg)
    s = jax.tree.map(np.asarray, E.summarise(log, cfg))
    assert s["success"].all(), [M.REASONS[r] for r in s["reason"]]
    assert not s["collision"].any() and (s["mae"] < 0.05).all(), s["mae"]


@pytest.mark.slow
def test_cli_writes_episodes_csv(tmp_path, capsys):
    import pandas as pd

    from mjxrow import episode as cli
    from mjxrow.rollout.cli import CSV_METRICS

    assert cli.main(["--preset", "vineyard", "--n", "2", "--seed", "3", "--out", str(tmp_path),
                     "--set", "field.terrain_dh=0.05", "--no-progress"]) == 0
    df = pd.read_csv(tmp_path / "episodes.csv")
    assert df["episode"].tolist() == [0, 1]
    assert set(CSV_METRICS) <= set(df.columns) and set(F.PARAM_NAMES) <= set(df.columns)
    assert np.allclose(df["terrain_dh"], 0.05) and (df["reason"] == "goal").all()
    out = capsys.readouterr().out
    assert "cha [deg]" in out and "95% CI" in out
    # a second run into the folder: refused, then with --overwrite the same episodes again
    again = ["--preset", "vineyard", "--n", "2", "--seed", "3", "--out", str(tmp_path), "--set",
             "field.terrain_dh=0.05", "--no-progress"]
    assert cli.main(again) == 2 and "--overwrite" in capsys.readouterr().err
    assert cli.main([*again, "--overwrite"]) == 0
    assert pd.read_csv(tmp_path / "episodes.csv").equals(df)


@pytest.mark.slow
def test_segzeros_on_rendered_masks_steers_back():
    """Closed loop through the renderer's ground-truth mask: from a lateral offset SegZeros
    turns back toward the lane centre (image column 0 is the left: signs end to end)."""
    from mjxrow import render
    from mjxrow.policies import perception as closed_loop

    n = 2
    params = F.make_params("vineyard", **FLAT)
    params = jax.tree.map(lambda x: jnp.broadcast_to(x, (n,)), params)
    fields = RB.generate_fn()(
        params, SHAPE, jax.random.split(jax.random.key(0), n))
    cfg = rollout_step.EpisodeConfig(crop="vineyard", max_time=200 / 15,
                                     sim=sim.SimConfig(path_length=6.0))
    _, mx = sim.make_model(SHAPE, cfg.sim)
    intr = render.Intrinsics(48, 32, 42.0)
    policy, pparams = closed_loop.make("segzeros", SHAPE, intr)
    cparams = C.seg_params("zeros", image_hw=(32, 48))
    log = jax.tree.map(np.asarray, E.rollout(mx, fields, None,
                                             jax.random.split(jax.random.key(20), n), policy,
                                             (pparams, cparams), cfg,
                                             noise=sim.pose_noise(0.3, 0.0)))
    dev0 = log.start[:, 1] - log.lane_y
    assert dev0[0] > 0.15 and dev0[1] < -0.15, dev0  # these keys start left, then right
    off0 = np.abs(dev0)
    for i in range(n):
        end = np.abs(log.pose[i, log.steps[i] - 1, 1] - log.lane_y[i])
        assert end < 0.5 * off0[i], (off0[i], end)
    assert (log.reason == M.GOAL).all(), log.reason



@pytest.mark.parametrize("n_steps", [20, 25, 60, 150])
def test_bench_counts_the_steps_the_loop_runs(n_steps):
    """The episode loop runs whole chunks (60 steps run 75): `steps_run` says how many, and
    `bench closed_loop` asks for that many, so that its control steps/s count every step
    timed."""
    import argparse

    from mjxrow.bench import closed_loop as CL

    steps = E.steps_run(n_steps)
    shapes = dict(pose=jax.ShapeDtypeStruct((3,), jnp.float32),
                  vel=jax.ShapeDtypeStruct((3,), jnp.float32),
                  cmd=jax.ShapeDtypeStruct(rollout_step.CMD_SHAPE, jnp.float32),
                  alive=jax.ShapeDtypeStruct((), jnp.bool_),
                  event=jax.ShapeDtypeStruct((), jnp.int32))
    ran = []

    def body(carry, t):  # never done; every call that runs is counted on the host
        jax.debug.callback(lambda: ran.append(1))
        out = dict(pose=jnp.zeros(3), vel=jnp.zeros(3), cmd=jnp.zeros(2),
                   alive=jnp.bool_(True), event=jnp.int32(0))
        return carry, out

    carry = (rollout_step.Carry(sim=jnp.int32(0), done=jnp.bool_(False), anchor=jnp.zeros(2)),
             None)
    out = jax.jit(lambda c: E._run_until_done(body, c, n_steps, shapes))(carry)
    jax.block_until_ready(out)
    jax.effects_barrier()
    assert out["alive"].shape == (n_steps,)
    assert len(ran) == steps >= n_steps
    assert (steps == n_steps) == (n_steps <= E.CHUNK or n_steps % E.CHUNK == 0)
    p = argparse.ArgumentParser()
    CL.add_args(p)
    args = p.parse_args(["--steps", str(n_steps), "--image", "16"])
    assert CL.run_config(args).episode.n_steps == steps
