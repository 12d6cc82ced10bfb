#!/usr/bin/env bash
# The shipped policy in one GPU command: train (BC / DAgger from the oracle, randomised fields),
# evaluate it beside SegZeros (learned segmenter) and the oracle at zucchini and vineyard default
# geometry (100 episodes each), ship the checkpoint (float16) into mjxrow/checkpoints/policy/
# and copy the artefacts into OUT.
#
#   bash experiments/train_policy_gpu.sh OUT [train_policy.py arguments ...]
#   bash experiments/train_policy_gpu.sh OUT --smoke     # the same path on a CPU, tiny
#   bash experiments/train_policy_gpu.sh --surfaces OUT  # the policy's sweep surfaces
#
# OUT receives 8 files: train.log (the device, then the output), policy.tgz (policy/, the
# checkpoint, and shipped_policy/, its float16 copy), train_log.jsonl, learning_curve.png,
# eval.md, eval.json, summary.json, benchmarks.jsonl.
# The artefacts are copied whatever the exit status (which is the script's). The training
# state and the compilation cache stay in a scratch folder (WORK, default
# /tmp/policy_run; a second command with the same WORK resumes).
set -euo pipefail
if [[ "${1:-}" == "--surfaces" ]]; then
  OUT=${2:?usage: $0 --surfaces OUT [sweep arguments ...]}
  shift 2
  WORK=${WORK:-/tmp/policy_surfaces}
  mkdir -p "$OUT" "$WORK"
  for y in sweeps/policy.yaml sweeps/policy_slope_roughness.yaml; do
    name=$(basename "$y" .yaml)
    python -m mjxrow.sweep "$y" --out "$WORK/$name" --no-progress "$@" 2>&1 | tee "$OUT/$name.log"
  done
  tar -czf "$OUT/surfaces.tgz" -C "$WORK" policy policy_slope_roughness
  exit 0
fi
OUT=${1:?usage: $0 OUT [train_policy.py arguments ...]}
shift
WORK=${WORK:-/tmp/policy_run}
mkdir -p "$OUT"
(nvidia-smi --query-gpu=name,driver_version --format=csv,noheader || true) > "$OUT/train.log"
set +e
python experiments/train_policy.py --out "$WORK" --budget-minutes 5 --deadline-minutes 9 \
  --eval-reserve-minutes 1.5 --bc-fraction 1 --ship "$@" 2>&1 | tee -a "$OUT/train.log"
status=${PIPESTATUS[0]}
set -e
for f in train_log.jsonl learning_curve.png eval.md eval.json summary.json benchmarks.jsonl; do
  if [[ -e "$WORK/$f" ]]; then cp "$WORK/$f" "$OUT/"; fi
done
# the checkpoints as one file: a device machine returns few files and no deep folders
parts=()
if [[ -d "$WORK/policy" ]]; then parts+=(-C "$WORK" policy); fi
if [[ -d mjxrow/checkpoints/policy ]]; then
  rm -rf "$WORK/shipped_policy" && cp -r mjxrow/checkpoints/policy "$WORK/shipped_policy"
  parts+=(-C "$WORK" shipped_policy)
fi
if (( ${#parts[@]} )); then tar -czf "$OUT/policy.tgz" "${parts[@]}"; fi
exit "$status"
