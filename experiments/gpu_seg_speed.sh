#!/usr/bin/env bash
# The segmenter's implementations on one GPU, and where the 224-px closed loop and renderer
# spend their time (one call, ~8 minutes). Run from the project root with mujoco importable
# (PYTHONPATH=/tmp/site:$PWD):
#
#   OUT=DIR bash experiments/gpu_seg_speed.sh
#
#  seg224 / seg64      experiments/seg_variants.py at 224 px (B = 1024) and 64 px (B = 4096):
#                      every variant compiled, then timed in interleaved rounds in one process
#                      (no other process compiles or autotunes on the GPU meanwhile)
#  profile_loop_224    experiments/profile_closed_loop.py, 224 px, B = 1024 (defaults)
#  profile_render_224  experiments/profile_render.py, 224 px, B = 1024, command buffers off
#                      (so that every kernel shows its stage)
# SEG_ONLY=1 skips the two profiles. Raw rows: $OUT/rows.jsonl; logs: $OUT/<name>.log.
set -uo pipefail
out=${OUT:-/tmp/seg_speed_out}; mkdir -p "$out"
py=${PY:-python3}
work=${WORK:-/tmp/seg_speed_work}; rm -rf "$work"; mkdir -p "$work"
export XLA_PYTHON_CLIENT_PREALLOCATE=false MJXROW_CACHE_DIR="$work/cache"
nvidia-smi --query-gpu=name,memory.total,driver_version --format=csv,noheader | tee "$out/device.txt"
start=$(date +%s)
step() {  # step NAME LIMIT CMD...: one command, its log, its exit status
  local name=$1 limit=$2; shift 2
  timeout "$limit" "$@" > "$out/$name.log" 2>&1; echo "exit $?" >> "$out/$name.log"
  echo "$name: $(tail -1 "$out/$name.log") at $(( $(date +%s) - start )) s"
}
step seg224 240 $py experiments/seg_variants.py --size 224 --batch 1024 --rounds 5 \
  --out "$out/rows.jsonl"
step seg64 150 $py experiments/seg_variants.py --size 64 --batch 4096 --rounds 5 \
  --out "$out/rows.jsonl" --variants float32:conv:conv float32:conv:dot float32:mixed:dot \
  float32:phases:dot bfloat16:phases:dot
if [ -z "${SEG_ONLY:-}" ]; then
  step profile_loop_224 300 $py experiments/profile_closed_loop.py --image 224 --batch 1024 \
    --steps 20 --repeats 3 --calls 1 --out "$work/profile_loop"
  step profile_render_224 120 env XLA_FLAGS=--xla_gpu_enable_command_buffer= \
    $py experiments/profile_render.py --res 224 --batch 1024 --out "$work/profile_render"
fi
for f in seg224 seg64; do grep "^|" "$out/$f.log"; echo; done
for f in "$out"/profile_*.log; do echo "== $(basename "$f")"; grep -v "Delay kernel" "$f" | tail -25; done
