#!/usr/bin/env bash
# One GPU against two: the same sweep and the same closed-loop benchmark with
# CUDA_VISIBLE_DEVICES=0 and with CUDA_VISIBLE_DEVICES=0,1 (one process; rollout.build shards
# the batch over the local devices). Run from the project root on a two-GPU machine
# (mujoco importable, e.g. PYTHONPATH=/tmp/site:$PWD):
#
#   OUT=DIR bash experiments/gpu_scaling.sh            # default OUT=/tmp/scaling_out
#   SMOKE=1 OUT=DIR bash experiments/gpu_scaling.sh    # tiny sizes: checks the script on a CPU
#   BENCH_SET="--set render.kernel=fused" ...          # extra flags for both benchmark runs
#
# The sweep is sweeps.yaml with 114 seeds (36 cells x 114 = 4,104 episodes) in batches of
# 1,368 (three calls); the benchmark is `python -m mjxrow.bench closed_loop` at B = 2,048,
# 64 x 64. Compile and run time are reported apart; the compilation cache starts empty (each
# device count compiles programs of its own: on two H100s no program was shared). Each run
# stops at SWEEP_LIMIT (default 190) or BENCH_LIMIT (default 180) seconds. Raw figures:
# $OUT/scaling.jsonl (sweep: wall, compile / run / write as the sweep
# prints them) and $OUT/closed_loop.jsonl (bench rows); the two summary.csv files are compared
# at the end (equal, or the largest difference per column), then a short table; both runs'
# summary.csv and results.csv are kept in $OUT/sweeps.tgz.
set -uo pipefail
out=${OUT:-/tmp/scaling_out}; mkdir -p "$out"
py=${PY:-python3}
work=${WORK:-/tmp/scaling_work}
rm -rf "$work"; mkdir -p "$work"
rm -f "$out/scaling.jsonl" "$out/closed_loop.jsonl"
if [ "${SMOKE:-0}" = 1 ]; then
  sweep_flags=(--smoke); bench_flags=(--batch 4 --image 16 --steps 10 --repeats 1)
else
  sweep_flags=(--set seeds=114 --set batch_size=1368)
  bench_flags=(--batch 2048 --image 64 --steps 150 --repeats 3)
fi
read -r -a bench_set <<<"${BENCH_SET:-}"
bench_flags+=("${bench_set[@]}")
{ command -v nvidia-smi >/dev/null && nvidia-smi --query-gpu=name,memory.total,driver_version \
    --format=csv,noheader; } 2>&1 | tee "$out/device.txt"

cache="$work/cache"  # one cache for all runs
sweep_one() {  # sweep_one DEVICES N
  local devs=$1 n=$2
  echo "== sweep on $n GPU(s) ($(date +%T))"
  local t0 t1 rc; t0=$(date +%s.%N)
  CUDA_VISIBLE_DEVICES=$devs timeout "${SWEEP_LIMIT:-190}" $py -m mjxrow.sweep sweeps.yaml \
    "${sweep_flags[@]}" --no-progress --cache-dir "$cache" --out "$work/sweep_$n" \
    >"$out/sweep_$n.log" 2>&1
  rc=$?
  t1=$(date +%s.%N)
  tail -n 2 "$out/sweep_$n.log"
  $py - "$n" "$rc" "$t0" "$t1" "$out/sweep_$n.log" >>"$out/scaling.jsonl" <<'PY'
import json, re, sys
n, rc, t0, t1, log = sys.argv[1:]
rec = {"step": "sweep", "gpus": int(n), "rc": int(rc), "wall_s": round(float(t1) - float(t0), 2)}
m = re.findall(r"time: ([\d.]+) s = (?:start-up [\d.]+ s \+ )?compile ([\d.]+) s .*?\+ run ([\d.]+) s \+ write ([\d.]+) s",
               open(log, errors="replace").read())
if m:
    tot, comp, run, write = m[-1]
    rec.update(inside_s=float(tot), compile_s=float(comp), run_s=float(run), write_s=float(write))
print(json.dumps(rec))
PY
}
bench_one() {  # bench_one DEVICES N
  local devs=$1 n=$2
  echo "== closed loop on $n GPU(s) ($(date +%T))"
  CUDA_VISIBLE_DEVICES=$devs timeout "${BENCH_LIMIT:-180}" $py -m mjxrow.bench closed_loop \
    "${bench_flags[@]}" --cache-dir "$cache" --out "$out/closed_loop.jsonl" \
    >"$out/bench_$n.log" 2>&1 || echo "!! bench on $n GPU(s) failed (log $out/bench_$n.log)"
  tail -n 2 "$out/bench_$n.log"
}
sweep_one 0 1
sweep_one 0,1 2
bench_one 0 1
bench_one 0,1 2
tar czf "$out/sweeps.tgz" -C "$work" --ignore-failed-read sweep_1/summary.csv sweep_1/results.csv \
  sweep_2/summary.csv sweep_2/results.csv 2>/dev/null

$py - "$out" "$work" <<'PY'
import json, pathlib, sys
import pandas as pd
out, work = map(pathlib.Path, sys.argv[1:])
print((out / "device.txt").read_text().strip())
a, b = (work / "sweep_1" / "summary.csv"), (work / "sweep_2" / "summary.csv")
if a.exists() and b.exists():
    x, y = pd.read_csv(a), pd.read_csv(b)
    same = a.read_bytes() == b.read_bytes()
    print(f"\nsummary.csv on 1 and 2 GPUs: {'byte-identical' if same else 'different'}")
    if not same:
        for c in x.columns:
            if x[c].dtype.kind in "fi" and c in y:
                d = (x[c] - y[c]).abs().max()
                if d > 0:
                    print(f"  {c}: largest difference {d:.3g}")
    ra, rb = (pd.read_csv(work / f"sweep_{n}" / "results.csv") for n in (1, 2))
    num = [c for c in ra.columns if ra[c].dtype.kind in "fi" and c in rb]
    diff = (ra[num] - rb[num]).abs().max()
    print(f"results.csv ({len(ra)} episodes): {int((diff > 0).sum())} numeric columns differ"
          + (f", largest {diff.max():.3g} ({diff.idxmax()})" if (diff > 0).any() else ""))
rows = [json.loads(l) for l in (out / "scaling.jsonl").read_text().splitlines() if l.strip()]
bench = [json.loads(l) for l in (out / "closed_loop.jsonl").read_text().splitlines()
         if l.strip()] if (out / "closed_loop.jsonl").exists() else []
print("\n| run | GPUs | wall [s] | compile [s] | run [s] | write [s] |\n|---|---|---|---|---|---|")
for r in rows:
    print(f"| sweep | {r['gpus']} | {r['wall_s']:.1f} | {r.get('compile_s', float('nan')):.1f} | "
          f"{r.get('run_s', float('nan')):.1f} | {r.get('write_s', float('nan')):.1f} |")
print("\n| closed loop | GPUs | B | control steps/s | episodes/min | compile [s] |"
      "\n|---|---|---|---|---|---|")
for r in bench:
    print(f"| {r['config']} | {r.get('devices', '?')} | {r['batch']} | {r['value']:,.0f} | "
          f"{r.get('episodes_per_min', float('nan')):,.0f} | {r['compile_s']:.1f} |")
sw = {r["gpus"]: r for r in rows if "run_s" in r}
if 1 in sw and 2 in sw:
    print(f"\nsweep run-time speed-up on 2 GPUs: {sw[1]['run_s'] / sw[2]['run_s']:.2f}x "
          f"(wall {sw[1]['wall_s'] / sw[2]['wall_s']:.2f}x)")
bd = {r.get("devices"): r for r in bench}
if 1 in bd and 2 in bd:
    print(f"closed-loop speed-up on 2 GPUs: {bd[2]['value'] / bd[1]['value']:.2f}x")
PY
