#!/usr/bin/env bash
# Cold compile time and run speed of the default sweep's closed-loop program (zucchini, 64 px,
# the XLA renderer, B = 216) under XLA flag sets, one after another so that each compiles on
# an otherwise idle host (~6 minutes on one GPU). Run from the project root with mujoco
# importable (PYTHONPATH=/tmp/site:$PWD):
#
#   OUT=DIR bash experiments/gpu_compile_flags.sh [VARIANT ...]
#
#  default   XLA's defaults
#  cmd       the control loop captured whole as CUDA graphs, not only its fusions
#            (--xla_gpu_enable_command_buffer=+WHILE)
#  noat      no autotuning (--xla_gpu_autotune_level=0): its share of the compile time
# (XLA compiles the LLVM modules of a program on several threads by default.)
# Raw rows: $OUT/benchmarks.jsonl; a short table last.
set -uo pipefail
out=${OUT:-/tmp/flags_out}; mkdir -p "$out"
py=${PY:-python3}
variants=("$@"); [ ${#variants[@]} -eq 0 ] && variants=(default cmd noat)
declare -A flags=(
  [default]=""
  [cmd]="--xla_gpu_enable_command_buffer=+WHILE"
  [noat]="--xla_gpu_autotune_level=0"
)
for v in "${variants[@]}"; do
  if [ -z "${flags[$v]+set}" ]; then
    echo "gpu_compile_flags.sh: unknown variant '$v' (one of: ${!flags[*]})" >&2; exit 2
  fi
done
export XLA_PYTHON_CLIENT_PREALLOCATE=false
jsonl="$PWD/benchmarks.jsonl"; lines0=$(wc -l < "$jsonl")
nvidia-smi --query-gpu=name,memory.total,driver_version --format=csv,noheader | tee "$out/device.txt"
for v in "${variants[@]}"; do
  extra=(JAX_LOG_COMPILES=1 TF_CPP_MIN_LOG_LEVEL=0 TF_CPP_VMODULE=gpu_compiler=1)
  t0=$(date +%s)
  env XLA_FLAGS="${flags[$v]}" "${extra[@]}" timeout 300 $py -m mjxrow.bench closed_loop \
    --image 64 --batch 216 --steps 150 --repeats 3 --no-cache --set render.kernel=fused \
    > "$out/$v.log" 2>&1
  echo "$v: exit $? in $(( $(date +%s) - t0 )) s" | tee -a "$out/summary.txt"
  grep -E "^B=" "$out/$v.log" | tee -a "$out/summary.txt"
done
for v in "${variants[@]}"; do  # the compiler's stage times of the closed-loop program
  grep -E "(RunHloPasses|RunBackend) for jit_batch |tracing batch for|conversion jit\(batch\)|compilation of jit\(batch\)" \
    "$out/$v.log" | sed -E "s/^.*(GpuCompiler::|Finished )/$v: /; s/ \(cumul.*//" | tee -a "$out/summary.txt"
done
tail -n +$((lines0 + 1)) "$jsonl" > "$out/benchmarks.jsonl"
cat "$out/summary.txt"
