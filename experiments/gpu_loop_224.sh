#!/usr/bin/env bash
# The closed loop at 224 px (bfloat16 segmenter) on one GPU in one call (~8 minutes): pairs
# of `python -m mjxrow.bench closed_loop` processes that compile side by side and take turns
# for the timed calls ($MJXROW_BENCH_LOCK), each with its own empty compilation cache. Run
# from the project root with mujoco importable (PYTHONPATH=/tmp/site:$PWD):
#
#   OUT=DIR bash experiments/gpu_loop_224.sh
#
# For each B of $BATCHES (default "4096 6144"), one pair: the defaults, and the defaults with
# $SETS (default "--set render.deep_share=0.125"). $STEPS control steps per call (default 60),
# 3 timed calls after an untimed first one. Raw rows: $OUT/rows.jsonl; logs: $OUT/<name>.log.
set -uo pipefail
out=${OUT:-/tmp/loop224_out}; mkdir -p "$out"
py=${PY:-python3}
work=${WORK:-/tmp/loop224_work}; rm -rf "$work"; mkdir -p "$work"
export MJXROW_BENCH_LOCK="$work/timing.lock" XLA_PYTHON_CLIENT_PREALLOCATE=false
sets=${SETS:---set render.deep_share=0.125}
nvidia-smi --query-gpu=name,memory.total,driver_version --format=csv,noheader | tee "$out/device.txt"
start=$(date +%s)
job() {  # job NAME ARGS...: one bench process in the background
  local name=$1; shift
  ( env MJXROW_CACHE_DIR="$work/cache_$name" timeout 560 $py -m mjxrow.bench closed_loop \
      --image 224 --seg-dtype bfloat16 --steps "${STEPS:-60}" --repeats 3 \
      --out "$out/rows.jsonl" "$@" > "$out/$name.log" 2>&1
    echo "exit $?" >> "$out/$name.log" ) &
}
for b in ${BATCHES:-4096 6144}; do
  job "default_$b" --batch "$b"
  # shellcheck disable=SC2086  # $sets is a list of arguments
  job "sets_$b" --batch "$b" $sets
  wait  # one pair at a time: two timed programs of this size do not fit the GPU together
  echo "B=$b done at $(( $(date +%s) - start )) s"
done
for f in "$out"/*.log; do echo "== $(basename "$f")"; grep -E "B=|exit|Error" "$f" | tail -4; done
$py - "$out/rows.jsonl" <<'EOF'
import json, statistics, sys
print("\n| config | batch | control steps/s | episodes/min | first call [s] | runs [s] | compile [s] |")
print("|---|---|---|---|---|---|---|")
for line in open(sys.argv[1]):
    r = json.loads(line)
    print(f"| {r['config']} | {r['batch']} | {r['value']:,.0f} | {r['episodes_per_min']:,.0f} | "
          f"{r.get('first_run_s', 0):.2f} | {', '.join(f'{x:.2f}' for x in r['runs_s'])} | "
          f"{r['compile_s']:.1f} |")
EOF
