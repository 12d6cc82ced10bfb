"""Where a command's time went: JAX's compile spans (tracing, lowering, XLA compilation or
loading from the persistent cache) and cache hits, recorded by `listen` from `jax.monitoring`,
and a `Stopwatch` that splits the wall time since its creation into start-up, compile, run and
write.

    watch = stopwatch.Stopwatch(started=mjxrow.STARTED)
    ...
    print(watch.line())            # time: 12.3 s = start-up 1.2 s + compile 4.5 s (...) + ...
"""

from __future__ import annotations

import contextlib
import dataclasses
import time
from typing import Any

import jax

_SPANS: dict[str, list[tuple[float, float]]] = {}
_COUNTS: dict[str, int] = {}
_EVENTS = {"/jax/core/compile/jaxpr_trace_duration": "trace",
           "/jax/core/compile/jaxpr_to_mlir_module_duration": "lower",
           "/jax/core/compile/backend_compile_duration": "compile"}
_LISTENING = False


def _on_span(event: str, start: float, end: float, **_: Any) -> None:
    if event in _EVENTS:
        _SPANS.setdefault(_EVENTS[event], []).append((start, end))


def _on_event(event: str, **_: Any) -> None:
    for name in ("cache_hits", "cache_misses"):
        if event == f"/jax/compilation_cache/{name}":
            _COUNTS[name] = _COUNTS.get(name, 0) + 1


def listen() -> None:
    """Start recording compile spans and cache hits (once per process; idempotent)."""
    global _LISTENING
    if not _LISTENING:
        if hasattr(jax.monitoring, "register_event_time_span_listener"):
            jax.monitoring.register_event_time_span_listener(_on_span)
        else:  # older JAX: spans from durations, ending when reported
            jax.monitoring.register_event_duration_secs_listener(
                lambda e, d, **kw: _on_span(e, time.time() - d, time.time()))
        jax.monitoring.register_event_listener(_on_event)
        _LISTENING = True


def union_seconds(spans: list[tuple[float, float]], since: float = float("-inf")) -> float:
    """Length of the union of [start, end] intervals (nested traces count once), clipped to
    start at `since`."""
    total, reach = 0.0, since
    for a, b in sorted(spans):
        a = max(a, reach)
        if b > a:
            total += b - a
            reach = b
    return total


@dataclasses.dataclass
class Stopwatch:
    """Wall time since creation split into compile (tracing, lowering to MLIR, XLA
    compilation or loading from the cache: the union of JAX's compile spans, in seconds),
    write (time spent inside `writing()`) and run (the rest). `started`: an earlier time
    (a command's `mjxrow.STARTED`) from which the seconds up to creation count as start-up
    (imports, configuration checks) and into the total."""

    t0: float = dataclasses.field(default_factory=time.time)
    started: float | None = None
    write_s: float = 0.0
    counts0: dict = dataclasses.field(default_factory=lambda: dict(_COUNTS))

    def __post_init__(self):
        listen()

    @contextlib.contextmanager
    def writing(self):
        t = time.perf_counter()
        try:
            yield
        finally:
            self.write_s += time.perf_counter() - t

    def split(self) -> dict[str, float]:
        """{'total', 'startup', 'compile', 'trace', 'lower', 'xla', 'run', 'write'} seconds,
        the XLA programs compiled or loaded ('programs') and the cache hits / misses since
        creation."""
        total = time.time() - self.t0
        every = [s for v in _SPANS.values() for s in v]
        out = {"total": total, "compile": union_seconds(every, self.t0),
               **{("xla" if k == "compile" else k): union_seconds(_SPANS.get(k, []), self.t0)
                  for k in ("trace", "lower", "compile")},
               "write": self.write_s}
        out["run"] = max(total - out["compile"] - out["write"], 0.0)
        out["startup"] = max(self.t0 - self.started, 0.0) if self.started is not None else 0.0
        out["total"] += out["startup"]
        out["programs"] = sum(1 for a, _ in _SPANS.get("compile", []) if a >= self.t0)
        for k in ("cache_hits", "cache_misses"):
            out[k] = _COUNTS.get(k, 0) - self.counts0.get(k, 0)
        return out

    def line(self) -> str:
        s = self.split()
        cache = f"; {s['programs']} XLA programs"
        if s["cache_hits"] or s["cache_misses"]:
            cache += f", cache {s['cache_hits']} hits, {s['cache_misses']} misses"
        start = f"start-up {s['startup']:.1f} s + " if self.started is not None else ""
        return (f"time: {s['total']:.1f} s = {start}compile {s['compile']:.1f} s (trace "
                f"{s['trace']:.1f}, lower {s['lower']:.1f}, XLA or cache load {s['xla']:.1f}"
                f"{cache}) + run {s['run']:.1f} s + write {s['write']:.1f} s")
