"""One batch of episodes from a RunConfig, scored and written as `episodes.csv` (the work of
`python -m mjxrow.episode`)."""

from __future__ import annotations

import contextlib
import sys
import threading
import time
from pathlib import Path
from typing import Any

import numpy as np
import pandas as pd
from tqdm.auto import tqdm

from mjxrow import field, runtime
from mjxrow.files import atomic_write_text
from mjxrow.rollout import aggregate as rollout_aggregate
from mjxrow.rollout import build as rollout_build
from mjxrow.rollout import metrics
from mjxrow.rollout.config import RunConfig

CSV = "episodes.csv"  # the file a run writes in its folder
CSV_METRICS = metrics.METRICS


@contextlib.contextmanager
def ticker(desc: str, enabled: bool = True):
    """Progress while a blocking call runs: on a terminal a line with the elapsed time,
    refreshed every second; otherwise one line at the start and one at the end."""
    if not enabled:
        yield
        return
    t0 = time.perf_counter()
    if not sys.stderr.isatty():
        print(f"{desc} ...", file=sys.stderr, flush=True)
        yield
        print(f"{desc}: done in {time.perf_counter() - t0:.1f} s", file=sys.stderr, flush=True)
        return
    bar = tqdm(total=None, desc=desc, bar_format="{desc}: {elapsed}")
    stop = threading.Event()

    def tick():
        while not stop.wait(1.0):
            bar.refresh()

    thread = threading.Thread(target=tick, daemon=True)
    thread.start()
    try:
        yield
    finally:
        stop.set()
        thread.join()
        bar.close()


def results_table(run: RunConfig, episodes: np.ndarray, lanes: np.ndarray,
                  summary: dict[str, Any]) -> pd.DataFrame:
    """One row per episode: episode index, lane, field parameters, metrics (reason by name)."""
    cols: dict[str, Any] = {"episode": episodes, "lane": lanes}
    fv = run.field_values()
    cols.update({k: np.full(len(episodes), fv[k], np.float32) for k in field.PARAM_NAMES})
    for k in CSV_METRICS:
        v = np.asarray(summary[k])
        cols[k] = np.asarray(metrics.REASONS)[v] if k == "reason" else v
    return pd.DataFrame(cols)


def run_episodes(run: RunConfig, n: int, out: str | Path, progress: bool = True
                 ) -> pd.DataFrame:
    """Episodes 0..n-1 of `run` (keys as the sweep's: the same seed and config give the same
    episodes as a sweep cell), written to OUT/episodes.csv (replacing one that is there: the
    command checks first); prints timing and the aggregate."""
    if n < 1:
        raise ValueError(f"--n: must be at least 1, got {n}")
    out = Path(out)
    with ticker(f"fields and model ({n} × {run.preset})", progress):
        built = rollout_build.build(run)
        batch = built.batch([(run, e) for e in range(n)])
    t0 = time.perf_counter()
    with ticker("compiling", progress):
        exe = built.executable(batch.args(built.mx))
    t1 = time.perf_counter()
    with ticker(f"running {n} episodes × {built.episode.n_steps} steps", progress):
        log = exe(*batch.args(built.mx))
        summary = built.summarise(log, n)
    t2 = time.perf_counter()
    table = results_table(run, np.arange(n), runtime.to_host(batch.lanes)[:n], summary)
    if not runtime.writer():  # several processes: process 0 reports and writes
        return table
    out.mkdir(parents=True, exist_ok=True)
    atomic_write_text(out / CSV, table.to_csv(index=False))
    print(f"{run.controller.name} on {run.preset}: {n} episodes, compile {t1 - t0:.1f} s, "
          f"run {t2 - t1:.1f} s ({n * built.episode.n_steps / (t2 - t1):.0f} env-steps/s)")
    print(rollout_aggregate.format_table({k: summary[k] for k in CSV_METRICS}))
    print(f"wrote {out / CSV}")
    return table
