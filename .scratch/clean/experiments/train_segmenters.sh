#!/usr/bin/env bash
# Per-crop segmenters: fine-tune the all-crop model on each crop's own on-the-fly renders, all
# five runs side by side on one GPU, and ship the best of each as mjxrow/checkpoints/<crop>/.
#   bash experiments/train_segmenters.sh OUT [STEPS]
# Each run logs to OUT/<crop>.log and keeps its state in runs/seg_<crop>_ft (re-running resumes).
set -uo pipefail
out=$1; steps=${2:-4000}; mkdir -p "$out"
crops=$(python3 -c "from mjxrow import crops; print(*crops.names())")
nvidia-smi --query-gpu=name,memory.total --format=csv,noheader
export XLA_PYTHON_CLIENT_MEM_FRACTION=0.18  # five processes share the GPU
for c in $crops; do
  python3 -m mjxrow.seg.train --crop "$c" --on-the-fly --init all --size 128 64 \
    --steps "$steps" --batch 40 --lr 4e-4 --warmup 200 --eval-every 500 --log-every 100 \
    --val-n 200 --out "runs/seg_${c}_ft" --export-to "mjxrow/checkpoints/$c" \
    --no-progress >"$out/$c.log" 2>&1 &
done
wait
for c in $crops; do echo "== $c"; grep -v -i warp "$out/$c.log" | tail -2; done
