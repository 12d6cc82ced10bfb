#!/usr/bin/env bash
# The whole Table 3 in one GPU command, as parallel processes on one GPU (their compilations
# overlap on the host's cores), from an empty compilation cache: the five presets with the
# oracle, SegZeros on ground-truth masks, SegZeros on the learned segmenter and the shipped
# policy (20 blocks of 100 episodes), then one pass that reuses every finished block and
# writes the page. A process per preset runs its controllers in one program (the policy's
# blocks each get their own process); SEPARATE=1: a process and a program per block. Then, as time allows, steps of experiments/gpu_time_to_result.sh named
# in TTR_STEPS. Run from the project root (mujoco importable, e.g. PYTHONPATH=/tmp/site:$PWD):
#
#   OUT=DIR bash experiments/gpu_table3.sh          # default OUT=/tmp/table3_out
#   SMOKE=1 OUT=DIR bash experiments/gpu_table3.sh  # --smoke blocks: checks the script
#   CONTROLLERS="oracle segzeros_gt segzeros_learned" OUT=DIR bash experiments/gpu_table3.sh
#                                                    # the paper's 15 blocks only
#   SEPARATE=1 OUT=DIR bash experiments/gpu_table3.sh  # one program per block
#
# The per-preset processes start STAGGER seconds apart (default 20): all compiling at once
# and then all running at once leaves the GPU idle during the compiles and the host's cores
# idle during the runs; staggered, the first presets' runs overlap the last ones' compiles.
#
# OUT receives table3.md (the page), table3.tgz (every block's results, summaries, logs) and
# ttr.tgz (the time-to-result steps' figures and logs).
set -uo pipefail
out=${OUT:-/tmp/table3_out}; mkdir -p "$out"
py=${PY:-python3}
work=${WORK:-/tmp/table3_work}
rm -rf "$work"; mkdir -p "$work/logs"
read -ra controllers <<< "${CONTROLLERS:-oracle segzeros_gt segzeros_learned policy}"
read -ra presets <<< "${PRESETS:-zucchini lettuce chard pear vineyard}"
flags=(--no-progress --cache-dir "$work/cache" --out "$work/t3")
[ "${SMOKE:-0}" = 1 ] && flags+=(--smoke)
export XLA_PYTHON_CLIENT_PREALLOCATE=false  # the processes share the GPU's memory
export MJXROW_RENDER_KERNEL=${MJXROW_RENDER_KERNEL:-fused}  # XLA renderer: compiles sooner

t0=$(date +%s.%N); procs=0
if [ "${SEPARATE:-0}" = 1 ]; then  # one process and one program per block
  for c in "${controllers[@]}"; do
    for p in "${presets[@]}"; do
      timeout "${BLOCK_LIMIT:-420}" $py experiments/table3_navigation.py "${flags[@]}" \
        --separate --presets "$p" --controllers "$c" --doc "$work/logs/$c-$p.md" \
        >"$work/logs/$c-$p.log" 2>&1 &
      procs=$((procs + 1))
    done
  done
else  # one process per preset, its controllers in one program; the policy's blocks apart
  shared=(); apart=()
  for c in "${controllers[@]}"; do
    if [ "$c" = policy ]; then apart+=("$c"); else shared+=("$c"); fi
  done
  for i in "${!presets[@]}"; do
    p=${presets[$i]}
    [ "$i" -gt 0 ] && sleep "${STAGGER:-20}"  # each run overlaps the next ones' compiles
    if [ ${#shared[@]} -gt 0 ]; then
      timeout "${BLOCK_LIMIT:-420}" $py experiments/table3_navigation.py "${flags[@]}" \
        --presets "$p" --controllers "${shared[@]}" --doc "$work/logs/shared-$p.md" \
        >"$work/logs/shared-$p.log" 2>&1 &
      procs=$((procs + 1))
    fi
    for c in "${apart[@]}"; do
      timeout "${BLOCK_LIMIT:-420}" $py experiments/table3_navigation.py "${flags[@]}" \
        --presets "$p" --controllers "$c" --doc "$work/logs/$c-$p.md" \
        >"$work/logs/$c-$p.log" 2>&1 &
      procs=$((procs + 1))
    done
  done
fi
wait
t1=$(date +%s.%N)
$py experiments/table3_navigation.py "${flags[@]}" --controllers "${controllers[@]}" \
  --presets "${presets[@]}" --doc "$out/table3.md" >"$work/logs/assemble.log" 2>&1
t2=$(date +%s.%N)
failed=$(grep -L "^written:" "$work"/logs/*-*.log | xargs -r -n1 basename | tr '\n' ' ')
$py -c "import sys; a, b, c = map(float, sys.argv[1:4]); print(f'blocks: {sys.argv[4]} in \
{sys.argv[6]} parallel processes, {b - a:.1f} s wall (compilation included); \
assembling the page {c - b:.1f} s; blocks without a result: {sys.argv[5] or \"none\"}')" "$t0" "$t1" "$t2" \
  "$(( ${#controllers[@]} * ${#presets[@]} ))" "$failed" "$procs" | tee "$work/logs/summary.txt"
grep -h "^| .* | ours\|^| .* | paper" "$out/table3.md" | head -40
runs=t3; [ "${SMOKE:-0}" = 1 ] && runs=t3_smoke  # --smoke runs into OUT_smoke
tar -czf "$out/table3.tgz" -C "$work" --exclude=cache --exclude=cells "$runs" logs

if [ -n "${TTR_STEPS:-}" ]; then
  mkdir -p "$work/ttr"
  ONLY="$TTR_STEPS" OUT="$work/ttr" BUDGET="${TTR_BUDGET:-200}" \
    bash experiments/gpu_time_to_result.sh 2>&1 | tail -n 12
  tar -czf "$out/ttr.tgz" -C "$work" ttr
fi
