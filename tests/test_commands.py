"""Every command answers `--help` (and a bad flag) at once: its light half (mjxrow.commands)
parses before JAX, MuJoCo, Flax, orbax, pandas or matplotlib are imported, and only then hands
over to the heavy module. Each case runs in a fresh process, as a user's command does."""

import os
import re
import subprocess
import sys
import time
from pathlib import Path

import pytest

ROOT = Path(__file__).parents[1]
HEAVY = ("jax", "mujoco", "flax", "optax", "orbax", "pandas", "matplotlib")
BOUND_S = 5.0  # generous for a loaded 2-core CI machine; about 0.2 s unloaded

# (command as run: a module after -m, or a script; arguments; exit code)
COMMANDS = [
    ("mjxrow.sweep", ["--help"], 0),
    ("mjxrow.search", ["--help"], 0),
    ("mjxrow.episode", ["--help"], 0),
    ("mjxrow.worlds", ["--help"], 0),
    ("mjxrow.bench", ["--help"], 0),
    ("mjxrow.seg.train", ["--help"], 0),
    ("mjxrow.seg.synth", ["--help"], 0),
    ("mjxrow.seg.eval", ["--help"], 0),
    ("mjxrow.seg.export", ["--help"], 0),
    ("mjxrow.sweep.docs", ["--help"], 0),
    ("experiments/train_policy.py", ["--help"], 0),
    ("experiments/table1.py", ["--help"], 0),
    ("experiments/table2_segmentation.py", ["--help"], 0),
    ("experiments/table3_navigation.py", ["--help"], 0),
    ("experiments/env_parts.py", ["--help"], 0),
    # argument errors answer as fast (argparse's usage line, exit 2)
    ("mjxrow.sweep", [], 2),
    ("mjxrow.episode", ["--n", "2"], 2),
    ("mjxrow.worlds", ["--out", "w"], 2),
    ("mjxrow.bench", ["nope"], 2),
    ("mjxrow.seg.synth", ["--crop", "zucchini"], 2),
    ("experiments/table3_navigation.py", ["--controllers", "nope"], 2),
    ("experiments/env_parts.py", ["--parts", "nope"], 2),
    ("experiments/env_parts.py", ["--batch", "0"], 2),
    ("experiments/env_parts.py", ["--ops", "--compile-profile", "DIR"], 2),
    ("experiments/env_parts.py", ["--ops", "--record", "R.jsonl"], 2),
]

# runs the command in this process, then reports which heavy packages it imported
PROBE = """
import runpy, sys
target, args = sys.argv[1], sys.argv[2:]
sys.argv = [target, *args]
try:
    if target.endswith(".py"):
        runpy.run_path(target, run_name="__main__")
    else:
        runpy.run_module(target, run_name="__main__", alter_sys=True)
    code = 0
except SystemExit as e:
    code = e.code if isinstance(e.code, int) else (0 if e.code is None else 1)
heavy = [m for m in {heavy!r} if m in sys.modules]
print("PROBE", code, ",".join(heavy), file=sys.stderr)
"""


@pytest.mark.parametrize("target, args, code", COMMANDS,
                         ids=[f"{c[0]} {' '.join(c[1])}".strip() for c in COMMANDS])
def test_answers_before_the_heavy_imports(tmp_path, target, args, code):
    path = str(ROOT / target) if target.endswith(".py") else target
    t0 = time.perf_counter()
    res = subprocess.run([sys.executable, "-c", PROBE.format(heavy=HEAVY), path, *args],
                         capture_output=True, text=True, cwd=tmp_path, timeout=60,
                         env={**os.environ, "PYTHONPATH": str(ROOT)})
    wall = time.perf_counter() - t0
    probe = [line for line in res.stderr.splitlines() if line.startswith("PROBE ")]
    assert probe, res.stderr
    _, got, *heavy = probe[-1].split(" ")
    assert int(got) == code, res.stderr
    assert heavy == [""], f"{target} {args} imported {heavy[0]} before answering"
    if code == 0:
        assert "usage:" in res.stdout
    else:
        assert "usage:" in res.stderr
    assert wall < BOUND_S, f"{target} {args}: {wall:.1f} s"


def test_every_entry_point_is_listed():
    """Each `python -m` module and table script of the project is in COMMANDS."""
    listed = {c[0] for c in COMMANDS}
    mains = {".".join(p.relative_to(ROOT).with_suffix("").parts[:-1])
             for p in (ROOT / "mjxrow").rglob("__main__.py")}
    assert mains <= listed, mains - listed
    assert {f"experiments/{p.name}" for p in (ROOT / "experiments").glob("table*.py")} <= listed


def test_sweep_parser_is_run_mains(capsys):
    """`mjxrow.sweep.cli.parser` and the parser `mjxrow.sweep.run.main` builds take the same
    arguments (one help text): run.main parses with cli.parser."""
    from mjxrow.sweep import cli, run

    with pytest.raises(SystemExit):
        run.main(["--help"])
    assert capsys.readouterr().out == cli.parser().format_help()


def test_light_choices_match_the_library():
    """Choices a light parser lists without importing the heavy module that defines them."""
    from mjxrow.seg import checkpoint, model, step
    from mjxrow.seg import train as seg_train_cli
    from mjxrow.worlds import cli as worlds_cli
    from mjxrow.worlds import export, sdf
    from paper import cli as paper_cli
    from paper import table3

    assert worlds_cli.GAZEBO == export.GAZEBO
    assert worlds_cli.SDF_COLLISIONS == sdf.SDF_COLLISIONS
    assert seg_train_cli.ARCHS == model.ARCHS
    assert seg_train_cli.LOSSES == tuple(step.LOSSES)
    assert seg_train_cli.WEIGHT_DTYPES == checkpoint.WEIGHT_DTYPES
    assert paper_cli.CONTROLLERS == tuple(table3.CONTROLLERS)


def test_run_command_hands_over():
    """The heavy module's entry gets the argument list (a copy) and its result comes back."""
    from mjxrow import commands

    assert commands.run_command("builtins", ("a", "b"), "len") == 2


def test_env_parts_counts_operations_and_profiles_a_compilation(tmp_path):
    """env_parts.operations puts each StableHLO operation under the mjxrow file that made it
    (or under NO_LINE) and misses none; compile_profile sums XLA's compiler events by name
    (self time within total time) and names its passes; a folder that holds a profile already
    is refused."""
    import importlib.util

    import jax
    import jax.numpy as jnp

    from mjxrow.render import geom
    spec = importlib.util.spec_from_file_location(
        "env_parts_t", Path(__file__).resolve().parents[1] / "experiments" / "env_parts.py")
    ep = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(ep)
    low = jax.jit(lambda o, d: geom.slab(o, d, o - 1, o + 1)).lower(jnp.ones(3), jnp.ones(3))
    counts = ep.operations(low)
    total = len(re.findall(r'^\s*(?:%[^=]*= )?"?(?:stablehlo|chlo)\.\w+', low.as_text(), re.M))
    assert sum(counts.values()) == total and counts["render/geom.py"] > 0
    rows = ep.compile_profile([jax.jit(lambda x: jnp.cumsum(jnp.sin(x))).lower(jnp.ones(8))],
                              tmp_path / "prof")
    assert rows and all(0 <= r["self_s"] <= r["total_s"] + 1e-9 for r in rows)
    assert [r["self_s"] for r in rows] == sorted((r["self_s"] for r in rows), reverse=True)
    assert any(r["name"] in ("algsimp", "cse", "dce") for r in rows)
    (tmp_path / "prof" / "compile_profile.csv").write_text("an earlier profile\n")
    with pytest.raises(SystemExit) as e:  # refused before any work, the earlier file kept
        ep.main(["--compile-profile", str(tmp_path / "prof")])
    assert e.value.code == 2
    assert (tmp_path / "prof" / "compile_profile.csv").read_text() == "an earlier profile\n"
