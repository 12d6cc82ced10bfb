"""Process set-up (mjxrow.runtime): cache directory, flags, the persistent compilation cache
across two processes, placement and gathering in one process; the compile clock
(mjxrow.stopwatch)."""

import argparse
import json
import os
import re
import subprocess
import sys
import time
from pathlib import Path

import jax
import numpy as np
import pytest
from flax import struct

from mjxrow import runtime as R
from mjxrow import stopwatch as SW

ROOT = Path(__file__).resolve().parents[1]


def parse(argv):
    p = argparse.ArgumentParser()
    R.add_args(p)
    return p.parse_args(argv)


def test_default_cache_dir(monkeypatch, tmp_path):
    monkeypatch.delenv(R.CACHE_ENV, raising=False)
    monkeypatch.delenv("XDG_CACHE_HOME", raising=False)
    monkeypatch.setenv("HOME", str(tmp_path / "home"))
    assert R.default_cache_dir() == tmp_path / "home" / ".cache" / "mjxrow" / "jax"
    monkeypatch.setenv("XDG_CACHE_HOME", str(tmp_path / "xdg"))
    assert R.default_cache_dir() == tmp_path / "xdg" / "mjxrow" / "jax"
    monkeypatch.setenv(R.CACHE_ENV, str(tmp_path / "mine"))
    assert R.default_cache_dir() == tmp_path / "mine"


def test_cluster_from_flags_and_environment(monkeypatch):
    for env in (*R.CLUSTER_ENV.values(), "JAX_COORDINATOR_ADDRESS", "JAX_NUM_PROCESSES",
                "JAX_PROCESS_ID"):
        monkeypatch.delenv(env, raising=False)
    assert R.cluster_from(parse([])) is None
    args = parse(["--coordinator", "h:1234", "--num-processes", "4", "--process-id", "3"])
    assert R.cluster_from(args) == ("h:1234", 4, 3)
    monkeypatch.setenv("MJXROW_COORDINATOR", "e:1")
    monkeypatch.setenv("MJXROW_NUM_PROCESSES", "2")
    monkeypatch.setenv("MJXROW_PROCESS_ID", "1")
    assert R.cluster_from(parse([])) == ("e:1", 2, 1)
    assert R.cluster_from(parse(["--process-id", "0"])) == ("e:1", 2, 0)  # flags win
    with pytest.raises(ValueError, match=r"^--process-id: must be in 0\.\.1, got 2$"):
        R.cluster_from(parse(["--process-id", "2"]))
    monkeypatch.delenv("MJXROW_NUM_PROCESSES")
    with pytest.raises(ValueError, match="^--num-processes: needed with --coordinator$"):
        R.cluster_from(parse([]))
    monkeypatch.delenv("MJXROW_COORDINATOR")
    with pytest.raises(ValueError, match="^--coordinator: needed"):
        R.cluster_from(parse([]))


def test_sweep_cli_names_the_missing_flag(tmp_path, capsys):
    from mjxrow.sweep import run as S

    cfg = tmp_path / "s.yaml"
    cfg.write_text("seeds: 1\n")
    assert S.main([str(cfg), "--out", str(tmp_path / "o"), "--num-processes", "2"]) == 2
    assert capsys.readouterr().err.strip() == \
        "error: --coordinator: needed with --num-processes / --process-id"


def test_union_seconds_counts_nested_spans_once():
    assert SW.union_seconds([(0.0, 2.0), (1.0, 3.0), (5.0, 6.0)]) == pytest.approx(4.0)
    assert SW.union_seconds([(0.0, 10.0), (2.0, 3.0)]) == pytest.approx(10.0)
    assert SW.union_seconds([(0.0, 2.0), (5.0, 6.0)], since=1.0) == pytest.approx(2.0)
    assert SW.union_seconds([]) == 0.0


def test_stopwatch_splits_compile_run_write():
    watch = SW.Stopwatch()
    time.sleep(0.06)
    now = time.time()  # as if the last 30 ms of the sleep compiled: 20 ms XLA, 20 ms trace
    SW._on_span("/jax/core/compile/backend_compile_duration", now - 0.02, now)
    SW._on_span("/jax/core/compile/jaxpr_trace_duration", now - 0.03, now - 0.01)
    SW._on_span("/jax/core/compile/backend_compile_duration", watch.t0 - 1, watch.t0 - 0.5)
    with watch.writing():
        time.sleep(0.02)
    s = watch.split()
    assert s["compile"] == pytest.approx(0.03, abs=1e-6)  # union of the spans since t0
    assert s["xla"] == pytest.approx(0.02, abs=1e-6)
    assert s["trace"] == pytest.approx(0.02, abs=1e-6)
    assert s["write"] >= 0.02 and s["total"] >= 0.08
    assert s["run"] == pytest.approx(s["total"] - 0.03 - s["write"], abs=1e-6)
    assert s["run"] >= 0.03 - 1e-6
    assert watch.line().startswith("time: ")


def test_stopwatch_counts_the_start_up_before_it():
    watch = SW.Stopwatch(started=time.time() - 2.0)
    s = watch.split()
    assert s["startup"] == pytest.approx(2.0, abs=0.05)
    assert s["total"] == pytest.approx(2.0 + s["compile"] + s["run"] + s["write"], abs=0.01)
    assert re.match(r"time: 2\.\d s = start-up 2\.0 s \+ compile ", watch.line()), watch.line()
    assert "start-up" not in SW.Stopwatch().line() and SW.Stopwatch().split()["startup"] == 0.0


def test_put_and_to_host_in_one_process():
    mesh = jax.sharding.Mesh(np.array(jax.devices()), ("batch",))
    n = 2 * len(jax.devices())
    tree = {"x": np.arange(n, dtype=np.float32), "k": jax.random.split(jax.random.key(3), n)}
    placed = R.put(tree, jax.sharding.NamedSharding(mesh, jax.sharding.PartitionSpec("batch")))
    assert placed["x"].sharding.spec == jax.sharding.PartitionSpec("batch")
    host = R.to_host({"x": placed["x"], "k": jax.random.key_data(placed["k"])})
    np.testing.assert_array_equal(host["x"], np.arange(n))
    np.testing.assert_array_equal(host["k"], np.asarray(jax.random.key_data(tree["k"])))
    assert R.writer() and R.agree({"a": [1, 2]}) == {"a": [1, 2]}


CACHE_SCRIPT = """
import argparse, json, sys
from mjxrow import runtime as R
from mjxrow import stopwatch as SW
p = argparse.ArgumentParser(); R.add_args(p); R.setup(p.parse_args(sys.argv[1:]))
import jax, jax.numpy as jnp
watch = SW.Stopwatch()
f = jax.jit(lambda x: jnp.tanh(x @ x.T).sum())
jax.block_until_ready(f(jnp.ones((8, 8))))
print(json.dumps(watch.split()))
"""


def _cached_run(*flags):
    env = {**os.environ, "PYTHONPATH": str(ROOT)}
    out = subprocess.run([sys.executable, "-c", CACHE_SCRIPT, *flags], capture_output=True,
                         text=True, env=env, timeout=120, check=True)
    return json.loads(out.stdout.strip().splitlines()[-1])


def test_persistent_cache_serves_a_second_process(tmp_path):
    cache = tmp_path / "cache"
    first = _cached_run("--cache-dir", str(cache))
    assert first["cache_misses"] >= 1 and first["cache_hits"] == 0
    assert any(cache.iterdir())  # the CPU backend stores its executables too
    second = _cached_run("--cache-dir", str(cache))
    assert second["cache_hits"] >= 1 and second["cache_misses"] == 0
    off = _cached_run("--no-cache", "--cache-dir", str(tmp_path / "unused"))
    assert off["cache_hits"] == off["cache_misses"] == 0
    assert not (tmp_path / "unused").exists()


@struct.dataclass
class State:  # the result: its tree structure (with the static n) comes from the caller
    a: jax.Array
    n: int = struct.field(pytree_node=False, default=3)


def test_exported_program_is_reused_without_tracing(tmp_path):
    traces = []

    def step(s, k):
        traces.append(1)
        return State(a=s.a * s.n + jax.random.uniform(k), n=s.n)

    fn = jax.jit(jax.vmap(step))
    args = (State(a=jax.numpy.arange(4.0)), jax.random.split(jax.random.key(0), 4))
    expect = fn(*args).a
    tree = jax.tree.structure(State(a=0.0, n=3))  # what the program returns, from the caller
    R.disable_cache()
    assert R.exported(fn, args, "toy", tree) is None  # cache off: nothing kept
    try:
        R.enable_cache(tmp_path / "cache")
        first = R.exported(fn, args, "toy", tree)
        assert first is not None and len(list((tmp_path / "cache" / "exported").iterdir())) == 1
        np.testing.assert_array_equal(first(*args).a, expect)
        n = len(traces)
        R._EXPORTED.clear()  # as a new process: read back from the file
        again = R.exported(jax.jit(jax.vmap(step)), args, "toy", tree)  # a new jit would trace
        out = again(*args)
        assert isinstance(out, State) and out.n == 3 and len(traces) == n  # not traced again
        np.testing.assert_array_equal(out.a, expect)
        np.testing.assert_array_equal(again.lower(*args).compile()(*args).a, expect)
        other = R.exported(jax.jit(jax.vmap(step)), args, "another key", tree)  # traced afresh
        assert other is not None and len(traces) == n + 1
    finally:
        R.disable_cache()
        R._EXPORTED.clear()


def test_a_poisoned_cache_file_runs_no_code(tmp_path, capsys):
    """A kept program file is data (jax.export's serialization), never unpickled: a file
    replaced by a pickle that would run a command is refused (the program is traced as usual)
    and the command does not run."""
    import pickle

    marker = tmp_path / "pwned"

    class Payload:
        def __reduce__(self):
            return (open, (str(marker), "w"))

    fn = jax.jit(jax.vmap(lambda s, k: State(a=s.a * 2 + jax.random.uniform(k))))
    args = (State(a=jax.numpy.arange(4.0)), jax.random.split(jax.random.key(0), 4))
    tree = jax.tree.structure(State(a=0.0, n=3))
    try:
        R.enable_cache(tmp_path / "cache")
        assert R.exported(fn, args, "poison", tree) is not None
        (kept,) = (tmp_path / "cache" / "exported").iterdir()
        blob = pickle.dumps(Payload())
        kept.write_bytes(len(blob).to_bytes(8, "little") + blob + b"\0" * 64)  # the old layout
        R._EXPORTED.clear()
        R._EXPORT_WARNED = False
        assert R.exported(fn, args, "poison", tree) is None  # refused: traced as usual
        assert not marker.exists()
        assert "traced programs are not kept" in capsys.readouterr().err
    finally:
        R.disable_cache()
        R._EXPORTED.clear()


def test_the_pallas_triton_call_of_this_jax_is_allowed_in_kept_programs():
    """The GPU renderer's Pallas kernels lower to a Triton custom call that jax.export refuses
    unless its check is disabled (`runtime._KERNEL_CALLS`); its name changed across JAX
    versions, so it is read from this JAX's Pallas registration: where it is missing, no GPU
    program is kept and every warm GPU run traces again."""
    import importlib.util

    spec = importlib.util.find_spec("jax._src.pallas.triton.pallas_call_registration")
    if spec is None or spec.origin is None:
        pytest.skip("this JAX has no Pallas Triton lowering")
    names = re.findall(r'call_target_name="([^"]+)"', Path(spec.origin).read_text())
    assert names and set(names) <= set(R._KERNEL_CALLS), names


def test_memory_peak_is_this_process_rss_and_the_device_peak_where_there_is_one():
    before = R.memory_peak()
    block = np.ones(64 * 2**20 // 8)  # 64 MiB touched: the host peak can only grow by it
    after = R.memory_peak()
    ram = os.sysconf("SC_PAGE_SIZE") * os.sysconf("SC_PHYS_PAGES") / 2**30
    assert block.sum() > 0 and 1 / 16 <= before["host"] <= after["host"] <= ram  # GiB
    stats = jax.local_devices()[0].memory_stats() or {}
    assert ("device" in after) == ("peak_bytes_in_use" in stats)
