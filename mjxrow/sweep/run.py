"""`python -m mjxrow.sweep SWEEP.yaml [--out DIR] [--smoke] [--set key=value ...]`.

YAML → validated config (config.py) → grid of cells (grid.py) → groups of cells sharing every
static value (one compile each) → batches of episodes → per-episode metrics (groups.py) →
`results.csv`, `summary.csv`, one PNG per metric, `report.md`.

Resumable: each finished cell is written at once to `DIR/cells/<hash>.csv` (temp file +
`os.replace`), `hash` covering the cell's resolved parameters and its group's static field
shape; a re-run verifies each cell file (complete, every episode, its own hash) and skips the
cells whose file passes; a damaged one is reported and recomputed. `DIR/.lock` keeps a second
sweep out of the folder. From the command line, Ctrl-C and SIGTERM at any moment (compilation
included) write results.csv and summary.csv from the finished cells and exit with 130
(mjxrow.interrupt); no finished cell is lost and no file is left half-written.

The evaluation of one group is one call with a narrow interface, `groups.Evaluator` (tests
inject a fake one); `writer.CellWriter` writes each cell's rows as they come; this module
drives the groups with a progress bar and the signals, and writes the outputs.
"""

from __future__ import annotations

import contextlib
import datetime
import json
import signal
import sys
import threading
import time
from pathlib import Path
from typing import Any

import jax
import pandas as pd
from tqdm.auto import tqdm

import mjxrow
from mjxrow import files as mjxrow_files
from mjxrow import interrupt, runtime, stopwatch
from mjxrow.sweep import cells as sweep_cells
from mjxrow.sweep import cli as sweep_cli
from mjxrow.sweep import config as sweep_config
from mjxrow.sweep import estimate as sweep_estimate
from mjxrow.sweep import figures as sweep_figures
from mjxrow.sweep import groups as sweep_groups
from mjxrow.sweep import report as sweep_report
from mjxrow.sweep import writer as sweep_writer

# ---------------------------------------------------------------------------------------------
# Summary


def write_outputs(
    cfg: sweep_config.SweepConfig,
    groups: list[sweep_groups.Group],
    out: Path,
    info: dict[str, Any],
    figures: bool = True,
    pool: Any = None,
) -> dict[str, Path]:
    """results.csv rebuilt from this sweep's cell files, then summary.csv, config.yaml and
    (with `figures`) the PNGs and report.md (plots.write_outputs)."""
    frames = []
    for g in groups:
        for cell, h in zip(g.cells, g.hashes, strict=True):
            p = out / "cells" / f"{h}.csv"
            if p.exists():
                frames.append(pd.read_csv(p).assign(cell=cell.index, group=g.index))
    if not frames:
        return {}
    results = pd.concat(frames, ignore_index=True).sort_values(["cell", "episode"])
    sweep_writer.atomic_write_csv(out / "results.csv", results)
    return {"results": out / "results.csv", **sweep_report.write_outputs(results, cfg, out, info,
                                                                   figures, pool)}


# ---------------------------------------------------------------------------------------------
# Driver


class _Terminated(KeyboardInterrupt):
    pass


def _raise_interrupt(signum, frame):
    raise _Terminated(f"signal {signum}")


@contextlib.contextmanager
def _ticking(bar, enabled: bool):
    """Refresh the bar every second, so elapsed time moves during long batches."""
    stop = threading.Event()

    def tick():
        while not stop.wait(1.0):
            bar.refresh()

    thread = threading.Thread(target=tick, daemon=True)
    if enabled:
        thread.start()
    try:
        yield
    finally:
        stop.set()
        if enabled:
            thread.join()


def _check_cells(out: Path) -> None:
    """OutputError when OUT/cells is a link: its files would be read, removed and written in
    another folder."""
    if (out / "cells").is_symlink():
        raise mjxrow_files.OutputError(f"--out {out}: cells/ is a link to another folder; give "
                                       "a folder of its own")


def run(cfg: sweep_config.SweepConfig, out: str | Path,
        evaluate: sweep_groups.Evaluator | None = None, progress: bool = True,
        command: str = "", figures: bool = True, hard_stop: bool = False,
        started: float | None = None, figure_workers: int = 0,
        estimate: str | None = None) -> dict[str, Any]:
    """Run every unfinished cell of `cfg`, persisting each as it finishes, then write the
    outputs (without `figures`: no PNGs and no report). Returns {'groups', 'ran', 'skipped',
    'files'}. Holds `out/.lock` (files.OutLock): a second run into `out` gets OutputError.

    On Ctrl-C or SIGTERM the finished cells are kept and results.csv and summary.csv hold them;
    then KeyboardInterrupt propagates, or, with `hard_stop` (the CLI), the process ends at once
    with exit code 130, whatever it was doing, compilation included (interrupt.HardStop).
    `started`: when the command started (`mjxrow.STARTED`); the time line then counts the
    start-up (imports, configuration checks) too. `figure_workers` ≥ 2: processes that draw
    the PNGs side by side (figures.figure_pool; started at once, so that their imports overlap
    the sweep). They are spawned, and a spawned process imports the caller's main script
    again: the CLI, whose main module is a package's, passes them; a script calling `run`
    needs an `if __name__ == "__main__":` guard to pass them. `estimate`: the line the command
    printed before the run (estimate.Estimate.text); report.md puts it beside what the run
    took."""
    evaluate = evaluate or sweep_groups.evaluate_group
    out = Path(out)
    _check_cells(out)
    if runtime.writer():  # several processes: process 0 writes, locks and decides what is finished
        (out / "cells").mkdir(parents=True, exist_ok=True)
    with contextlib.ExitStack() as stack:
        if runtime.writer():
            stack.enter_context(mjxrow_files.OutLock(out))
        stop = stack.enter_context(interrupt.HardStop()) if hard_stop else None
        with sweep_figures.figure_pool(figures and runtime.writer(), figure_workers) as pool:
            return _run(cfg, out, evaluate, progress, command, figures, stop, started, pool,
                        estimate)


FACTS = "run.json"  # the facts (date, command, device, timings) of the last run that ran episodes


def _run(
    cfg: sweep_config.SweepConfig,
    out: Path,
    evaluate: sweep_groups.Evaluator,
    progress: bool,
    command: str,
    figures: bool,
    stop: interrupt.HardStop | None,
    started: float | None = None,
    pool: Any = None,
    estimate: str | None = None,
) -> dict[str, Any]:
    watch = stopwatch.Stopwatch(started=started)
    groups = sweep_groups.pending(cfg, out, report=True)
    n_cells = sum(len(g.cells) for g in groups)
    total, todo = n_cells * cfg.seeds, sum(len(g.episodes) for g in groups)
    skipped = (total - todo) // cfg.seeds
    info: dict[str, Any] = {"date": datetime.datetime.now().isoformat(timespec="seconds"),
                            "command": command or "(API call)", "device": _device(),
                            "cells": n_cells, "episodes": total, "groups": len(groups),
                            "cells skipped (already finished)": skipped}
    if estimate:  # report.md shows it beside the wall time the run took
        info["estimated before the run"] = estimate
    bar = tqdm(total=total, initial=total - todo, unit="ep", disable=not progress,
               desc=cfg.name, dynamic_ncols=True)

    def flush() -> None:
        bar.close()
        if pool is not None:  # the figure processes end first (no leaked semaphores on exit)
            pool.shutdown(wait=True, cancel_futures=True)
        if runtime.writer():
            write_outputs(cfg, groups, out, info, figures=False)
        finished = sweep_cells.finished_cells(out / "cells")
        kept = len(finished & {h for g in groups for h in g.hashes})
        print(f"interrupted: {kept} of {n_cells} cells finished and kept in {out}; run the "
              "same command again to resume", file=sys.stderr)

    if stop is not None:
        stop.flush = flush
    old = signal.signal(signal.SIGTERM, _raise_interrupt) \
        if _main_thread() and stop is None else None
    lock = stop.lock if stop is not None else contextlib.nullcontext()
    ran, t0 = 0, time.perf_counter()
    try:
        with _ticking(bar, progress):
            for g in groups:
                if not g.episodes:
                    continue
                bar.set_postfix_str(f"group {g.index}: compiling")
                writer = sweep_writer.CellWriter(g, cfg.seeds, out / "cells", bar, watch, lock,
                                     in_batch=progress and jax.default_backend() == "cpu")
                jax.monitoring.register_event_duration_secs_listener(writer.on_compile)
                try:
                    evaluate(g, cfg, writer)
                finally:
                    jax.monitoring.unregister_event_duration_listener(writer.on_compile)
                    ran += writer.episodes
                    info[f"group {g.index} ({g.shape.crop}, {len(g.cells)} cells)"] = \
                        writer.timing()
    except KeyboardInterrupt:
        with lock:
            flush()
        raise
    finally:
        bar.close()
        if old is not None:
            signal.signal(signal.SIGTERM, old)
    info["wall time"] = f"{time.perf_counter() - t0:.1f} s for {ran} episodes"
    info["memory peak"] = runtime.peak_text(runtime.memory_peak(), digits=2)
    split = watch.split()
    info["time"] = (f"compile {split['compile']:.1f} s, run {split['run']:.1f} s, write cells "
                    f"{split['write']:.1f} s")
    if started is not None:
        info["time"] = f"start-up {split['startup']:.1f} s, " + info["time"]
    files: dict[str, Any] = {}
    if runtime.writer():
        with lock, watch.writing():
            info = _facts(out, info, ran, todo)
            files = write_outputs(cfg, groups, out, info, figures, pool)
    return {"groups": groups, "ran": ran, "skipped": skipped, "files": files, "time": watch}


def _facts(out: Path, info: dict[str, Any], ran: int, todo: int) -> dict[str, Any]:
    """The run facts for report.md: this run's, saved to out/run.json when it ran episodes; a
    re-run with nothing to do keeps the saved facts of the run that made the results, and
    says when it was re-run."""
    path = out / FACTS
    if ran or todo:
        mjxrow_files.atomic_write_text(path, json.dumps(info, indent=1, ensure_ascii=False) + "\n")
        return info
    try:
        saved = json.loads(path.read_text())
    except (OSError, json.JSONDecodeError):
        return info
    return {**saved, "re-run": f"{info['date']} ({info['command']}): every cell already "
            "finished, nothing run"}


def _main_thread() -> bool:
    return threading.current_thread() is threading.main_thread()


def _device() -> str:
    devs = jax.devices()
    return f"{len(devs)} × {devs[0].device_kind}"


# ---------------------------------------------------------------------------------------------
# CLI


def main(argv: list[str] | None = None) -> int:
    """The work of `python -m mjxrow.sweep` (its parser: sweep.cli)."""
    args = sweep_cli.parser().parse_args(argv)
    try:
        runtime.setup(args, cpu_split=True)
        cfg = sweep_config.load(args.config, args.set, args.smoke)
        out = Path(args.out or cfg.out)
        if args.smoke and not args.out:
            out = out.with_name(out.name + "_smoke")
        mjxrow_files.check_out_dir(out, "--out")
        _check_cells(out)  # before its files are read
        cells = out / "cells"
        est = sweep_estimate.estimate(
            sweep_groups.plan(cfg, sweep_cells.finished_cells(cells, cfg.seeds)), cfg.seeds,
            cfg.batch_size, _device_name(), jax.default_backend(), len(jax.local_devices()))
        line = sweep_estimate.check(est, args.force)
        workers = sweep_figures.figure_workers()
    except ValueError as e:
        print(f"error: {e}", file=sys.stderr)
        return 2
    if not args.no_progress:
        print(line, file=sys.stderr)
    command = "python -m mjxrow.sweep " + " ".join(argv if argv is not None else sys.argv[1:])
    try:
        res = run(cfg, out, progress=not args.no_progress, command=command, hard_stop=True,
                  started=mjxrow.STARTED, figure_workers=workers, estimate=line)
    except mjxrow_files.OutputError as e:
        print(f"error: {e}", file=sys.stderr)
        return 2
    except KeyboardInterrupt:
        return 130
    if runtime.writer():
        print(f"{res['ran']} episodes run, {res['skipped']} cells skipped; report: "
              f"{res['files'].get('report', out)}")
        print(res["time"].line())
    return 0


def _device_name() -> str:
    """The device as benchmarks.jsonl names it: the accelerator's name, or `cpu`."""
    dev = jax.devices()[0]
    return "cpu" if dev.platform == "cpu" else dev.device_kind


if __name__ == "__main__":
    sys.exit(main())
