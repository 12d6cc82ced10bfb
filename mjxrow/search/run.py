"""`python -m mjxrow.search SEARCH.yaml [--out DIR] [--smoke] [--set KEY=VALUE ...] [--confirm N]`.

Finds fields where a controller fails: a search method (CMA-ES by default) proposes a generation
of candidates in the normalised box, each candidate runs `repeats` episodes, all of them in ONE
call of the compiled closed loop (every searched key is traced: no recompilation between
generations), and their failures and margins steer the next generation. Then the baseline
(uniform random sampling by default) runs as many episodes, for comparison. Outputs in DIR:
`candidates.csv` (every candidate), `failures.csv` (the distinct failures, ranked),
`convergence.png`, `pairs.png`, `failure_<rank>.png` (first camera frame, mask, trajectory over
the plants), `report.md`; with `--confirm N`, `confirm.csv`: the top failures re-run with N new
seeds each. The last lines printed are a summary table.

Resumable: after every generation `candidates.csv` and then `state.json` (the streams' states:
generation, episodes, CMA-ES's mean, step and covariance) are written atomically; the same
command continues where it stopped, asking for exactly the candidates an uninterrupted run
would (a larger budget continues too). Ctrl-C or SIGTERM at any moment exits 130 keeping every
finished generation. `DIR/.lock` keeps a second search out of the folder.
"""

from __future__ import annotations

import contextlib
import datetime
import json
import sys
import time
from pathlib import Path
from typing import Any

import jax
import numpy as np
import pandas as pd
import yaml
from tqdm.auto import tqdm

import mjxrow
from mjxrow import files as mjxrow_files
from mjxrow import interrupt, runtime
from mjxrow.search import box as search_box
from mjxrow.search import cli as search_cli
from mjxrow.search import config as search_config
from mjxrow.search import evaluate as search_evaluate
from mjxrow.search import methods as search_methods
from mjxrow.search import objective
from mjxrow.search import report as search_report
from mjxrow.sweep.yamlfile import read_yaml

STATE, CANDIDATES, CONFIG = "state.json", "candidates.csv", "config.yaml"
COMPILE_EVENT = "/jax/core/compile/backend_compile_duration"
TABU = 1.5  # added to a failure near a known one (so −0.5): CMA-ES looks for new ones
INVALID = 3.0  # fitness of an invalid candidate: below every valid one (margins ≤ 1)
BOUNDARY = 0.1  # weight of the squared distance outside the box, times the fitness spread


class _Search:
    """The state of one search folder: its streams, the candidates so far, the evaluator."""

    def __init__(self, cfg: search_config.SearchConfig, out: Path, progress: bool, lock):
        self.cfg, self.out, self.progress, self.lock = cfg, out, progress, lock
        self.streams = [cfg.method] + ([cfg.baseline] if cfg.baseline != "none" else [])
        self.state: dict[str, Any] = {"version": 1, "shape": repr(cfg.shape), "streams": {},
                                      "compile_s": 0.0}
        self.rows = pd.DataFrame()
        self.evaluator: search_evaluate.Evaluator | None = None
        self.ran = 0
        self.generations_here: dict[str, int] = {}  # per stream, run by this process
        self.seen: dict[str, np.ndarray] = {}  # per stream, its distinct failures so far
        self._load()

    # --- files -----------------------------------------------------------------------------

    def _load(self) -> None:
        if not (self.out / STATE).exists():
            return
        state = _read_state(self.cfg, self.out)
        self.state = state
        n = int(state.get("rows", 0))
        if n:
            self.rows = pd.read_csv(self.out / CANDIDATES).iloc[:n].reset_index(drop=True)

    def save(self) -> None:
        """candidates.csv, then state.json (the commit point: it says how many rows count)."""
        self.state["rows"] = len(self.rows)
        with self.lock:
            mjxrow_files.atomic_write_text(self.out / CANDIDATES, self.rows.to_csv(index=False))
            mjxrow_files.atomic_write_text(self.out / STATE, json.dumps(self.state) + "\n")

    def get_evaluator(self) -> search_evaluate.Evaluator:
        """The compiled program of this search, built on first need."""
        if self.evaluator is None:
            self.evaluator = search_evaluate.Evaluator(self.cfg)
        return self.evaluator

    # --- streams ---------------------------------------------------------------------------

    def stream_rows(self, name: str) -> pd.DataFrame:
        if self.rows.empty:
            return self.rows
        return self.rows[self.rows["method"] == name]

    def _u(self, df: pd.DataFrame) -> np.ndarray:
        return df[[f"u_{j}" for j in range(len(self.cfg.box))]].to_numpy(float)

    def _done(self, name: str, st: dict[str, Any]) -> str:
        """Why the stream `name` stops before its next generation ('' to go on)."""
        cfg = self.cfg
        if name == cfg.method:
            if cfg.episodes is not None and st["episodes"] + cfg.generation > cfg.episodes:
                return "episodes"
            # the next generation's time: the last one's that compiled nothing (the first of
            # a process compiles the program)
            if cfg.minutes is not None and st["generation"] and (
                    st["elapsed_s"] + st.get("last_s", 0.0) > 60.0 * cfg.minutes):
                return "minutes"
            if cfg.failures is not None and st.get("distinct", 0) >= cfg.failures:
                return "failures"
            return ""
        target = self.state["streams"][cfg.method]["episodes"]
        return "episodes" if st["episodes"] >= target else ""

    def run_stream(self, name: str) -> None:
        cfg = self.cfg
        st = self.state["streams"].setdefault(
            name, {"generation": 0, "episodes": 0, "elapsed_s": 0.0, "distinct": 0,
                   "stall": 0, "best": None})
        stream = search_methods.make(name, len(cfg.box), cfg.population, cfg.seed, cfg.sigma)
        if "method" in st:
            stream.load(st["method"])
        total = cfg.episodes if name == cfg.method else \
            self.state["streams"][cfg.method]["episodes"]
        bar = tqdm(total=total, initial=st["episodes"], unit="ep", desc=f"{cfg.name}: {name}",
                   disable=not self.progress, dynamic_ncols=True)
        try:
            while not self._done(name, st):
                self._generation(name, stream, st)
                bar.update(int(self.rows["episodes_spent"].iloc[-1]) - bar.n)
                best = self.stream_rows(name)["margin"].min()
                fails = int((self.stream_rows(name)["outcome"] == "fail").sum())
                bar.set_postfix_str(f"gen {st['generation']}, best margin {best:.3f}, "
                                    f"{fails} failing ({st['distinct']} distinct)", refresh=False)
            st["stopped_by"] = self._done(name, st)
        finally:
            bar.close()

    def _generation(self, name: str, stream: search_methods.Stream, st: dict[str, Any]) -> None:
        cfg, g = self.cfg, st["generation"]
        t0 = time.perf_counter()
        U, raw = stream.ask(g)
        cands = search_box.candidates(cfg.scenario, cfg.box, U, cfg.shape)
        k0 = g * cfg.population
        items = [(run, (k0 + i) * cfg.repeats + r) for i, (run, _) in enumerate(cands)
                 if run is not None for r in range(cfg.repeats)]
        res = self.get_evaluator().episodes(items) if items else None
        earlier = self.stream_rows(name)
        known = self._u(earlier[earlier["outcome"] == "fail"]) if len(earlier) else \
            np.zeros((0, len(cfg.box)))
        rows, j = [], 0
        for i, (run, why) in enumerate(cands):
            row: dict[str, Any] = {"method": name, "generation": g, "candidate": k0 + i}
            if run is None:
                row.update(outcome="invalid", fail_rate=np.nan, margin=np.nan, episodes="",
                           reasons="", first_failing=-1, lane=-1, invalid=why)
            else:
                sl = slice(j, j + cfg.repeats)
                j += cfg.repeats
                fail = objective.failed(res["reason"][sl])
                eps = [e for _, e in items[sl]]
                row.update(outcome="fail" if fail.mean() >= cfg.fail_share else "pass",
                           fail_rate=float(fail.mean()), margin=float(res["margin"][sl].mean()),
                           episodes=";".join(map(str, eps)),
                           reasons=";".join(search_report.reason_names(res["reason"][sl])),
                           first_failing=int(eps[int(np.argmax(fail))]) if fail.any() else -1,
                           lane=int(res["lane"][sl][int(np.argmax(fail))]), invalid="")
            row.update({f"u_{d}": float(U[i, d]) for d in range(len(cfg.box))})
            row.update(search_box.values(cfg.box, U[i]))
            rows.append(row)
        df = pd.DataFrame(rows)
        valid = df["outcome"] != "invalid"
        fit = np.where(valid, df["margin"].fillna(0.0), INVALID)
        failing = (df["outcome"] == "fail").to_numpy()
        fit = fit + TABU * (failing & objective.near(U, known, cfg.merge_radius))
        # outside the box: evaluated at its nearest point, told with the squared distance to
        # it, weighed by a tenth of the generation's spread of fitness (scale-free)
        fit = fit + BOUNDARY * np.ptp(fit) * np.sum((raw - U) ** 2, axis=1)
        stream.tell(g, raw, fit)
        if name not in self.seen:  # the distinct failures of the rows before this process
            self.seen[name] = objective.extend_distinct(np.zeros((0, len(cfg.box))), known,
                                                        cfg.merge_radius)
        self.seen[name] = objective.extend_distinct(self.seen[name], U[failing],
                                                    cfg.merge_radius)
        distinct = len(self.seen[name])
        gen_best = float(np.min(fit))
        progress = distinct > st["distinct"] or st["best"] is None or gen_best < st["best"] - 1e-6
        st["stall"] = 0 if progress else st["stall"] + 1
        st["best"] = gen_best if st["best"] is None else min(st["best"], gen_best)
        st["distinct"] = distinct
        df["restart"] = getattr(stream, "restarts", 0)  # the start these were sampled from
        if isinstance(stream, search_methods.CMAES) and (
                st["stall"] >= cfg.patience or stream.spread() < 0.1 * cfg.merge_radius):
            stream.restart()
            st["stall"], st["best"] = 0, None
        st["generation"] = g + 1
        st["episodes"] += len(items)
        took = time.perf_counter() - t0
        if self.generations_here.get(name):  # not this process's first: no compilation in it
            st["last_s"] = took
        self.generations_here[name] = self.generations_here.get(name, 0) + 1
        st["elapsed_s"] += took
        st["method"] = stream.state()
        df["episodes_spent"] = st["episodes"]
        df["elapsed_s"] = round(st["elapsed_s"], 3)
        df["seed"] = cfg.seed
        self.rows = pd.concat([self.rows, df], ignore_index=True)
        self.ran += len(items)
        self.save()


def _read_state(cfg: search_config.SearchConfig, out: Path) -> dict[str, Any]:
    """`out`'s state.json once it is a mapping of this search's field shape whose row count
    candidates.csv can hold; OutputError naming --out and the file otherwise."""
    def bad(why: str) -> mjxrow_files.OutputError:
        return mjxrow_files.OutputError(f"--out {out}: {STATE} {why}; remove the folder to "
                                        "start again")

    try:
        state = json.loads((out / STATE).read_text())
    except (OSError, ValueError) as e:  # JSONDecodeError, UnicodeDecodeError: ValueErrors
        raise bad(f"is unreadable ({str(e).splitlines()[0] if str(e) else type(e).__name__})"
                  ) from None
    if not isinstance(state, dict):
        raise bad(f"is not a mapping (a {type(state).__name__})")
    if state.get("shape") != repr(cfg.shape):
        raise mjxrow_files.OutputError(f"--out {out}: its search has another field shape (the "
                                       "field generator or limits changed)")
    rows = state.get("rows", 0)
    if isinstance(rows, bool) or not isinstance(rows, int) or rows < 0:
        raise bad(f"counts {rows!r} rows, not a number of candidates")
    if rows and not (out / CANDIDATES).is_file():
        raise bad(f"counts {rows} candidates but {CANDIDATES} is missing")
    return state


def _check_folder(cfg: search_config.SearchConfig, out: Path) -> None:
    """OutputError unless `out` is new, empty of a search, or holds this search (same
    identity: the candidates it asks for are the same), its files readable; nothing is
    written before this check."""
    if (out / STATE).exists():
        _read_state(cfg, out)
        try:  # strictly, as a search YAML: no alias bomb
            saved = search_config.from_dict(read_yaml(out / CONFIG), out)
        except (OSError, ValueError) as e:
            raise mjxrow_files.OutputError(f"--out {out}: holds a search whose {CONFIG} cannot "
                                           f"be read ({str(e).splitlines()[0]})") from None
        a, b = search_config.identity(saved), search_config.identity(cfg)
        if a != b:
            key = next(k for k in sorted(set(a) | set(b)) if a.get(k) != b.get(k))
            raise mjxrow_files.OutputError(f"--out {out}: holds another search ({key} differs); "
                                           "choose another --out")
    elif (out / CANDIDATES).exists():
        raise mjxrow_files.OutputError(f"--out {out}: holds {CANDIDATES} but no {STATE}; choose "
                                       "another --out")


def run(cfg: search_config.SearchConfig, out: str | Path, progress: bool = True,
        figures: bool = True, confirm: int = 0, confirm_top: int = 20, command: str = "",
        hard_stop: bool = False) -> dict[str, Any]:
    """Run (or resume) the search of `cfg` into `out`, then its baseline, then write the
    outputs (without `figures`: no PNGs); with `confirm` > 0, re-run the top `confirm_top`
    distinct failures with `confirm` new seeds each. Returns {'candidates', 'failures',
    'summary' (one row per method), 'confirm', 'ran', 'files', 'compile_s', 'wall_s'}.
    The notebook's entry point (`mjxrow.run_search`); any registered controller."""
    out = Path(out)
    _check_folder(cfg, out)
    out.mkdir(parents=True, exist_ok=True)
    t0 = time.perf_counter()
    with contextlib.ExitStack() as stack:
        stack.enter_context(mjxrow_files.OutLock(out))
        stop = stack.enter_context(interrupt.HardStop()) if hard_stop else None
        lock = stop.lock if stop is not None else contextlib.nullcontext()
        with lock:  # this run's budget and `top` (the rest is the folder's search)
            mjxrow_files.atomic_write_text(out / CONFIG, yaml.safe_dump(
                search_config.to_dict(cfg), sort_keys=False, allow_unicode=True))
        search = _Search(cfg, out, progress, lock)
        if stop is not None:
            stop.flush = lambda: print(f"interrupted: {len(search.rows)} candidates kept in "
                                       f"{out}; run the same command again to resume",
                                       file=sys.stderr)
        compile_s = [0.0]

        def on_compile(event: str, seconds: float, **_) -> None:
            if event == COMPILE_EVENT:
                compile_s[0] += seconds

        jax.monitoring.register_event_duration_secs_listener(on_compile)
        try:
            for name in search.streams:
                search.run_stream(name)
        finally:
            jax.monitoring.unregister_event_duration_listener(on_compile)
            search.state["compile_s"] = search.state.get("compile_s", 0.0) + compile_s[0]
            if search.ran:
                search.save()
        info = {"date": datetime.datetime.now().isoformat(timespec="seconds"),
                "command": command or "(API call)", "device": _device(),
                "episodes run by this command": search.ran}
        with lock:
            res = search_report.write_outputs(cfg, out, search.rows, search.state, info,
                                              search, figures, confirm, confirm_top)
    res.update(ran=search.ran, compile_s=search.state["compile_s"],
               wall_s=time.perf_counter() - t0)
    return res


def prepare(cfg: search_config.SearchConfig) -> float:
    """Compile the program of a search of `cfg` ahead of it (`Evaluator.prepare`), e.g. in a
    thread beside other work; with the compilation cache on (`runtime.cache_dir`), the
    search's first generation then compiles nothing. Returns the seconds it took."""
    t0 = time.perf_counter()
    search_evaluate.Evaluator(cfg).prepare()
    return time.perf_counter() - t0


def _device() -> str:
    devs = jax.devices()
    return f"{len(devs)} × {devs[0].device_kind}"


def _device_name() -> str:
    """The device as benchmarks.jsonl names it: the accelerator's name, or `cpu`."""
    dev = jax.devices()[0]
    return "cpu" if dev.platform == "cpu" else dev.device_kind


def main(argv: list[str] | None = None) -> int:
    """The work of `python -m mjxrow.search` (its parser: search.cli)."""
    args = search_cli.parse(argv)
    try:
        runtime.setup(args, cpu_split=True)
        cfg = search_config.load(args.config, args.set, args.smoke)
        out = Path(args.out or cfg.out)
        if args.smoke and not args.out:
            out = out.with_name(out.name + "_smoke")
        mjxrow_files.check_out_dir(out, "--out")
        _check_folder(cfg, out)
        if args.record:
            mjxrow_files.check_out_file(args.record, "--record")
    except ValueError as e:
        print(f"error: {e}", file=sys.stderr)
        return 2
    if not args.no_progress and cfg.valid_share < 1:
        print(f"note: {100 * (1 - cfg.valid_share):.0f} % of the box gives impossible fields; "
              "those candidates are scored as invalid and not run", file=sys.stderr)
    command = "python -m mjxrow.search " + " ".join(argv if argv is not None else sys.argv[1:])
    try:
        res = run(cfg, out, progress=not args.no_progress, command=command, hard_stop=True,
                  confirm=args.confirm, confirm_top=args.confirm_top)
    except mjxrow_files.OutputError as e:
        print(f"error: {e}", file=sys.stderr)
        return 2
    except KeyboardInterrupt:
        return 130
    wall = time.time() - mjxrow.STARTED
    if args.record:
        search_report.record(args.record, cfg, res, command, wall, _device_name())
    print(f"report: {res['files'].get('report', out)}")
    print(search_report.summary_text(cfg, res))
    return 0


if __name__ == "__main__":
    sys.exit(main())
