"""What every benchmark stage shares: timed calls (compile apart from run, interleaved variants,
the lock of several bench processes on one machine), the device's name, and the rows appended
to `benchmarks.jsonl` and printed as a table."""

from __future__ import annotations

import contextlib
import datetime
import fcntl
import json
import os
import statistics
import subprocess
import sys
import time
from collections.abc import Callable
from pathlib import Path
from typing import Any

import jax


def device_name() -> str:
    """The accelerator's name as nvidia-smi prints it, or 'cpu'."""
    if jax.default_backend() == "cpu":
        return "cpu"
    try:
        out = subprocess.run(["nvidia-smi", "--query-gpu=name", "--format=csv,noheader"],
                             capture_output=True, text=True, timeout=10).stdout.strip()
        return out.splitlines()[0] if out else jax.devices()[0].device_kind
    except (OSError, subprocess.SubprocessError):
        return jax.devices()[0].device_kind


LOCK_ENV = "MJXROW_BENCH_LOCK"
XLA_FLAGS = os.environ.get("XLA_FLAGS", "").strip()  # as given (before runtime.cpu_devices)


@contextlib.contextmanager
def timing_lock():
    """Held around the timed calls when $MJXROW_BENCH_LOCK names a file: several bench
    processes on one machine then compile side by side but time one at a time."""
    path = os.environ.get(LOCK_ENV)
    if not path:
        yield
        return
    with open(path, "a") as f:
        fcntl.flock(f, fcntl.LOCK_EX)
        try:
            yield
        finally:
            fcntl.flock(f, fcntl.LOCK_UN)


def time_call(fn: Callable[..., Any], *args: Any, repeats: int = 5) -> dict[str, float]:
    """Compile time (first call) apart from run time: median and all of `repeats` further calls.
    Seconds; every call is waited for with block_until_ready. The further calls run under
    `timing_lock`."""
    t0 = time.perf_counter()
    jax.block_until_ready(fn(*args))
    compile_s = time.perf_counter() - t0
    runs = time_runs(fn, *args, repeats=repeats)["runs_s"]
    return {"compile_s": compile_s, "median_s": statistics.median(runs), "runs_s": runs}


def time_runs(fn: Callable[..., Any], *args: Any, repeats: int) -> dict[str, Any]:
    """Under `timing_lock`: one untimed call (after the wait for the lock; it also sets up
    what a program runs once, e.g. its CUDA graphs), then `repeats` timed ones. Returns
    {first_s, runs_s, out (the last call's output)}; every call is waited for."""
    runs = []
    with timing_lock():
        t0 = time.perf_counter()
        out = jax.block_until_ready(fn(*args))
        first_s = time.perf_counter() - t0
        for _ in range(repeats):
            t0 = time.perf_counter()
            out = jax.block_until_ready(fn(*args))
            runs.append(time.perf_counter() - t0)
    return {"first_s": first_s, "runs_s": runs, "out": out}


def time_interleaved(calls: dict[Any, Callable[[], Any]], rounds: int) -> dict[Any, list[float]]:
    """Seconds of each of `calls` (compiled already), timed in `rounds` interleaved rounds under
    `timing_lock`, every call waited for: variants compared in one process, so that no other
    process's compilation or autotuning shares the device with a timed call."""
    times = {name: [] for name in calls}
    with timing_lock():
        for _ in range(rounds):
            for name, call in calls.items():
                t0 = time.perf_counter()
                jax.block_until_ready(call())
                times[name].append(time.perf_counter() - t0)
    return times


def record(rows: list[dict], path: str | Path = "benchmarks.jsonl",
           command: str | None = None) -> None:
    """Append rows ({stage, config, batch, value, unit, ...}) with date, device and command
    (default: this `python -m mjxrow.bench` command line; and $XLA_FLAGS where set: they
    change compile and run times)."""
    base = {"date": datetime.date.today().isoformat(), "device": device_name(),
            "command": command or "python -m mjxrow.bench " + " ".join(sys.argv[1:])}
    if XLA_FLAGS:
        base["xla_flags"] = XLA_FLAGS
    with open(path, "a") as f:
        for row in rows:
            f.write(json.dumps({**base, **row}) + "\n")


def print_table(rows: list[dict]) -> None:
    print("\n| device | stage | config | batch | value | unit |\n|---|---|---|---|---|---|")
    dev = device_name()
    for r in rows:
        print(f"| {dev} | {r['stage']} | {r['config']} | {r['batch']} | {r['value']:.4g} | "
              f"{r['unit']} |")
