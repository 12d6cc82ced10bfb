#!/usr/bin/env bash
# MuJoCo's batch renderer beside ours on one GPU: `python -m mjxrow.bench render_mjwarp`.
# Needs warp-lang importable (PYTHONPATH=/tmp/site:$PWD with warp installed there). Raw rows in
# $OUT/benchmarks.jsonl, the log in $OUT/mjwarp.log.
#
#   OUT=DIR bash experiments/gpu_mjwarp.sh [bench args, default --batch 1024]
set -uo pipefail
out=${OUT:-/tmp/mjwarp_out}; mkdir -p "$out"
py=${PY:-python3}
jsonl="$PWD/benchmarks.jsonl"; lines0=$(wc -l < "$jsonl")
nvidia-smi --query-gpu=name,memory.total,driver_version --format=csv,noheader | tee "$out/device.txt"
args=("$@"); [ ${#args[@]} -eq 0 ] && args=(--batch 1024)
timeout 540 $py -m mjxrow.bench render_mjwarp "${args[@]}" 2>&1 | tee "$out/mjwarp.log" | \
  grep -v "^Module \|^Warp " | tail -40
tail -n +$((lines0 + 1)) "$jsonl" > "$out/benchmarks.jsonl"
