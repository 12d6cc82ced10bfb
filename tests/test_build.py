"""rollout.build, the one assembly: the same seed and config give the same episodes from every
command (the sweep, the episode CLI, the builder called directly), whatever the batching."""

import jax
import numpy as np
import pandas as pd
import pytest

from mjxrow.rollout import build as B
from mjxrow.rollout import cli
from mjxrow.rollout import metrics as M
from mjxrow.sweep import config as C
from mjxrow.sweep import grid as G
from mjxrow.sweep import run as S

TINY = {"preset": "vineyard", "seed": 5, "seeds": 3, "batch_size": 2,
        "controller": {"name": "oracle"}, "perception": {"source": "ground_truth"},
        "field": {"row_length": 6.0, "terrain_length": 10.0, "terrain_width": 8.0,
                  "terrain_dh": 0.1},
        "sim": {"path_length": 1.5}, "episode": {"max_time": 2.0, "start_offset_std": 0.1},
        "camera": {"width": 16, "height": 16}}
METRICS = ["lane", "success", "reason", "cha", "mae", "mse", "omega_std", "time"]


@pytest.fixture(scope="module")
def runs(tmp_path_factory):
    out = tmp_path_factory.mktemp("build")
    cfg = C.from_dict(TINY)
    S.run(cfg, out / "sweep", progress=False, figures=False)
    sweep = pd.read_csv(out / "sweep" / "results.csv").sort_values("episode")
    run = G.expand(cfg)[0].cfg
    table = cli.run_episodes(run, 3, out / "episode", progress=False)
    return cfg, run, sweep.reset_index(drop=True), table


def test_episode_cli_equals_sweep_cell(runs):
    _, _, sweep, table = runs
    assert len(sweep) == 3 and sweep["episode"].tolist() == table["episode"].tolist()
    for m in METRICS:
        a, b = sweep[m].to_numpy(), table[m].to_numpy()
        assert (a == b).all() or np.allclose(a.astype(float), b.astype(float), equal_nan=True), m
    # the start-pose noise differs between episodes: they are not copies of each other
    assert sweep["max_offset"].nunique() == 3


# -m slow (.ci/slow): 37 s of CPU compilation (another batch size); the suite keeps the
# episode CLI's episodes equal to the sweep's
@pytest.mark.slow
def test_batch_composition_does_not_change_an_episode(runs):
    _, run, sweep, _ = runs
    built = B.build(run)
    one = built.summarise(built.rollout(built.batch([(run, 2)], size=4)), 1)
    assert one["mae"][0] == pytest.approx(sweep["mae"][2], rel=1e-6, abs=1e-9)
    assert one["time"][0] == pytest.approx(sweep["time"][2], nan_ok=True)
    assert one["cha"][0] == pytest.approx(sweep["cha"][2], rel=1e-6, abs=1e-9)


def test_build_refuses_mixed_static_values():
    cfg = C.from_dict({**TINY, "camera": {"width": [16, 24], "height": 16}})
    with pytest.raises(ValueError, match="static values"):
        B.build([c.cfg for c in G.expand(cfg)])


def _close(a, b) -> bool:
    a, b = np.asarray(a), np.asarray(b)
    if a.dtype.kind not in "fc":
        return bool((a == b).all())
    return bool(np.allclose(a, b, rtol=1e-5, atol=1e-7, equal_nan=True))


def _mixed_episodes(runs):
    """(SegZeros run, the sweep's oracle table, the mixed group's metrics of 3 SegZeros then 3
    oracle episodes)."""
    _, oracle, sweep, _ = runs
    seg = G.expand(C.from_dict({**TINY, "controller": {"name": "segzeros"}}))[0].cfg
    mixed = B.build([oracle, seg])
    assert len(mixed.variants) == 2 and B.build(oracle).variants == ()
    items = [(seg, e) for e in range(3)] + [(oracle, e) for e in range(3)]
    return seg, sweep, mixed.summarise(mixed.rollout(mixed.batch(items)), 6)


def test_a_mixed_group_runs_each_episode_with_its_own_controller(runs):
    """The oracle's episodes of a mixed group are the sweep's; its SegZeros episodes are
    driven differently (the selection works). SegZeros' episodes against SegZeros' own
    program: the slow test below (another 45 s of CPU compilation)."""
    _, oracle, _, _ = runs
    seg, sweep, got = _mixed_episodes(runs)
    for m in ("success", "reason", "cha", "mae", "omega_std", "time"):
        mine = np.asarray(M.REASONS)[got[m][3:]] if m == "reason" else got[m][3:]
        assert _close(mine, sweep[m].to_numpy()), m  # the oracle as in the sweep
    # the controllers really differ here, so the selection is what made them match
    assert not _close(got["omega_std"][:3], got["omega_std"][3:])
    # a run of another static value cannot join
    wide = G.expand(C.from_dict({**TINY, "camera": {"width": 24, "height": 16}}))[0].cfg
    with pytest.raises(ValueError, match="besides the controller"):
        B.build([oracle, seg, wide])


@pytest.mark.slow  # -m slow (.ci/slow): SegZeros' own program, 45 s more of CPU compilation
def test_a_mixed_group_runs_segzeros_as_its_own_program_does(runs):
    seg, _, got = _mixed_episodes(runs)
    alone = B.build(seg)
    want = alone.summarise(alone.rollout(alone.batch([(seg, e) for e in range(3)])), 3)
    for m in ("success", "reason", "cha", "mae", "omega_std", "time"):
        assert _close(got[m][:3], want[m]), m  # SegZeros as in its own program


def test_checks_and_batch_assembly_compile_only_their_programs(compiled):
    """The configuration checks run on the host, and a batch's keys, fields and lanes take one
    program each: no program per small array operation (each costs a compile or a cache
    load, which on a GPU is tenths of a second)."""
    cfg = C.from_dict({**TINY, "field": {**TINY["field"], "d_rr": [2.0, 2.2]}})
    assert compiled(lambda: G.check(cfg)) == []
    runs = [c.cfg for c in G.expand(cfg)]
    built = B.build(runs[0])
    names = compiled(lambda: built.batch([(runs[0], 0), (runs[0], 1)], size=2))
    assert len(names) == 3 and "jit(gen)" in names, names


@pytest.mark.parametrize("seed", [0, 7, 2**32 - 1, 2**40 + 3])
def test_batch_keys_are_fold_in_of_the_seed_then_split(seed):
    """One program for a batch's keys gives the keys of the definition: episode i of a run of
    seed s: split(fold_in(key(s), i)); batches mixing seeds too."""
    import jax

    eps = [0, 1, 5, 99]
    ref = [jax.random.split(jax.random.fold_in(jax.random.key(seed), i)) for i in eps]
    kd = jax.random.key_data
    for got in (B.batch_keys([seed] * 4, eps), B.batch_keys([seed, seed, seed, 3], eps)):
        for n in range(3):
            assert np.array_equal(kd(got[0][n]), kd(ref[n][0]))
            assert np.array_equal(kd(got[1][n]), kd(ref[n][1]))
    mixed = B.batch_keys([seed, seed, seed, 3], eps)
    other = jax.random.split(jax.random.fold_in(jax.random.key(3), 99))
    assert np.array_equal(kd(mixed[0][3]), kd(other[0]))


def test_a_batch_shown_as_it_goes_gives_the_same_log(runs, monkeypatch):
    """Built.rollout(progress=...) runs the batch as three programs, calling back between
    chunks of control steps: the same Log, bit for bit, as the one program (the module's
    run: 30 control steps, two chunks)."""
    monkeypatch.setattr(B, "STAGE_CHUNKS", 1)
    _, run, _, _ = runs
    built = B.build(run)
    batch = built.batch([(run, e) for e in range(3)])
    one = built.rollout(batch)
    calls = []
    staged = built.rollout(batch, progress=lambda steps, ended: calls.append((steps, ended)))
    for a, b in zip(jax.tree.leaves(one), jax.tree.leaves(staged), strict=True):
        np.testing.assert_array_equal(np.asarray(a), np.asarray(b))
    steps = [s for s, _ in calls]
    assert len(calls) >= 2 and steps == sorted(steps) and steps[0] > 0
    assert all(0 <= e <= 3 for _, e in calls)
    assert calls[-1][1] == 3 or steps[-1] >= built.episode.n_steps
