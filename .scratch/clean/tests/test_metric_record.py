"""A metric added from this file alone (one `register(Metric(...))` call) is computed by
`summarise`, reported by the training env and the trainer, and written by a tiny real sweep to
results.csv, summary.csv, its heatmap and report.md: the registry is the only place that names
it."""

import math
import types

import jax
import jax.numpy as jnp
import numpy as np
import pandas as pd
import pytest
from PIL import Image

from mjxrow.env import core as env_core
from mjxrow.field.lanes import straight_lane
from mjxrow.rollout import aggregate as rollout_aggregate
from mjxrow.rollout import metrics as rollout_metrics
from mjxrow.sweep import config as sweep_config
from mjxrow.sweep import figures as sweep_figures
from mjxrow.sweep import run as sweep_run
from mjxrow.train import rollout as train_rollout

DT = 0.1


def _double_time(log, control_dt):
    """Twice the episode's time [s], reached the goal or not."""
    return 2.0 * log.steps * control_dt


TOY = rollout_metrics.Metric("toy_double_time", _double_time, "twice the episode time", "s",
                             "{:.2f}", better="lower", bounds=(0.0, math.inf), train=True)


@pytest.fixture
def toy():
    before = list(rollout_metrics.METRICS.items())
    rollout_metrics.register(TOY)
    try:
        yield TOY
    finally:
        rollout_metrics.unregister(TOY.name)
        assert list(rollout_metrics.METRICS.items()) == before


def straight_log(steps, T=12, reason=rollout_metrics.GOAL):
    """One episode along y = 0 at 0.05 m per step that ran `steps` of T steps."""
    alive = np.arange(T) < steps
    pose = np.stack([0.05 * np.arange(1, T + 1), np.zeros(T), np.zeros(T)], -1)
    event = np.where(np.arange(T) == steps - 1, reason, 0)
    return rollout_metrics.Log(
        pose=jnp.asarray(pose, jnp.float32), cmd=jnp.full((T, 2), 0.5, jnp.float32),
        alive=jnp.asarray(alive), event=jnp.asarray(event, jnp.int32),
        start=jnp.zeros(3, jnp.float32), goal=jnp.asarray([1.0, 0.0], jnp.float32),
        lane=straight_lane(0.0, 1.0), reason=jnp.int32(reason), steps=jnp.int32(steps))


def test_built_in_registry_keeps_the_order_and_flags():
    M = rollout_metrics.METRICS
    assert list(M) == ["success", "collision", "reason", "excluded", "cha", "mae", "mse",
                       "omega_std", "v_mean", "time", "path_ratio", "max_offset",
                       "heading_error"]
    assert [m for m in M if M[m].trajectory] == ["cha", "mae", "mse", "omega_std", "v_mean",
                                                 "path_ratio", "max_offset", "heading_error"]
    assert [m for m in M if M[m].binary] == ["success", "collision", "excluded"]
    assert [m for m in M if not M[m].env] == ["excluded"]
    assert train_rollout.episode_keys() == (
        "return", "nav/success", "nav/collision", "nav/cha", "nav/mae", "nav/mse",
        "nav/omega_std", "nav/time", "nav/max_offset", "nav/heading_error")
    assert M["cha"].better == "zero" and M["reason"].better is None
    with pytest.raises(ValueError, match="already registered"):
        rollout_metrics.register(M["mae"])
    with pytest.raises(ValueError, match="better must be one of"):
        rollout_metrics.Metric("bad", _double_time, "bad", better="high")
    with pytest.raises(ValueError, match="train needs env"):
        rollout_metrics.Metric("bad", _double_time, "bad", env=False, train=True)


def test_registered_metric_reaches_summarise_env_trainer_and_figures(toy):
    batch = jax.tree.map(lambda *x: jnp.stack(x), straight_log(10),
                         straight_log(4, reason=rollout_metrics.COLLISION))
    s = rollout_metrics.summarise(batch, DT)
    np.testing.assert_allclose(np.asarray(s[toy.name]), [2.0, 0.8], rtol=1e-6)
    np.testing.assert_allclose(np.asarray(s["time"])[0] * 2, np.asarray(s[toy.name])[0])
    # the env's metrics of one episode (Env._metrics needs only the control period)
    nav = env_core.Env._metrics(types.SimpleNamespace(dt=DT), {}, straight_log(10),
                                jnp.float32(0.0))
    assert float(nav[f"nav/{toy.name}"]) == pytest.approx(2.0)
    assert "nav/excluded" not in nav and "nav/reason" in nav
    assert train_rollout.episode_keys()[-1] == f"nav/{toy.name}"
    assert sweep_figures.metric_info(toy.name) == ("twice the episode time", "s", "{:.2f}",
                                                   "lower")
    agg = rollout_aggregate.aggregate({toy.name: np.asarray([-1.0, 1.0, 3.0])})[toy.name]
    assert agg["lo"] == 0.0  # clipped to the metric's bounds


def test_jitted_summarise_is_retraced_on_register():
    f = jax.jit(rollout_metrics.summarise, static_argnums=1)
    log = straight_log(10)
    assert TOY.name not in f(log, DT)
    rollout_metrics.register(TOY)
    try:
        assert float(f(log, DT)[TOY.name]) == pytest.approx(2.0)
    finally:
        rollout_metrics.unregister(TOY.name)
    assert TOY.name not in f(log, DT)


# the tiny real sweep of tests/test_sweep.py (oracle, ground-truth masks, 16 × 16 camera, a
# 1.5 m path): 2 cells over d_rr (and terrain_dh as a one-valued second axis: a heatmap) ×
# 2 episodes, one batch
TINY = {"name": "toy", "seeds": 2, "batch_size": 4, "controller": {"name": "oracle"},
        "perception": {"source": "ground_truth"},
        "field": {"d_rr": [1.6, 2.4], "terrain_dh": [0.0], "row_length": 6.0,
                  "terrain_length": 10.0, "terrain_width": 10.0, "rows_per_group": 2},
        "sim": {"path_length": 1.5}, "episode": {"max_time": 4.0},
        "camera": {"width": 16, "height": 16}}


# -m slow (.ci/slow): 37 s of CPU compilation; test_registries keeps a toy crop and controller
# running a sweep
@pytest.mark.slow
def test_registered_metric_runs_a_sweep(toy, tmp_path):
    sweep_run.run(sweep_config.from_dict(TINY), tmp_path, progress=False)
    res = pd.read_csv(tmp_path / "results.csv")
    assert len(res) == 4 and res["success"].all(), res["reason"]
    assert toy.name in res.columns
    np.testing.assert_allclose(res[toy.name], 2 * res["time"], rtol=1e-6)
    summary = pd.read_csv(tmp_path / "summary.csv")
    assert len(summary) == 2
    assert {toy.name, f"{toy.name}_lo", f"{toy.name}_hi", f"{toy.name}_n"} <= set(summary.columns)
    np.testing.assert_allclose(summary[toy.name], 2 * summary["time"], rtol=1e-6)
    np.testing.assert_allclose(
        summary[toy.name], res.groupby("cell")[toy.name].mean().to_numpy(), rtol=1e-6)
    assert (summary[f"{toy.name}_n"] == 2).all()
    png = tmp_path / f"{toy.name}.png"
    with Image.open(png) as im:
        assert im.format == "PNG" and min(im.size) > 100
    report = (tmp_path / "report.md").read_text()
    assert f"### twice the episode time\n\n![{toy.name}]({toy.name}.png)" in report
