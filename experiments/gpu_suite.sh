#!/usr/bin/env bash
# Every GPU measurement of the project in two calls of at most ~10 minutes each, or one.
#   bash experiments/gpu_suite.sh bench   OUT   # stage benchmarks + the default sweep's wall time
#   bash experiments/gpu_suite.sh tables  OUT   # Table 2 (segmentation) and Table 3 (navigation)
#   bash experiments/gpu_suite.sh final   OUT   # renderer, closed loop, sweep, then Table 3 with
#                                               # its three controllers side by side on the GPU
#                                               # (Table 2 runs on any machine: see the README)
# Appends to OUT/benchmarks.jsonl; copy it into the repo's benchmarks.jsonl afterwards.
set -uo pipefail
mode=$1; out=$2; mkdir -p "$out"
b="--out $out/benchmarks.jsonl"
py=python3
log() { echo "== $* ($(date +%T))"; }
nvidia-smi --query-gpu=name,memory.total,driver_version --format=csv,noheader
sweep_time() {
  log sweep; t0=$(date +%s.%N)
  $py -m mjxrow.sweep sweeps.yaml --set batch_size=216 --out "$out/sweep" --no-progress | tail -25
  t1=$(date +%s.%N)
  $py - "$out" "$t0" "$t1" <<'PY'
import json, sys, datetime, subprocess
out, t0, t1 = sys.argv[1], float(sys.argv[2]), float(sys.argv[3])
dev = subprocess.run(["nvidia-smi", "--query-gpu=name", "--format=csv,noheader"], capture_output=True, text=True).stdout.strip().splitlines()[0]
row = {"date": datetime.date.today().isoformat(), "device": dev, "stage": "closed_loop",
       "config": "python -m mjxrow.sweep sweeps.yaml (all cells, compile included)", "batch": 216,
       "value": t1 - t0, "unit": "s wall", "command": "python -m mjxrow.sweep sweeps.yaml --set batch_size=216"}
open(f"{out}/benchmarks.jsonl", "a").write(json.dumps(row) + "\n")
print(f"sweeps.yaml wall time {t1 - t0:.1f} s")
PY
}
if [ "$mode" = bench ]; then
  log fields;   $py -m mjxrow.bench fields --batch 1024 $b
  log physics;  $py -m mjxrow.bench physics --batch 256 1024 4096 $b
  if [ -f mjxrow/bench/render.py ]; then log render; $py -m mjxrow.bench render $b; fi
  log closed_loop; $py -m mjxrow.bench closed_loop --batch 256 1024 --image 64 --steps 150 $b
  sweep_time
  if [ -f mjxrow/bench/dataset.py ]; then log dataset; timeout 200 $py -m mjxrow.bench dataset $b; fi
  (cd "$out" && tar czf sweep.tgz sweep && rm -rf sweep)
elif [ "$mode" = final ]; then
  log render; timeout 200 $py -m mjxrow.bench render --res 64 128 $b
  log closed_loop; timeout 150 $py -m mjxrow.bench closed_loop --batch 256 1024 --image 64 --steps 150 $b
  timeout 150 bash -c "$(declare -f log sweep_time); py=$py; out=$out; sweep_time"
  (cd "$out" && tar czf sweep.tgz sweep && rm -rf sweep)
  log table3; mkdir -p runs/table3
  for c in oracle segzeros_gt segzeros_learned; do
    XLA_PYTHON_CLIENT_MEM_FRACTION=0.3 timeout "${T3_LIMIT:-420}" $py \
      experiments/table3_navigation.py --episodes 100 --out runs/table3 --controllers $c \
      --doc "runs/table3/$c.md" --no-progress >"runs/table3_$c.log" 2>&1 &
  done
  wait
  tail -n 3 runs/table3_*.log
  timeout 60 $py experiments/table3_navigation.py --episodes 100 --out runs/table3 \
    --doc docs/table3.md --no-progress | tail -30
  cp docs/table3.md "$out/table3.md"
  tar czf "$out/table3_runs.tgz" runs/table3 runs/table3_*.log
else
  log table2; $py experiments/table2_segmentation.py --n 512 --out "$out/table2.md"
  log table3; $py experiments/table3_navigation.py --episodes 100 --out runs/table3 --doc "$out/table3.md" --no-progress
  tar czf "$out/table3_runs.tgz" runs/table3
fi
log done
