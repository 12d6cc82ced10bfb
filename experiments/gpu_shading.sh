#!/usr/bin/env bash
# The renderer's shading from noise slots on one GPU (one call, ~9 minutes). Run from the
# project root with mujoco importable (PYTHONPATH=/tmp/site:$PWD):
#
#   OUT=DIR bash experiments/gpu_shading.sh
#
#  render_variants     experiments/render_variants.py at 64, 128 and 224 px (B = 1024),
#                      settle none (the GPU default) and barrier: compiled in threads, then
#                      timed in interleaved rounds in one process
#  profile_render_224  experiments/profile_render.py, 224 px, B = 1024, command buffers off
#                      (so that every kernel shows its stage); _barrier: settle=barrier
#  loop_224            python -m mjxrow.bench closed_loop --image 224 --batch 1024 (defaults)
# ONLY="name ..." runs a subset. Raw rows: $OUT/rows.jsonl; logs: $OUT/<name>.log.
set -uo pipefail
out=${OUT:-/tmp/shading_out}; mkdir -p "$out"
py=${PY:-python3}
only=${ONLY:-render_variants profile_render_224 profile_render_224_barrier loop_224}
work=${WORK:-/tmp/shading_work}; rm -rf "$work"; mkdir -p "$work"
export XLA_PYTHON_CLIENT_PREALLOCATE=false MJXROW_CACHE_DIR="$work/cache"
nvidia-smi --query-gpu=name,memory.total,driver_version --format=csv,noheader | tee "$out/device.txt"
start=$(date +%s)
want() { [[ " $only " == *" $1 "* ]]; }
step() {  # step NAME LIMIT CMD...: one command, its log, its exit status
  local name=$1 limit=$2; shift 2
  want "$name" || return 0
  timeout "$limit" "$@" > "$out/$name.log" 2>&1; echo "exit $?" >> "$out/$name.log"
  echo "$name: $(tail -1 "$out/$name.log") at $(( $(date +%s) - start )) s"
}
step render_variants 300 $py experiments/render_variants.py --res 64 128 224 --batch 1024 \
  --variants "" settle=barrier --rounds 5 --out "$out/rows.jsonl"
step profile_render_224 120 env XLA_FLAGS=--xla_gpu_enable_command_buffer= \
  $py experiments/profile_render.py --res 224 --batch 1024 --calls 2 --out "$work/pr"
step profile_render_224_barrier 120 env XLA_FLAGS=--xla_gpu_enable_command_buffer= \
  $py experiments/profile_render.py --res 224 --batch 1024 --calls 2 --out "$work/prb" \
  --set settle=barrier
step loop_224 240 $py -m mjxrow.bench closed_loop --image 224 --batch 1024 --steps 150 \
  --repeats 3 --out "$out/rows.jsonl" ${LOOP_SETS:-}
grep -h "^|" "$out/render_variants.log" 2>/dev/null
for f in "$out"/profile_*.log "$out"/loop_*.log; do
  [ -f "$f" ] && { echo "== $(basename "$f")"; grep -v "Delay kernel" "$f" | tail -22; }
done
