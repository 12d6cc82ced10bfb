#!/usr/bin/env bash
# Every GPU measurement of the project in two calls of at most ~10 minutes each.
#   bash experiments/gpu_suite.sh bench   OUT   # stage benchmarks + the default sweep's wall time
#   bash experiments/gpu_suite.sh tables  OUT   # Table 2 (segmentation) and Table 3 (navigation)
# Appends to OUT/benchmarks.jsonl; copy it into the repo's benchmarks.jsonl afterwards.
set -uo pipefail
mode=$1; out=$2; mkdir -p "$out"
b="--out $out/benchmarks.jsonl"
py=python3
log() { echo "== $* ($(date +%T))"; }
nvidia-smi --query-gpu=name,memory.total,driver_version --format=csv,noheader
if [ "$mode" = bench ]; then
  log fields;   $py -m mjxrow.bench fields --batch 1024 $b
  log physics;  $py -m mjxrow.bench physics --batch 256 1024 4096 $b
  if [ -f mjxrow/bench/render.py ]; then log render; $py -m mjxrow.bench render $b; fi
  log closed_loop; $py -m mjxrow.bench closed_loop --batch 256 1024 --image 64 --steps 150 $b
  log sweep;    t0=$(date +%s.%N)
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
  if [ -f mjxrow/bench/dataset.py ]; then log dataset; timeout 200 $py -m mjxrow.bench dataset $b; fi
  (cd "$out" && tar czf sweep.tgz sweep && rm -rf sweep)
else
  log table2; $py experiments/table2_segmentation.py --n 512 --out "$out/table2.md"
  log table3; $py experiments/table3_navigation.py --episodes 100 --out runs/table3 --doc "$out/table3.md" --no-progress
  tar czf "$out/table3_runs.tgz" runs/table3
fi
log done
