#!/usr/bin/env bash
# Renderer and closed-loop speed on one GPU in one call (~7 minutes): the benchmarks run as
# parallel processes that compile side by side and take turns for the timed calls
# ($MJXROW_BENCH_LOCK), each with its own empty compilation cache (compile times are cold).
# Run from the project root with mujoco importable (PYTHONPATH=/tmp/site:$PWD):
#
#   OUT=DIR bash experiments/gpu_speed_round.sh
#
#  render_z2 / render_z1   bench render, zucchini, 64 and 128 px, B = 1024, deep tiles split
#                          in 2 x 2 sub-tiles (the default) / not split (render.deep_split=1)
#  render_l2 / render_l1   the same for lettuce (the crop whose deep tiles keep 192 plants)
#  loop_64                 bench closed_loop, 64 px, B = 1024, 2048, 4096
#  loop_64_noautotune      the same at B = 1024 with XLA's autotuning off (compile time)
#  loop_224                bench closed_loop, 224 px, B = 512, 1024
# Raw rows: $OUT/benchmarks.jsonl; logs: $OUT/<name>.log; a short table last.
set -uo pipefail
out=${OUT:-/tmp/speed_out}; mkdir -p "$out"
py=${PY:-python3}
work=${WORK:-/tmp/speed_work}; rm -rf "$work"; mkdir -p "$work"
export MJXROW_BENCH_LOCK="$work/timing.lock" XLA_PYTHON_CLIENT_PREALLOCATE=false
jsonl="$PWD/benchmarks.jsonl"; lines0=$(wc -l < "$jsonl")
nvidia-smi --query-gpu=name,memory.total,driver_version --format=csv,noheader | tee "$out/device.txt"

job() {  # job NAME [ENV=VALUE ...] -- ARGS: one bench process in the background
  local name=$1; shift
  local envs=()
  while [ "$1" != "--" ]; do envs+=("$1"); shift; done; shift
  ( env MJXROW_CACHE_DIR="$work/cache_$name" "${envs[@]}" timeout 560 \
      $py -m mjxrow.bench "$@" > "$out/$name.log" 2>&1; echo "exit $?" >> "$out/$name.log" ) &
}
start=$(date +%s)
job render_z2 -- render --preset zucchini --res 64 128 --batch 1024
job render_z1 -- render --preset zucchini --res 64 128 --batch 1024 --set deep_split=1
job render_l2 -- render --preset lettuce --res 64 128 --batch 1024
job render_l1 -- render --preset lettuce --res 64 128 --batch 1024 --set deep_split=1
job loop_64 -- closed_loop --image 64 --batch 1024 2048 4096 --steps 150 --repeats 3
job loop_64_noautotune XLA_FLAGS=--xla_gpu_autotune_level=0 -- \
  closed_loop --image 64 --batch 1024 --steps 150 --repeats 3
job loop_224 -- closed_loop --image 224 --batch 512 1024 --steps 150 --repeats 2
wait
echo "all done in $(( $(date +%s) - start )) s"
tail -n +$((lines0 + 1)) "$jsonl" > "$out/benchmarks.jsonl"
for f in "$out"/*.log; do echo "== $(basename "$f")"; grep -E "B=|frames/s|exit|Error|error" "$f" | tail -8; done
$py - "$out/benchmarks.jsonl" <<'EOF'
import json, sys
print("\n| stage | config | batch | value | unit | compile [s] |\n|---|---|---|---|---|---|")
for line in open(sys.argv[1]):
    r = json.loads(line)
    print(f"| {r['stage']} | {r['config']} | {r['batch']} | {r['value']:,.0f} | {r['unit']} | "
          f"{r.get('compile_s', 0):.1f} |")
EOF
