"""A training run's rollout programs traced in processes, side by side, while the run's own
process compiles each one as soon as it is kept (`Trainer.start_tracing`, then
`Trainer.compile(tracing=...)`).

Python traces one program at a time in a process, and XLA then compiles each for tens of
seconds. So every crop's rollout programs are traced in a process of its own, the one XLA takes
longest over first (`ORDER`), each kept beside the compilation cache (`runtime.exported`) and
reported on a queue the moment it is (`report`). `Tracing.ready` yields them as they come, so
XLA starts on a crop's reset while its frame and advance are still being traced, instead of
after every process has ended.
"""

from __future__ import annotations

import multiprocessing
import os
import queue
import sys
import time
from collections.abc import Callable, Iterator
from concurrent.futures import Future, ProcessPoolExecutor
from pathlib import Path
from typing import Any

ORDER = ("reset", "observe", "advance")  # a crop's programs, most XLA time first (on an H100:
# 59-63, 38-67 and 26-46 s; docs/training.md, tenth round)

_QUEUE: Any = None  # in a tracing process: where `report` puts what it has kept


def _init(q) -> None:
    """A tracing process's start, before JAX starts its backend: GPU memory taken as needed,
    not JAX's default share (it only traces; the run's process holds the worlds), and the
    queue `report` writes to."""
    global _QUEUE
    os.environ["XLA_PYTHON_CLIENT_PREALLOCATE"] = "false"
    _QUEUE = q


def report(crop: int, part: str) -> None:
    """In a tracing process: crop `crop`'s program `part` is kept (nothing elsewhere)."""
    if _QUEUE is not None:
        _QUEUE.put((crop, part))


class Tracing:
    """Every crop's rollout programs being traced by `worker(cfg, crop, cache)` in a process
    each (`start`)."""

    def __init__(self, pool: ProcessPoolExecutor, jobs: list[Future], q, marker: Path,
                 t0: float):
        self.pool, self.jobs, self.queue, self.marker, self.t0 = pool, jobs, q, marker, t0
        self.noted = False

    def ready(self) -> Iterator[tuple[int, str]]:
        """(crop, part) for each of the run's rollout programs, once: as its process reports
        it kept, or, where a process ended without reporting it (a failure, noted once), as
        soon as it ended: the caller then traces it itself (`runtime.exported` finds no kept
        file)."""
        left = {(i, p) for i in range(len(self.jobs)) for p in ORDER}
        while left:
            try:
                got = self.queue.get(timeout=0.2)
            except queue.Empty:
                got = None
            if got in left:
                left.discard(got)
                yield got
                continue
            for i, job in enumerate(self.jobs):
                if job.done():
                    self._note(job)
                    for p in ORDER:
                        if (i, p) in left:
                            left.discard((i, p))
                            yield i, p

    def _note(self, job: Future) -> None:
        e = job.exception()
        if e is not None and not self.noted:
            self.noted = True
            first = str(e).splitlines()[0][:160] if str(e) else ""
            print(f"note: tracing in processes failed ({type(e).__name__}: {first}); "
                  "tracing here", file=sys.stderr)

    def close(self) -> float:
        """End the processes (waiting for those still tracing); where every one kept all it
        traced, write the marker that spares the next run with these programs the processes.
        Returns the seconds since `start`."""
        self.pool.shutdown(wait=True, cancel_futures=True)
        if all(j.done() and not j.cancelled() and j.exception() is None for j in self.jobs):
            self.marker.parent.mkdir(parents=True, exist_ok=True)
            self.marker.write_text("traced\n")
        return time.perf_counter() - self.t0


def start(worker: Callable, cfg: Any, crops: int, cache: str, marker: Path) -> Tracing:
    """`worker(cfg, crop, cache)` for every crop, in a process each (spawned: no CUDA state
    inherited), reporting on a queue of their own."""
    t0 = time.perf_counter()
    ctx = multiprocessing.get_context("spawn")
    q = ctx.Queue()
    pool = ProcessPoolExecutor(crops, mp_context=ctx, initializer=_init, initargs=(q,))
    return Tracing(pool, [pool.submit(worker, cfg, i, cache) for i in range(crops)], q, marker,
                   t0)
