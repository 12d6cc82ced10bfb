#!/usr/bin/env bash
# The whole Table 3 in one GPU command, its blocks as parallel processes on one GPU (their
# compilations overlap on the host's cores), from an empty compilation cache: the five presets
# with the oracle, SegZeros on ground-truth masks, SegZeros on the learned segmenter and the
# shipped policy (20 blocks of 100 episodes), then one pass that reuses every finished block
# and writes the page. Then, as time allows, steps of experiments/gpu_time_to_result.sh named
# in TTR_STEPS. Run from the project root (mujoco importable, e.g. PYTHONPATH=/tmp/site:$PWD):
#
#   OUT=DIR bash experiments/gpu_table3.sh          # default OUT=/tmp/table3_out
#   SMOKE=1 OUT=DIR bash experiments/gpu_table3.sh  # --smoke blocks: checks the script
#   CONTROLLERS="oracle segzeros_gt segzeros_learned" OUT=DIR bash experiments/gpu_table3.sh
#                                                    # the paper's 15 blocks only
#
# OUT receives table3.md (the page), table3.tgz (every block's results, summaries, logs) and
# ttr.tgz (the time-to-result steps' figures and logs).
set -uo pipefail
out=${OUT:-/tmp/table3_out}; mkdir -p "$out"
py=${PY:-python3}
work=${WORK:-/tmp/table3_work}
rm -rf "$work"; mkdir -p "$work/logs"
read -ra controllers <<< "${CONTROLLERS:-oracle segzeros_gt segzeros_learned policy}"
presets=(zucchini lettuce chard pear vineyard)
flags=(--no-progress --cache-dir "$work/cache" --out "$work/t3")
[ "${SMOKE:-0}" = 1 ] && flags+=(--smoke)
export XLA_PYTHON_CLIENT_PREALLOCATE=false  # 20 processes share the GPU's memory

t0=$(date +%s.%N)
for c in "${controllers[@]}"; do
  for p in "${presets[@]}"; do
    timeout "${BLOCK_LIMIT:-420}" $py experiments/table3_navigation.py "${flags[@]}" \
      --presets "$p" --controllers "$c" --doc "$work/logs/$c-$p.md" \
      >"$work/logs/$c-$p.log" 2>&1 &
  done
done
wait
t1=$(date +%s.%N)
$py experiments/table3_navigation.py "${flags[@]}" --controllers "${controllers[@]}" \
  --doc "$out/table3.md" >"$work/logs/assemble.log" 2>&1
t2=$(date +%s.%N)
failed=$(grep -L "^written:" "$work"/logs/*-*.log | xargs -r -n1 basename | tr '\n' ' ')
$py -c "import sys; a, b, c = map(float, sys.argv[1:4]); print(f'blocks: {sys.argv[4]} in \
parallel, {b - a:.1f} s wall (compilation included); assembling the page {c - b:.1f} s; \
blocks without a result: {sys.argv[5] or \"none\"}')" "$t0" "$t1" "$t2" \
  "$(( ${#controllers[@]} * ${#presets[@]} ))" "$failed" | tee "$work/logs/summary.txt"
grep -h "^| .* | ours\|^| .* | paper" "$out/table3.md" | head -40
runs=t3; [ "${SMOKE:-0}" = 1 ] && runs=t3_smoke  # --smoke runs into OUT_smoke
tar -czf "$out/table3.tgz" -C "$work" --exclude=cache --exclude=cells "$runs" logs

if [ -n "${TTR_STEPS:-}" ]; then
  mkdir -p "$work/ttr"
  ONLY="$TTR_STEPS" OUT="$work/ttr" BUDGET="${TTR_BUDGET:-200}" \
    bash experiments/gpu_time_to_result.sh 2>&1 | tail -n 12
  tar -czf "$out/ttr.tgz" -C "$work" ttr
fi
