#!/usr/bin/env bash
# The segmenter's speed by implementation on one GPU, and where the 224-px closed loop and
# renderer spend their time (one call, ~8 minutes). Run from the project root with mujoco
# importable (PYTHONPATH=/tmp/site:$PWD):
#
#   OUT=DIR bash experiments/gpu_seg_speed.sh
#
#  seg_<dtype>_<dw>_<pw>   bench segmenter, shipped zucchini weights, 224 and 64 px, B = 1024,
#                          every compute dtype x depthwise (conv, shift) x 1x1 (conv, dot);
#                          side by side, timed in turn ($MJXROW_BENCH_LOCK)
#  profile_loop_224        experiments/profile_closed_loop.py, 224 px, B = 1024 (defaults)
#  profile_render_224      experiments/profile_render.py, 224 px, B = 1024
# SEG_ONLY=1 skips the two profiles. Raw rows: $OUT/benchmarks.jsonl; logs: $OUT/<name>.log.
set -uo pipefail
out=${OUT:-/tmp/seg_speed_out}; mkdir -p "$out"
py=${PY:-python3}
work=${WORK:-/tmp/seg_speed_work}; rm -rf "$work"; mkdir -p "$work"
export MJXROW_BENCH_LOCK="$work/timing.lock" XLA_PYTHON_CLIENT_PREALLOCATE=false
jsonl="$PWD/benchmarks.jsonl"; lines0=$(wc -l < "$jsonl")
nvidia-smi --query-gpu=name,memory.total,driver_version --format=csv,noheader | tee "$out/device.txt"
start=$(date +%s)
for dtype in float32 bfloat16; do
  for dw in conv shift; do
    for pw in conv dot; do
      name=seg_${dtype}_${dw}_${pw}
      ( MJXROW_CACHE_DIR="$work/cache_$name" timeout 400 $py -m mjxrow.bench segmenter \
          --ckpt zucchini --single --sizes 224 64 --batch 1024 --repeats 5 --dtype $dtype \
          --dw-impl $dw --pw-impl $pw > "$out/$name.log" 2>&1; echo "exit $?" >> "$out/$name.log" ) &
    done
  done
done
wait
echo "segmenter variants done in $(( $(date +%s) - start )) s"
if [ -z "${SEG_ONLY:-}" ]; then
  MJXROW_CACHE_DIR="$work/cache_loop" timeout 300 $py experiments/profile_closed_loop.py \
    --image 224 --batch 1024 --steps 20 --repeats 3 --calls 1 --out "$work/profile_loop" \
    > "$out/profile_loop_224.log" 2>&1; echo "exit $?" >> "$out/profile_loop_224.log"
  MJXROW_CACHE_DIR="$work/cache_render" timeout 200 $py experiments/profile_render.py \
    --res 224 --batch 1024 --out "$work/profile_render" \
    > "$out/profile_render_224.log" 2>&1; echo "exit $?" >> "$out/profile_render_224.log"
fi
echo "all done in $(( $(date +%s) - start )) s"
tail -n +$((lines0 + 1)) "$jsonl" > "$out/benchmarks.jsonl"
$py - "$out/benchmarks.jsonl" <<'PY'
import json, sys
print("\n| config | batch | frames/s | compile [s] |\n|---|---|---|---|")
for line in open(sys.argv[1]):
    r = json.loads(line)
    print(f"| {r['config']} | {r['batch']} | {r['value']:,.0f} | {r.get('compile_s', 0):.1f} |")
PY
for f in "$out"/profile_*.log; do echo "== $(basename "$f")"; tail -30 "$f"; done
grep -l "Error\|exit [1-9]" "$out"/*.log
