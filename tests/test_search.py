"""The failure search (`python -m mjxrow.search`) on a toy controller registered here: it drives
along the lane, off its centre line the more the nearer its field's parameters lie to a planted
box (1 % of the searched 4-D box), and stops inside that box (the episode times out: a
failure). Every test shares one tiny scenario and one generation size, so the closed loop
compiles once for the whole file."""

import dataclasses
import json
import math

import jax.numpy as jnp
import numpy as np
import pandas as pd
import pytest
import yaml

import mjxrow
import mjxrow.search
from mjxrow import control, runtime
from mjxrow.control import oracle
from mjxrow.search import box as search_box
from mjxrow.search import config as search_config
from mjxrow.search import evaluate as search_evaluate
from mjxrow.search import run as search_run
from mjxrow.worlds import cli as worlds_cli

# four keys that leave a straight, flat lane as it is: only the toy reads them
BOX = {"field.plant_height": [0.3, 0.9], "field.row_wavelength": [8.0, 20.0],
       "field.p_missing": [0.0, 0.3], "field.terrain_scale": [1.0, 5.0]}
SIDE = 0.01 ** 0.25  # the planted box: the top 31.6 % of each range, 1 % of the box's volume
PLANTED_LOW = 1.0 - SIDE
SCENARIO = {"name": "planted", "preset": "zucchini", "seed": 0,
            "field": {"row_length": 4.0, "terrain_length": 7.0, "terrain_width": 8.0,
                      "rows_per_group": 2, "terrain_dh": 0.0, "plant_size_var": 0.0},
            "sim": {"path_length": 1.0}, "episode": {"max_time": 2.5},
            "camera": {"width": 16, "height": 16},
            "controller": {"name": "planted"}, "perception": {"source": "ground_truth"},
            "population": 4, "repeats": 1, "box": BOX}


def _distance(params) -> jnp.ndarray:
    """Distance of a field's parameters to the planted box, in the normalised search box."""
    u = jnp.stack([(getattr(params, k.split(".")[1]) - lo) / (hi - lo)
                   for k, (lo, hi) in BOX.items()])
    return jnp.linalg.norm(jnp.maximum(PLANTED_LOW - u, 0.0))


def _planted_act(params, state, obs):
    d = _distance(obs.field.params)
    offset = 0.15 * (1.0 - jnp.minimum(d, 1.0))  # m off the centre line, nearer: further
    lane = obs.lane.replace(u=obs.lane.u + offset)
    cmd = oracle.pursuit_command(params, obs.pose, lane)
    return state, jnp.where(d > 0.0, cmd, jnp.zeros_like(cmd))  # inside: stop


PLANTED = control.Controller("planted", oracle.OracleConfig, oracle.make_oracle_params,
                             oracle.oracle_init, _planted_act)


@pytest.fixture(scope="module", autouse=True)
def planted():
    control.register(PLANTED)
    try:
        yield
    finally:
        control.CONTROLLERS.pop("planted", None)


def _cfg(**over) -> search_config.SearchConfig:
    raw = json.loads(json.dumps(SCENARIO))
    for k, v in over.items():
        raw[k] = v
    return search_config.from_dict(raw)


def _first_failure(cfg, out) -> int:
    res = search_run.run(cfg, out, progress=False, figures=False)
    fails = res["candidates"][res["candidates"]["outcome"] == "fail"]
    u = fails[[f"u_{j}" for j in range(len(BOX))]].to_numpy(float)
    assert np.all(u >= PLANTED_LOW - 1e-6), u  # every failure lies in the planted box
    row = res["summary"].set_index("method").loc[cfg.method]
    return int(row["first_failure_at"]) if not math.isnan(row["first_failure_at"]) \
        else int(row["episodes"]) + cfg.generation  # not found: more than the budget


def test_cma_es_finds_the_planted_failure_with_fewer_episodes_than_random(tmp_path):
    """Episodes spent when the first failure was found (whole generations of 4), median over
    5 search seeds, CMA-ES against uniform random sampling in the same box."""
    cma, rnd = [], []
    for seed in range(5):
        budget = {"episodes": 120, "failures": 1}  # none found: counted as 124
        cma.append(_first_failure(_cfg(seed=seed, method="cma_es", baseline="none",
                                       budget=budget), tmp_path / f"cma{seed}"))
        rnd.append(_first_failure(_cfg(seed=seed, method="random", budget=budget),
                                  tmp_path / f"rnd{seed}"))
    ratio = np.median(rnd) / np.median(cma)
    # random sampling's expected median, whole generations of 4: p = 1 % a candidate
    expected = 4 * math.ceil(math.log(0.5) / math.log(1.0 - 0.01) / 4)
    print(f"episodes to the first failure: CMA-ES {cma}, random {rnd}; ratio of medians "
          f"{ratio:.1f}; random's expected median {expected}: "
          f"{expected / np.median(cma):.1f} × CMA-ES's")
    assert ratio >= 5.0, (cma, rnd)
    # and against random's expectation rather than its 5 draws (which scatter widely)
    assert np.median(cma) * 3 <= expected, cma


def test_resume_after_an_interrupt_gives_the_same_candidates(tmp_path, monkeypatch):
    # merge_radius 4: CMA-ES's steps (0.3) are below a tenth of it, so it restarts after
    # every generation, and the resumed run must go on from the saved restart as well
    cfg = _cfg(budget={"episodes": 12}, objective={"merge_radius": 4.0})
    search_run.run(cfg, tmp_path / "whole", progress=False, figures=False)
    calls = {"n": 0}
    real = search_evaluate.Evaluator.episodes

    def flaky(self, items):
        calls["n"] += 1
        if calls["n"] == 3:  # CMA-ES's third generation: the first two are kept
            raise KeyboardInterrupt
        return real(self, items)

    monkeypatch.setattr(search_evaluate.Evaluator, "episodes", flaky)
    with pytest.raises(KeyboardInterrupt):
        search_run.run(cfg, tmp_path / "cut", progress=False, figures=False)
    state = json.loads((tmp_path / "cut" / "state.json").read_text())
    assert state["streams"]["cma_es"]["generation"] == 2 and state["rows"] == 8
    monkeypatch.setattr(search_evaluate.Evaluator, "episodes", real)
    search_run.run(cfg, tmp_path / "cut", progress=False, figures=False)
    a, b = (pd.read_csv(tmp_path / d / "candidates.csv").drop(columns="elapsed_s")
            for d in ("whole", "cut"))
    assert len(a) == 24 and set(a["method"]) == {"cma_es", "random"}
    assert a[a["method"] == "cma_es"]["restart"].tolist() == [0] * 4 + [1] * 4 + [2] * 4
    pd.testing.assert_frame_equal(a, b)


def test_a_minutes_budget_counts_generations_that_compile_nothing(tmp_path):
    """A budget of 60 ms: the first generation (which may compile) always runs and
    ends the search; the baseline then spends as many episodes."""
    res = search_run.run(_cfg(budget={"minutes": 0.001}), tmp_path, progress=False,
                         figures=False)
    table = res["summary"].set_index("method")
    assert table.loc["cma_es", "generations"] == 1 and table.loc["cma_es", "stopped_by"] == \
        "minutes"
    assert table.loc["random", "episodes"] == table.loc["cma_es", "episodes"]


def test_a_search_prepared_ahead_compiles_no_rollout_program(tmp_path, compiled):
    """`search.run.prepare` compiles a search's program ahead (the adversarial curriculum does
    it in a thread beside the training's compilation): with the compilation cache on, the
    search then compiles neither the closed loop (`jit(batch)`) nor the fields' program
    (`jit(gen)`), only the small programs of its method and summary."""
    # a population of its own (a batch shape no other test compiles): nothing of it compiled
    # yet, and no cache emptied for the tests after it
    cfg = _cfg(population=6, budget={"episodes": 6})
    res = {}
    try:
        runtime.enable_cache(tmp_path / "cache")
        ahead = compiled(lambda: search_run.prepare(cfg), clear=False)
        names = compiled(lambda: res.update(search_run.run(cfg, tmp_path / "out",
                                                           progress=False, figures=False)),
                         clear=False)
    finally:
        runtime.disable_cache()
        runtime._EXPORTED.clear()
    assert {"jit(batch)", "jit(gen)"} <= set(ahead), ahead  # the closed loop, the fields
    assert not {"jit(batch)", "jit(gen)"} & set(names), names
    assert len(res["candidates"]) == 12  # 6 of CMA-ES, 6 of the random baseline


# -m slow (.ci/slow): 35-45 s of CPU (the command end to end with its figures); the suite
# keeps the search's runs, resume and its one-line errors
@pytest.mark.slow
def test_command_outputs_and_replay_of_a_failure(tmp_path, capsys):
    """The command end to end on a box of which a quarter fails: figures, report, the
    confirmation with new seeds, the summary printed last, a benchmarks row; then
    `--from-search` exports the failure's exact field."""
    # every key's range narrowed to its top 1.25 · SIDE: 0.8 of each inside the planted box
    narrow = {k: [hi - 1.25 * SIDE * (hi - lo), hi] for k, (lo, hi) in BOX.items()}
    raw = {**SCENARIO, "box": narrow, "budget": {"episodes": 8}, "top": 1}
    path = tmp_path / "s.yaml"
    path.write_text(yaml.safe_dump(raw))
    out, record = tmp_path / "run", tmp_path / "bench.jsonl"
    assert search_run.main([str(path), "--out", str(out), "--no-progress", "--confirm", "2",
                            "--record", str(record)]) == 0
    printed = capsys.readouterr().out.strip().splitlines()
    assert printed[-1].startswith("confirmed: ") and "| cma_es |" in "\n".join(printed[-5:])
    for name in ("candidates.csv", "failures.csv", "confirm.csv", "convergence.png",
                 "pairs.png", "failure_1.png", "report.md", "config.yaml", "state.json"):
        assert (out / name).exists(), name
    failures = pd.read_csv(out / "failures.csv")
    assert len(failures) >= 1 and failures["rank"].tolist() == list(range(1, len(failures) + 1))
    rows = [json.loads(line) for line in record.read_text().splitlines()]
    assert {r["stage"] for r in rows} == {"search"} and rows[0]["unit"] == "fields"
    for key in ("device", "date", "command", "config", "value", "unit", "compile_s", "run_s"):
        assert key in rows[0], key

    # --from-search: the failure's field, as the search generated it (the same batch path)
    cfg = search_config.from_dict(yaml.safe_load((out / "config.yaml").read_text()), out)
    top = failures.iloc[0]
    world = tmp_path / "world"
    assert worlds_cli.main(["--from-search", str(out), "--rank", "1", "--gazebo", "none",
                            "--out", str(world)]) == 0
    ev = search_evaluate.Evaluator(cfg)
    run = search_box.run_of(cfg.scenario, cfg.box,
                            top[[f"u_{j}" for j in range(4)]].to_numpy(float))
    batch, log = ev.replay([(run, int(top["first_failing"]))])
    fields = runtime.to_host(batch.fields)
    r, p = np.nonzero(fields.plant_active[0])
    want = np.sort(fields.plant_pos[0][r, p], axis=0)
    plants = pd.read_csv(world / "zucchini_search_r1_plants.csv")
    got = np.sort(plants[["x", "y", "z"]].to_numpy(), axis=0)
    assert got.shape == want.shape
    np.testing.assert_allclose(got, want, atol=6e-5)
    assert int(log.reason[0]) != 1  # the exported episode is the failing one (not the goal)


@pytest.mark.parametrize("change, key", [
    ({"box": {"camera.width": [16, 32]}}, "box.camera.width: static"),
    ({"box": {"field.p_missing": [0.0, 1.5]}}, "box.field.p_missing: the high bound 1.5"),
    ({"box": {"field.d_rr": [1.0, 1e9]}}, "box.field.d_rr: the high bound"),
    ({"box": {}}, "box: empty"),
    ({"box": {"field.d_rr": [1.8, 1.8]}}, "box.field.d_rr: empty range"),
    ({"budget": {"episodes": 3}}, "budget.episodes: 3 episodes is less than one generation"),
    ({"seeds": 4}, "seeds: a sweep's key"),
])
def test_bad_input_is_one_line_naming_the_key(tmp_path, capsys, change, key):
    raw = {**SCENARIO, "budget": {"episodes": 8}, **change}
    path = tmp_path / "bad.yaml"
    path.write_text(yaml.safe_dump(raw))
    out = tmp_path / "out"
    assert search_run.main([str(path), "--out", str(out), "--no-progress"]) == 2
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1 and err.startswith(f"error: {key}"), err
    assert not out.exists()


def test_config_round_trip_and_identity():
    cfg = _cfg(budget={"episodes": 8, "minutes": 1.0})
    again = search_config.from_dict(search_config.to_dict(cfg))
    assert again == dataclasses.replace(cfg)
    longer = search_config.from_dict({**search_config.to_dict(cfg), "budget": {"episodes": 80}})
    assert search_config.identity(longer) == search_config.identity(cfg)
    assert cfg.shape.weed_slots == 0 and cfg.generation == 4
    # the notebook's names (mjxrow's lazy public API and the package's)
    assert mjxrow.run_search is search_run.run and mjxrow.load_search is search_config.load
    assert mjxrow.search.run_search is search_run.run
