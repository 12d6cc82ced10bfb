python3 -m pip install -q --no-index --no-deps --no-compile --no-cache-dir --upgrade --target /tmp/site .whl/*.whl && export PYTHONPATH=/tmp/site:$PWD PYTHONUNBUFFERED=1
# Time to result on one GPU, in at most ~9 minutes of wall time (run from the project root):
#   bash experiments/gpu_time_to_result.sh            # raw logs and benchmarks.jsonl in $OUT
# 1. `python -m mjxrow.sweep sweeps.yaml --set batch_size=216` with an empty compilation cache
#    (cold), then again with the same cache into a fresh --out (warm): wall time and the sweep's
#    own compile / run / write split;
# 2. `python -m mjxrow.bench closed_loop` at 64 x 64 (B = 1024) and 224 x 224 (B = 512):
#    control steps/s and episodes/min of 600 steps, compile apart;
# 3. while time is left: one Table 3 block (SegZeros on the learned segmenter, zucchini, 100
#    episodes) cold and warm, then the 64 x 64 closed loop with the segmenter in bfloat16.
#    The whole Table 3 (15 blocks, each its own program) does not fit in this call.
# Ends with a short table of the figures.
set -uo pipefail
out=${OUT:-/tmp/out}; mkdir -p "$out"
cache=/tmp/mjxrow_cache; rm -rf "$cache" /tmp/ttr; mkdir -p /tmp/ttr
py=python3
start=$(date +%s)
left() { echo $((530 - ($(date +%s) - start))); }  # seconds left of the ~9 minutes
log() { echo "== $* ($(date +%T), $(left) s left)"; }
nvidia-smi --query-gpu=name,memory.total,driver_version --format=csv,noheader | tee "$out/gpu.txt"
$py -c "import jax, mujoco; print('jax', jax.__version__, 'mujoco', mujoco.__version__, jax.devices())" \
  | tee -a "$out/gpu.txt"

wall() {  # wall NAME TIMEOUT CMD...: run CMD, log to $out/NAME.log, record NAME's wall time
  local name=$1 limit=$2; shift 2
  local t0; t0=$(date +%s.%N)
  timeout "$limit" "$@" >"$out/$name.log" 2>&1
  local rc=$?
  echo "$name $rc $(awk "BEGIN {print $(date +%s.%N) - $t0}")" >>"$out/walls.txt"
  tail -n 4 "$out/$name.log"
}

sweep=($py -m mjxrow.sweep sweeps.yaml --set batch_size=216 --no-progress --cache-dir "$cache")
log "sweep, cold cache"; wall sweep_cold 240 "${sweep[@]}" --out /tmp/ttr/sweep_cold
log "sweep, warm cache"; wall sweep_warm 120 "${sweep[@]}" --out /tmp/ttr/sweep_warm
cp /tmp/ttr/sweep_warm/summary.csv "$out/sweep_summary.csv" 2>/dev/null

bench=($py -m mjxrow.bench closed_loop --steps 150 --out "$out/benchmarks.jsonl"
       --cache-dir "$cache")
log "closed loop 64 x 64"; wall closed_loop_64 180 "${bench[@]}" --image 64 --batch 1024
log "closed loop 224 x 224"; wall closed_loop_224 200 "${bench[@]}" --image 224 --batch 512 \
  --repeats 2

if [ "$(left)" -gt 150 ]; then
  t3=($py experiments/table3_navigation.py --episodes 100 --presets zucchini
      --controllers segzeros_learned --no-progress --cache-dir "$cache" --doc /tmp/ttr/t3.md)
  log "Table 3 block, cold"; wall table3_block_cold 150 "${t3[@]}" --out /tmp/ttr/t3_cold
  if [ "$(left)" -gt 40 ]; then
    log "Table 3 block, warm"; wall table3_block_warm 60 "${t3[@]}" --out /tmp/ttr/t3_warm
  fi
else
  echo "Table 3 block skipped: $(left) s left"
fi
if [ "$(left)" -gt 110 ]; then
  log "closed loop 64 x 64, bfloat16 segmenter"
  wall closed_loop_64_bf16 "$(($(left) - 10))" "${bench[@]}" --image 64 --batch 1024 \
    --seg-dtype bfloat16
else
  echo "bfloat16 closed loop skipped: $(left) s left"
fi

log "summary"
$py - "$out" <<'PY'
import json, pathlib, re, sys
out = pathlib.Path(sys.argv[1])
print("| run | rc | wall [s] | sweep's own split |\n|---|---|---|---|")
for line in (out / "walls.txt").read_text().splitlines():
    name, rc, wall = line.split()
    text = (out / f"{name}.log").read_text() if (out / f"{name}.log").exists() else ""
    split = re.findall(r"^time: .*$", text, re.M)
    print(f"| {name} | {rc} | {float(wall):.1f} | {split[-1][6:] if split else ''} |")
rows = [json.loads(l) for l in (out / "benchmarks.jsonl").read_text().splitlines()] \
    if (out / "benchmarks.jsonl").exists() else []
print("\n| closed loop | B | control steps/s | episodes/min | compile [s] | median run [s] |")
print("|---|---|---|---|---|---|")
for r in rows:
    runs = sorted(r["runs_s"])
    print(f"| {r['config']} | {r['batch']} | {r['value']:,.0f} | {r['episodes_per_min']:,.0f} "
          f"| {r['compile_s']:.1f} | {runs[len(runs) // 2]:.2f} |")
PY
du -sh "$cache"
log done
