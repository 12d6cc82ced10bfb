"""Where a training step's time goes: the training environment of one preset (the trainer's
wrappers: episode, vmap, auto-reset) at one or more batches B, its parts timed as separate
programs:

    python experiments/env_parts.py [--batch 2048 ...] [--preset zucchini] [--repeats 5]
        [--parts advance observe ...] [--max-resets K] [--spread 300] [--record FILE.jsonl]

- `advance`: physics, end events, reward and the episode's log (every world, no frame);
- `observe`: the camera frame, the teacher's action and the observation;
- `render`: the frame alone (no sensor noise);
- `summarise`: the navigation metrics of every world's episode log (`rollout.metrics`);
- `network`: the policy network on every world's observation;
- `reset_pass`: one pass of the auto-reset loop's reset: `max_resets` new worlds, unobserved;
- `step`: the auto-reset step (advance, the resets of the worlds that ended, observe), with zero
  actions from the first state (no world ends, so no reset pass runs);
- `rollout`: the trainer's rollout as one program (`train.rollout.unroll`: network, step,
  transitions, episode stats; the trainer runs the same as three programs a step,
  `train.rollout.Stepwise`) for `train.unroll` steps, on worlds whose episodes end at a
  steady rate: each world's step count starts uniform in [0, `--spread`) under a time limit
  of `--spread` steps, so about B / spread worlds end per step (as in training, where episodes
  last a few hundred steps). Its env-steps/s is B · unroll over a call.

With `--ops` nothing is compiled or timed: each part's program is lowered and its StableHLO
operations are counted by the innermost `mjxrow` source file that made them (`operations`;
JAX's own, such as loops' plumbing and random bits, under "(no mjxrow line)"), the size that
XLA's compilation time follows (docs/training.md, eighth round). With `--compile-profile DIR`
the operations are counted so, then the parts are compiled side by side under JAX's profiler
(its trace in DIR), not timed, and XLA's compile time is summed by event (`compile_profile`:
passes, pipelines, code generation) over every compiler thread, most self time first;
DIR/compile_profile.csv holds every event.

The programs are lowered one after another and compiled side by side (threads), then each is
timed by `mjxrow.bench.timing.time_runs`: the median of `--repeats` calls after one untimed
call; env-steps/s is B (B · unroll for `rollout`) over it. Run it with
`MJXROW_NONDETERMINISTIC=1` to time the same programs without XLA's deterministic ops.
`--record` appends one row per part and batch (stage `env_parts`) in benchmarks.jsonl's form.
"""

from __future__ import annotations

import argparse
import collections
import csv
import datetime
import functools
import json
import os
import re
import statistics
import sys
import time
from concurrent.futures import ThreadPoolExecutor
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))  # run from a checkout, uninstalled

PARTS = ("advance", "observe", "render", "summarise", "network", "reset_pass", "step", "rollout")


def _programs(preset: str, B: int, parts, max_resets, spread: int) -> dict:
    """{part: (lowered program, its arguments, env steps per call)} at batch B."""
    import jax
    import jax.numpy as jnp

    from mjxrow.rollout import metrics as rollout_metrics
    from mjxrow.train import loop, programs, rollout

    cfg = loop.TrainConfig(presets=(preset,), num_envs=B, max_resets=max_resets,
                           episode_length=spread if "rollout" in parts else None)
    tr = programs.Trainer(cfg)
    env, e = tr.envs[0], tr.raw[0]
    vm = env.env
    key = jax.random.key(0)
    st = jax.jit(env.reset)(key)  # the trainer's worlds, reset
    a = jnp.zeros((B, 2))
    params = tr.init_params(key)
    keys = jax.random.split(key, env.max_resets)
    progs = {
        "advance": (vm.advance, (st, a), B),
        "observe": (vm.observe, (st,), B),
        "render": (lambda s: jax.vmap(lambda d: e.frame(d, d.sim, None))(s.data), (st,), B),
        "summarise": (lambda s: rollout_metrics.summarise(s.data.log, e.dt), (st,), B),
        "network": (tr.net.apply, (params, st.obs), B),
        "reset_pass": (vm.reset_world, (keys,), env.max_resets),
        "step": (env.step, (st, a), B),
    }
    if "rollout" in parts:
        steps = jax.random.randint(jax.random.key(1), (B,), 0, spread)
        spread_st = st.replace(info={**st.info, "steps": steps})
        c = (jnp.float32(0.5), jnp.float32(0.1), jnp.bool_(False))
        unroll = functools.partial(rollout.unroll, tr.net, env, length=cfg.unroll)
        progs["rollout"] = (unroll, (params, spread_st, key, *c), B * cfg.unroll)
    return {p: (jax.jit(fn).lower(*args), args, n) for p, (fn, args, n) in progs.items()
            if p in parts}


NO_LINE = "(no mjxrow line)"


def operations(lowered) -> collections.Counter:
    """{source: StableHLO operations} of a lowered program: each operation under the innermost
    frame of its location in the mjxrow package (the file, relative to the package), else
    under `NO_LINE`."""
    text = lowered.as_text(debug_info=True)
    alias = {m[1]: m[2] for m in re.finditer(r"^#(loc\d*) = loc\((.*)\)$", text, re.M)}

    @functools.cache
    def frames(loc: str) -> tuple:  # (file, line), innermost first
        m = re.match(r'"([^"]+)":(\d+)', loc)
        if m:
            return ((m[1], int(m[2])),)
        inner = re.findall(r"#(loc\d*)\b", loc)  # a name, a call site or a fusion of aliases
        return tuple(f for a in inner for f in frames(alias.get(a, "")))

    counts: collections.Counter = collections.Counter()
    for m in re.finditer(r'^\s*(?:%[^=]*= )?"?(?:stablehlo|chlo)\.\w+.*loc\((.*)\)\s*$',
                         text, re.M):
        ours = [f for f, _ in frames(m[1]) if "/mjxrow/" in f]
        counts[ours[0].rsplit("/mjxrow/", 1)[1] if ours else NO_LINE] += 1
    return counts


def compile_profile(lowered: list, folder: Path) -> list[dict]:
    """Compile `lowered` side by side under JAX's profiler (its trace in `folder`) and sum the
    compiler threads' events by name: [{name, count, self_s, total_s}], most self time first.
    An event's self time leaves out the events it encloses on its thread; a pipeline's name
    ends in ' (jit_NAME)', dropped here so that the programs add up. An event whose work runs
    on other threads (the compile call itself, a thread pool's dispatch) counts its waiting as
    its own."""
    import jax
    from jax.profiler import ProfileData

    with jax.profiler.trace(str(folder)), ThreadPoolExecutor(len(lowered)) as ex:
        list(ex.map(lambda low: low.compile(), lowered))
    path = max(folder.rglob("*.xplane.pb"), key=lambda f: f.stat().st_mtime)
    sums: dict[str, list] = {}

    def add(name: str, total: int, own: int) -> None:
        row = sums.setdefault(re.sub(r" \(jit_\w+\)$", "", name), [0, 0, 0])
        row[0] += 1
        row[1] += own
        row[2] += total

    for plane in ProfileData.from_file(str(path)).planes:
        for line in plane.lines if plane.name.startswith("/host:") else ():
            if line.name == "python":  # the Python side: the calls, not XLA's work
                continue
            events = [e for e in line.events if not e.name.startswith("$")]  # Python's too
            open_: list[list] = []  # [end, name, duration, enclosed] of the enclosing events
            for e in sorted(events, key=lambda e: (e.start_ns, -e.duration_ns)):
                while open_ and open_[-1][0] <= e.start_ns:
                    _end, name, dur, inner = open_.pop()
                    add(name, dur, dur - inner)
                if open_:
                    open_[-1][3] += e.duration_ns
                open_.append([e.end_ns, e.name, e.duration_ns, 0])
            for _end, name, dur, inner in open_:
                add(name, dur, dur - inner)
    rows = [{"name": k, "count": v[0], "self_s": v[1] / 1e9, "total_s": v[2] / 1e9}
            for k, v in sums.items()]
    return sorted(rows, key=lambda r: -r["self_s"])


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(prog="python experiments/env_parts.py",
                                description=__doc__.split("\n")[0])
    p.add_argument("--batch", type=int, nargs="+", default=[2048])
    p.add_argument("--preset", default="zucchini")
    p.add_argument("--repeats", type=int, default=5)
    p.add_argument("--parts", nargs="+", default=list(PARTS), metavar="PART",
                   help=f"what to time: {', '.join(PARTS)} (default: all)")
    p.add_argument("--max-resets", type=int, default=None,
                   help="worlds per reset pass (default: the trainer's, B / 16)")
    p.add_argument("--spread", type=int, default=300,
                   help="rollout: the time limit the step counts are spread over [steps]")
    p.add_argument("--record", type=Path, default=None)
    p.add_argument("--ops", action="store_true",
                   help="count each program's StableHLO operations by source file instead "
                        "(no compilation, no timing)")
    p.add_argument("--compile-profile", type=Path, default=None, metavar="DIR",
                   help="count the operations as --ops does, then compile under JAX's "
                        "profiler (trace in DIR) and print where XLA's time goes (no timing)")
    args = p.parse_args(argv)
    if min(args.batch) < 1 or args.repeats < 1 or args.spread < 2 or (
            args.max_resets is not None and args.max_resets < 1):
        p.error("--batch, --repeats and --max-resets must be ≥ 1, --spread ≥ 2")  # exit 2
    if args.ops and args.compile_profile is not None:
        p.error("--ops and --compile-profile: one at a time (--compile-profile counts the "
                "operations too)")  # exit 2
    if args.record is not None and (args.ops or args.compile_profile is not None):
        p.error("--record: only with timings, not with --ops or --compile-profile")
    if args.compile_profile is not None:
        from mjxrow import files

        try:
            args.compile_profile = files.check_out_dir(args.compile_profile, "--compile-profile")
        except ValueError as e:
            p.error(str(e))
        if (args.compile_profile / "compile_profile.csv").exists():
            p.error(f"--compile-profile {args.compile_profile}: holds a compile_profile.csv "
                    "already (an earlier profile's); give another folder")
    bad = [x for x in args.parts if x not in PARTS]
    if bad:
        p.error(f"--parts: {bad[0]!r} is not one of {', '.join(PARTS)}")
    import jax

    from mjxrow import crops
    from mjxrow.bench.timing import time_runs

    if args.preset not in crops.names():
        print(f"error: --preset: {args.preset!r} is not one of {', '.join(crops.names())}",
              file=sys.stderr)
        return 2
    t0 = time.perf_counter()
    jobs = {(B, part): job for B in args.batch
            for part, job in _programs(args.preset, B, args.parts, args.max_resets,
                                       args.spread).items()}
    lower_s = time.perf_counter() - t0
    if args.ops or args.compile_profile is not None:
        for (B, part), (low, _, _) in jobs.items():
            counts = operations(low)
            print(f"B {B} {part}: {sum(counts.values()):,} operations")
            for source, n in counts.most_common():
                print(f"  {n:8,d}  {source}")
    if args.ops:
        return 0
    if args.compile_profile is not None:
        args.compile_profile.mkdir(parents=True, exist_ok=True)
        t0 = time.perf_counter()
        rows = compile_profile([low for low, _, _ in jobs.values()], args.compile_profile)
        print(f"{len(jobs)} programs: traced in {lower_s:.1f} s, compiled side by side under "
              f"the profiler in {time.perf_counter() - t0:.1f} s; XLA's events, most self "
              "time first (seconds summed over the compiler's threads):")
        for r in rows[:40]:
            print(f"  {r['self_s']:8.2f} self {r['total_s']:8.2f} in all {r['count']:6d}x  "
                  f"{r['name'][:90]}")
        with (args.compile_profile / "compile_profile.csv").open("w", newline="") as f:
            w = csv.DictWriter(f, ["name", "count", "self_s", "total_s"])
            w.writeheader()
            w.writerows(rows)
        return 0
    t0 = time.perf_counter()
    with ThreadPoolExecutor(len(jobs)) as ex:
        compiled = dict(zip(jobs, ex.map(lambda j: j[0].compile(), jobs.values()), strict=True))
    compile_s = time.perf_counter() - t0
    print(f"{len(jobs)} programs: traced in {lower_s:.1f} s, compiled side by side in "
          f"{compile_s:.1f} s", flush=True)
    det = not os.environ.get("MJXROW_NONDETERMINISTIC")
    rows = []
    for (B, part), (_, fargs, n) in jobs.items():
        t = time_runs(compiled[(B, part)], *fargs, repeats=args.repeats)
        med = statistics.median(t["runs_s"])
        k = args.max_resets or max(1, B // 16)
        rows.append({"date": datetime.date.today().isoformat(),
                     "device": jax.devices()[0].device_kind, "stage": "env_parts",
                     "config": f"training env, {args.preset}, {part}, max_resets {k}"
                               + (f", spread {args.spread}" if part == "rollout" else "")
                               + f", deterministic ops {'on' if det else 'off'}",
                     "batch": B, "value": n / med,
                     "unit": "worlds/s" if part == "reset_pass" else "env-steps/s",
                     "run_ms": 1e3 * med,
                     "compile_s": compile_s, "runs_s": t["runs_s"],
                     "command": "python experiments/env_parts.py " + " ".join(sys.argv[1:]),
                     "note": "compile_s: every part's programs compiled side by side"})
        print(f"B {B:6d} {part:10s} run {1e3 * med:9.2f} ms  {n / med:12,.0f} env-steps/s",
              flush=True)
    if args.record is not None:
        with args.record.open("a") as f:
            for r in rows:
                f.write(json.dumps(r) + "\n")
    return 0


if __name__ == "__main__":
    sys.exit(main())
