"""Two processes on this machine through jax.distributed (one CPU device each, collectives
over gloo): the runtime's placement, gathering and agreement, and a whole sweep whose results
equal a single-process run's while only process 0 writes."""

import json
import os
import socket
import subprocess
import sys
from pathlib import Path

import pandas as pd
import pytest
import yaml

ROOT = Path(__file__).resolve().parents[1]


def free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def env(devices: int = 1) -> dict:
    return {**os.environ, "PYTHONPATH": str(ROOT), "MUJOCO_GL": "osmesa",
            "XLA_FLAGS": f"--xla_force_host_platform_device_count={devices}"}


def launch(argv, n: int = 2, timeout: float = 900) -> list[str]:
    """Run `python argv(i)... --coordinator ... --process-id i` as n processes (argv: a list,
    or a function of the process index); their stdout."""
    port = free_port()
    procs = [subprocess.Popen([sys.executable, *(argv(i) if callable(argv) else argv),
                               "--coordinator", f"127.0.0.1:{port}",
                               "--num-processes", str(n), "--process-id", str(i)],
                              stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True,
                              env=env()) for i in range(n)]
    outs = []
    try:
        for p in procs:
            out, err = p.communicate(timeout=timeout)
            assert p.returncode == 0, err[-3000:]
            outs.append(out)
    finally:
        for p in procs:
            if p.poll() is None:
                p.kill()
    return outs


HELPERS = """
import argparse, json, sys
import numpy as np
from mjxrow import runtime as R
p = argparse.ArgumentParser(); R.add_args(p); R.setup(p.parse_args(sys.argv[1:]))
import jax, jax.numpy as jnp
mesh = jax.sharding.Mesh(np.array(jax.devices()), ("batch",))
batched = jax.sharding.NamedSharding(mesh, jax.sharding.PartitionSpec("batch"))
shared = jax.sharding.NamedSharding(mesh, jax.sharding.PartitionSpec())
x = R.put(np.arange(6, dtype=np.float32), batched)
keys = R.put(jax.random.split(jax.random.key(7), 6), batched)
w = R.put({"w": np.float32(10.0)}, shared)
y = jax.jit(lambda x, k, w: x * w["w"] + jax.random.uniform(k[0]) * 0)(x, keys, w)
z = jax.jit(jax.vmap(lambda k: jax.random.uniform(k)))(keys)
print(json.dumps({"devices": len(jax.devices()), "local": len(jax.local_devices()),
                  "addressable": x.is_fully_addressable, "y": R.to_host(y).tolist(),
                  "z": R.to_host(z).tolist(), "writer": R.writer(),
                  "agreed": R.agree({"from": jax.process_index()})}))
"""


def test_runtime_helpers_across_two_processes():
    import jax

    outs = [json.loads(o.strip().splitlines()[-1]) for o in
            launch(["-c", HELPERS, "--no-cache"], timeout=300)]
    expect_z = jax.vmap(jax.random.uniform)(jax.random.split(jax.random.key(7), 6)).tolist()
    for i, o in enumerate(outs):
        assert (o["devices"], o["local"], o["addressable"]) == (2, 1, False)
        assert o["y"] == [0.0, 10.0, 20.0, 30.0, 40.0, 50.0]  # whole array in every process
        assert o["z"] == pytest.approx(expect_z, abs=0)  # keys travelled intact
        assert o["writer"] == (i == 0) and o["agreed"] == {"from": 0}


TINY = {"name": "tiny", "seeds": 2, "batch_size": 4, "controller": {"name": "oracle"},
        "perception": {"source": "ground_truth"},
        "field": {"d_rr": [1.6, 2.4], "terrain_dh": 0.0, "row_length": 6.0,
                  "terrain_length": 10.0, "terrain_width": 10.0, "rows_per_group": 2},
        "episode": {"max_time": 4.0, "start_offset_std": [0.0, 0.1]},
        "sim": {"path_length": 1.5}, "camera": {"width": 16, "height": 16}}


@pytest.mark.slow
def test_sweep_over_two_processes_equals_one(tmp_path):
    cfg = tmp_path / "tiny.yaml"
    cfg.write_text(yaml.safe_dump(TINY))
    sweep = ["-m", "mjxrow.sweep", str(cfg), "--no-progress", "--no-cache"]
    outs = launch(lambda i: [*sweep, "--out", str(tmp_path / f"multi{i}")])
    assert "episodes run" in outs[0] and "episodes run" not in outs[1]
    assert not (tmp_path / "multi1").exists()  # process 1 writes nothing
    subprocess.run([sys.executable, *sweep, "--out", str(tmp_path / "single")], check=True,
                   env=env(2), capture_output=True, timeout=900)
    for name in ("summary.csv", "results.csv"):
        multi = pd.read_csv(tmp_path / "multi0" / name)
        single = pd.read_csv(tmp_path / "single" / name)
        assert len(single) == (4 if name == "summary.csv" else 8)
        pd.testing.assert_frame_equal(multi, single)
