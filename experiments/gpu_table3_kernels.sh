#!/usr/bin/env bash
# Table 3 blocks of one preset with the Pallas kernels and with the XLA renderer
# (MJXROW_RENDER_KERNEL=pallas / fused), every block its own process from an empty compilation
# cache, all side by side on one GPU: how long a block takes to its result either way, and
# whether the two give the same table. Run from the project root (mujoco importable):
#
#   OUT=DIR bash experiments/gpu_table3_kernels.sh        # zucchini, the four controllers
#   SMOKE=1 PRESET=zucchini CONTROLLERS="oracle segzeros_gt" OUT=DIR bash ...  # CPU check
#
# OUT receives one line per block in blocks.txt (kernel, controller, seconds wall, exit status),
# the two pages (table3_pallas.md, table3_fused.md) and the logs (logs.tgz).
set -uo pipefail
out=${OUT:-/tmp/t3k_out}; mkdir -p "$out"
py=${PY:-python3}
work=${WORK:-/tmp/t3k_work}; rm -rf "$work"; mkdir -p "$work/logs"
preset=${PRESET:-zucchini}
read -r -a controllers <<< "${CONTROLLERS:-oracle segzeros_gt segzeros_learned policy}"
flags=(--no-progress --presets "$preset")
[ "${SMOKE:-0}" = 1 ] && flags+=(--smoke)
export XLA_PYTHON_CLIENT_PREALLOCATE=false
: > "$out/blocks.txt"
for k in pallas fused; do
  for c in "${controllers[@]}"; do
    ( t0=$(date +%s.%N)
      MJXROW_RENDER_KERNEL=$k timeout "${BLOCK_LIMIT:-500}" $py experiments/table3_navigation.py \
        "${flags[@]}" --controllers "$c" --out "$work/t3_$k" --cache-dir "$work/cache_${k}_$c" \
        --doc "$work/logs/$k-$c.md" > "$work/logs/$k-$c.log" 2>&1
      rc=$?; t1=$(date +%s.%N)
      printf '%s %s %.1f %s\n' "$k" "$c" "$(awk "BEGIN{print $t1 - $t0}")" "$rc" >> "$out/blocks.txt" ) &
  done
done
wait
for k in pallas fused; do
  $py experiments/table3_navigation.py "${flags[@]}" --controllers "${controllers[@]}" \
    --out "$work/t3_$k" --cache-dir "$work/cache_assemble_$k" --doc "$out/table3_$k.md" \
    > "$work/logs/assemble-$k.log" 2>&1
done
tar czf "$out/logs.tgz" -C "$work" logs
echo "| kernel | controller | wall [s] | exit |"; echo "|---|---|---|---|"
sort "$out/blocks.txt" | while read -r k c s rc; do echo "| $k | $c | $s | $rc |"; done
for k in pallas fused; do echo "== $k"; grep "^| $preset" "$out/table3_$k.md" | head -8; done
