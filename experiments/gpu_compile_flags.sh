#!/usr/bin/env bash
# Cold compile time and run speed of the default sweep's closed-loop program (zucchini, 64 px,
# the XLA renderer, B = 216) under XLA flag sets, one after another so that each compiles on
# an otherwise idle host (~6 minutes on one GPU). Run from the project root with mujoco
# importable (PYTHONPATH=/tmp/site:$PWD):
#
#   OUT=DIR bash experiments/gpu_compile_flags.sh [VARIANT ...]
#
#  default   XLA's defaults (the compiler's own stage timers in $OUT/default.log)
#  par       LLVM modules compiled in parallel over the host's cores
#            (--xla_gpu_enable_llvm_module_compilation_parallelism, 16 threads)
#  par_cmd   par, and the control loop's body captured as CUDA graphs
#            (--xla_gpu_enable_command_buffer=+WHILE,+CONDITIONAL)
#  par_noat  par, and no autotuning (--xla_gpu_autotune_level=0)
# Raw rows: $OUT/benchmarks.jsonl; a short table last.
set -uo pipefail
out=${OUT:-/tmp/flags_out}; mkdir -p "$out"
py=${PY:-python3}
variants=("$@"); [ ${#variants[@]} -eq 0 ] && variants=(default par par_cmd)
par="--xla_gpu_enable_llvm_module_compilation_parallelism=true --xla_gpu_force_compilation_parallelism=16"
declare -A flags=(
  [default]=""
  [par]="$par"
  [par_cmd]="$par --xla_gpu_enable_command_buffer=+WHILE,+CONDITIONAL"
  [par_noat]="$par --xla_gpu_autotune_level=0"
)
export XLA_PYTHON_CLIENT_PREALLOCATE=false
jsonl="$PWD/benchmarks.jsonl"; lines0=$(wc -l < "$jsonl")
nvidia-smi --query-gpu=name,memory.total,driver_version --format=csv,noheader | tee "$out/device.txt"
for v in "${variants[@]}"; do
  extra=()
  [ "$v" = default ] && extra=(TF_CPP_MIN_LOG_LEVEL=0 TF_CPP_VMODULE=gpu_compiler=1,nvptx_compiler=1)
  t0=$(date +%s)
  env XLA_FLAGS="${flags[$v]}" "${extra[@]}" timeout 300 $py -m mjxrow.bench closed_loop \
    --image 64 --batch 216 --steps 150 --repeats 3 --no-cache --set render.kernel=fused \
    > "$out/$v.log" 2>&1
  echo "$v: exit $? in $(( $(date +%s) - t0 )) s" | tee -a "$out/summary.txt"
  grep -E "^B=" "$out/$v.log" | tee -a "$out/summary.txt"
done
grep -E "took|Compil|compil" "$out/default.log" | grep -v "^WARNING" | head -60 > "$out/default_timers.txt"
tail -n +$((lines0 + 1)) "$jsonl" > "$out/benchmarks.jsonl"
cat "$out/summary.txt"
