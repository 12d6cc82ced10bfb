#!/usr/bin/env bash
# shellcheck disable=SC2317  # the sets are called by name: "set_$s"
# The project's GPU measurements, as named sets run one after another in one call:
#
#   OUT=DIR bash experiments/gpu.sh SET [SET ...]      # default OUT=/tmp/gpu_out
#   bash experiments/gpu.sh --list                     # the sets, one line each
#   SMOKE=1 OUT=DIR bash experiments/gpu.sh SET        # tiny sizes: checks a set on a CPU
#                                                      # (time_to_result, surfaces, scaling,
#                                                      # table3, table3_kernels)
#
# Set-up, once per call: the project root as working folder; the wheels in .whl/ (the packages
# the GPU machine lacks; /tmp/wp/*.whl too, for a wheel brought in parts) installed into SITE
# (default /tmp/site) where nvidia-smi is found (not on a CPU check) and unless the same files
# are there already, with PYTHONPATH=SITE:ROOT
# (ROOT alone without wheels) and PYTHONUNBUFFERED=1; the device (nvidia-smi, jax, mujoco) in
# OUT/device.txt. A set writes into OUT/SET and works in WORK/SET (default WORK=/tmp/gpu_work),
# which it empties first (train_policy resumes from it instead). Compilation caches: most sets
# compile into empty caches under WORK/SET (cold compile times), compile_flags with --no-cache;
# mjwarp, suite_*, train_policy and policy_surfaces use mjxrow's cache (MJXROW_CACHE_DIR, else
# ~/.cache/mjxrow/jax), which a warm machine keeps between calls. Each set runs in a subshell
# (its exports stay its own); the call exits with the first failing set's status. Raw rows
# land in OUT/SET (benchmarks.jsonl, rows.jsonl, ...): copy those a round keeps into the
# repository's benchmarks.jsonl, then python experiments/benchmarks_table.py --write BENCHMARKS.md.
#
# Variables: PY (interpreter, default python3), SMOKE=1, and per set (default in brackets):
#   time_to_result  BUDGET [530] s for all its steps, each started only while its share is left;
#                   ONLY="STEP ..." runs only those steps; LIMIT_SCALE [1; SMOKE: 5] scales the
#                   step limits; FULL_TABLE3 [420] s left needed for the whole Table 3 (0: force)
#   surfaces        LIMIT [520] s per sweep; XLA_PYTHON_CLIENT_MEM_FRACTION [0.15]
#   scaling         SWEEP_LIMIT [190], BENCH_LIMIT [180] s; BENCH_SET: more closed-loop flags
#   table3          CONTROLLERS [oracle segzeros_gt segzeros_learned policy], PRESETS [all five],
#                   SEPARATE=1 (a process and program per block), STAGGER [20] s,
#                   BLOCK_LIMIT [420] s, MJXROW_RENDER_KERNEL [fused]
#   table3_kernels  PRESET [zucchini], CONTROLLERS [as table3], BLOCK_LIMIT [500] s
#   compile_flags   VARIANTS [default cmd noat]
#   mjwarp          MJWARP_ARGS [--batch 1024]
#   seg_speed       SEG_ONLY=1 skips the two profiles
#   shading         ONLY="STEP ..." runs only those steps; LOOP_SETS: more flags for loop_224
#   loop_224        BATCHES [4096 6144], SETS [--set render.deep_share=0.125], STEPS [60]
#   suite_final     T3_LIMIT [420] s per Table 3 controller
#   seg_variety     TRAIN_LIMIT [390] s, STEPS [2500], SIZES ["128 64"], T2_LIMIT [150] s;
#                   the model lands in WORK/seg_variety/ckpt/all (later sets' CKPT)
#   search_segzeros CKPT [seg_variety's model if present, else shipped], SEARCH_LIMIT [560] s
#   search_oracle   MINUTES [2] of search, SEARCH_LIMIT [200] s
#   variety_surfaces CKPT [as search_segzeros], LIMIT [300] s per sweep
#   render_curved   LIMIT [240] s
#   scale_out       GPUS ["1 2 4"], PER_GPU ["8208"] episodes per GPU and batch (multiples of
#                   36: whole seeds of sweeps.yaml's 36 cells), LIMIT [280] s per sweep
#   train_policy    TRAIN_ARGS: more train_policy.py arguments (e.g. --smoke on a CPU)
#   train_side      TRAIN_ARGS_0 .. TRAIN_ARGS_3: each set one's arguments (command I on GPU I,
#                   the cores split evenly); XLA_FLAGS_I: its XLA flags
#   policy_surfaces SWEEP_ARGS: more sweep arguments
#   compile_profile PRESET [pear], BATCH [3072], PARTS [rollout]: env_parts.py's parts
#   sun             SUN_CONTROLLERS [segzeros policy], SUN_CHECKPOINT [shipped] (the policy's),
#                   SUN_LABEL [none]: added to the outputs' names
set -uo pipefail
OUT=${OUT:-/tmp/gpu_out}; WORK=${WORK:-/tmp/gpu_work}
[[ $OUT == /* ]] || OUT="$PWD/$OUT"; [[ $WORK == /* ]] || WORK="$PWD/$WORK"
root=$(cd "$(dirname "${BASH_SOURCE[0]}")/.." && pwd)
cd "$root" || exit 2

sets=(time_to_result determinism surfaces scaling table3 table3_kernels speed_round loop_224
      compile_flags mjwarp seg_speed shading suite_bench suite_tables suite_final train_policy
      policy_surfaces seg_variety search_segzeros search_oracle variety_surfaces render_curved
      scale_out train_side compile_profile sun)
declare -A about=(
  [time_to_result]="sweeps.yaml cold / warm, closed loop 64 / 224 px, Table 3 block and whole"
  [determinism]="sweeps.yaml cold, warm, warm; the same with XLA's deterministic ops; diffs"
  [surfaces]="both sweep surfaces with SegZeros, the shipped policy and the oracle"
  [scaling]="sweeps.yaml (114 seeds) and the closed loop on one GPU and on two"
  [scale_out]="sweeps.yaml at PER_GPU episodes per GPU on 1, 2, 4 GPUs: episodes/s ratios"
  [table3]="the whole Table 3 from an empty cache, a process per preset, then the page"
  [table3_kernels]="Table 3 blocks of one preset, Pallas kernels against the XLA renderer"
  [speed_round]="renderer 64 / 128 px and closed loop 64 / 224 px, processes side by side"
  [loop_224]="closed loop 224 px (bfloat16 segmenter) at B = BATCHES, defaults beside SETS"
  [seg_variety]="the all-crop segmenter fine-tuned on the field variety, then Table 2"
  [search_segzeros]="the failure search over the field variety against SegZeros (learned)"
  [search_oracle]="the same box against the oracle: CMA-ES only, MINUTES of it"
  [variety_surfaces]="the curvature x gaps and weeds sweeps, SegZeros and the oracle"
  [render_curved]="render accuracy and frames/s on straight, arc and sine rows with weeds"
  [compile_flags]="the sweep's closed-loop program compiled and run under XLA flag sets"
  [sun]="sweeps/sun.yaml (pear, the sun's azimuth) for SegZeros and a policy checkpoint"
  [mjwarp]="MuJoCo's batch renderer (MJX, Warp) beside ours (needs warp-lang)"
  [seg_speed]="segmenter implementations; where a 224-px step and frame spend their time"
  [shading]="renderer settle variants at 64 / 128 / 224 px, profiles, closed loop 224 px"
  [suite_bench]="stage benchmarks (fields, physics, render, closed loop, dataset), sweep"
  [suite_tables]="Table 2 (segmentation) and Table 3 (navigation)"
  [suite_final]="renderer, closed loop, sweep, Table 3 with its controllers side by side"
  [train_policy]="train the policy (BC / DAgger), evaluate it, ship its checkpoint"
  [train_side]="up to four train_policy commands side by side, a GPU each, none shipped"
  [policy_surfaces]="the policy's sweep surfaces (sweeps/policy*.yaml)"
  [compile_profile]="where XLA's compile time goes: env_parts.py --compile-profile (operations, events)"
)

if [ $# -eq 0 ] || [ "$1" = -h ] || [ "$1" = --help ]; then
  sed -n '3,/^set -uo/p' "${BASH_SOURCE[0]}" | sed '$d; s/^# \{0,1\}//'; exit $(($# == 0 ? 2 : 0))
fi
if [ "$1" = --list ]; then
  for s in "${sets[@]}"; do printf '%-16s %s\n' "$s" "${about[$s]}"; done; exit 0
fi
for s in "$@"; do
  if [ -z "${about[$s]+set}" ]; then
    echo "gpu.sh: unknown set '$s' (bash experiments/gpu.sh --list names them)" >&2; exit 2
  fi
done

read -r -a py <<<"${PY:-python3}"
mkdir -p "$OUT" "$WORK"
shopt -s nullglob; wheels=(.whl/*.whl /tmp/wp/*.whl); shopt -u nullglob
# the wheels are the device machine's (its Python); a machine without nvidia-smi (a CPU check)
# runs on the packages installed there
command -v nvidia-smi >/dev/null || wheels=()
if [ ${#wheels[@]} -gt 0 ]; then
  site=${SITE:-/tmp/site}; stamp=$(ls -l "${wheels[@]}")
  if [ "$(cat "$site/.gpu_wheels" 2>/dev/null)" != "$stamp" ]; then
    "${py[@]}" -m pip install -q --no-index --no-deps --no-compile --no-cache-dir --upgrade \
      --target "$site" "${wheels[@]}" || exit
    echo "$stamp" > "$site/.gpu_wheels"
  fi
  export PYTHONPATH="$site:$root"
else
  export PYTHONPATH="$root${PYTHONPATH:+:$PYTHONPATH}"
fi
export PYTHONUNBUFFERED=1
{ command -v nvidia-smi >/dev/null && nvidia-smi --query-gpu=name,memory.total,driver_version \
    --format=csv,noheader; "${py[@]}" -c "import jax, mujoco; print('jax', jax.__version__, \
'mujoco', mujoco.__version__, jax.devices())"; } 2>&1 | tee "$OUT/device.txt"
summary() { "${py[@]}" experiments/gpu_summary.py "$@"; }

# ---- helpers of several sets (out, work: the set's folders) ----
fresh_work() { rm -rf "$work"; mkdir -p "$work" "$@"; }
mark_rows() { lines0=$(wc -l < benchmarks.jsonl); }  # the bench appends to benchmarks.jsonl:
new_rows() { tail -n +$((lines0 + 1)) benchmarks.jsonl > "$out/benchmarks.jsonl"; }  # its new lines
# timed [--with KEY=INT ...] JSONL NAME LIMIT CMD...: CMD for at most LIMIT s (log OUT/NAME.log);
# one JSON line to JSONL (exit status, wall time, the command's printed split)
timed() {
  local extra=(); while [ "$1" = --with ]; do extra+=(--with "$2"); shift 2; done
  local jsonl=$1 name=$2 limit=$3 t0 t1 rc; shift 3
  t0=$(date +%s.%N); timeout "$limit" "$@" >"$out/$name.log" 2>&1; rc=$?; t1=$(date +%s.%N)
  summary step "$name" "$rc" "$t0" "$t1" "$out/$name.log" "${extra[@]}" >>"$jsonl"
  [ "$rc" = 0 ] || echo "!! $name: exit status $rc (log $out/$name.log)"
}
# run_step NAME LIMIT CMD...: CMD (log OUT/NAME.log, its exit status last) unless the set's
# list `only` is set and leaves NAME out
run_step() {
  local name=$1 limit=$2; shift 2
  [ -z "$only" ] || [[ " $only " == *" $name "* ]] || return 0
  timeout "$limit" "$@" > "$out/$name.log" 2>&1; echo "exit $?" >> "$out/$name.log"
  echo "$name: $(tail -1 "$out/$name.log") at $(( $(date +%s) - start )) s"
}
# bench_job NAME [ENV=VALUE ...] -- BENCH ARGS: `python -m mjxrow.bench` in the background with
# an empty cache of its own; the timed calls of side-by-side jobs take turns (MJXROW_BENCH_LOCK)
bench_job() {
  local name=$1 envs=(); shift
  while [ "$1" != "--" ]; do envs+=("$1"); shift; done; shift
  ( env MJXROW_CACHE_DIR="$work/cache_$name" "${envs[@]}" timeout 560 \
      "${py[@]}" -m mjxrow.bench "$@" > "$out/$name.log" 2>&1; echo "exit $?" >> "$out/$name.log" ) &
}

# ---- the sets ----

set_determinism() {  # raw: det.jsonl, STEP.log, DETERMINISM.txt (episodes differing per pair)
  fresh_work; rm -f "$out/det.jsonl"
  local sweep=("${py[@]}" -m mjxrow.sweep sweeps.yaml --no-progress ${DET_SET:-}) flags name
  for flags in "" "--xla_gpu_deterministic_ops=true"; do
    for name in ${DET_RUNS:-cold warm1 warm2}; do
      local tag=${flags:+det_}$name
      local xla="${XLA_FLAGS:-}${flags:+ $flags}"; xla=${xla# }
      if [ -n "$xla" ]; then
        XLA_FLAGS="$xla" timed "$out/det.jsonl" "$tag" 300 "${sweep[@]}" \
          --cache-dir "$work/cache${flags:+_det}" --out "$work/$tag"
      else
        (unset XLA_FLAGS; timed "$out/det.jsonl" "$tag" 300 "${sweep[@]}" \
          --cache-dir "$work/cache" --out "$work/$tag")
      fi
      tail -n 2 "$out/$tag.log"
    done
  done
  for name in cold det_cold; do cp "$work/$name/report.md" "$out/report_$name.md" 2>/dev/null; done
  "${py[@]}" - "$work" > "$out/DETERMINISM.txt" <<'PY'
import sys
from pathlib import Path

import numpy as np
import pandas as pd

work = Path(sys.argv[1])
cols = ["success", "cha", "mae", "mse", "omega_std", "time"]
for pre in ("", "det_"):
    runs = {n: pd.read_csv(work / f"{pre}{n}" / "results.csv").sort_values(["cell", "episode"])
            for n in ("cold", "warm1", "warm2") if (work / f"{pre}{n}" / "results.csv").exists()}
    names = list(runs)
    for a, b in zip(names, names[1:], strict=False):
        x, y = runs[a][cols].to_numpy(float), runs[b][cols].to_numpy(float)
        rows = ~np.all(np.isclose(x, y, rtol=0, atol=1e-6, equal_nan=True), axis=1)
        print(f"{pre or 'default '}{a} vs {b}: {int(rows.sum())} of {len(x)} episodes differ "
              f"by more than 1e-6; max |d| {np.nanmax(np.abs(x - y)):.3g}")
PY
  cat "$out/DETERMINISM.txt"
}
set_time_to_result() {  # raw: ttr.jsonl, closed_loop.jsonl, seg_bf16_iou.jsonl, STEP.log
  budget=${BUDGET:-530}; smoke=${SMOKE:-0}; start=$(date +%s)
  scale=${LIMIT_SCALE:-$([ "$smoke" = 1 ] && echo 5 || echo 1)}; cache="$work/cache"
  fresh_work; rm -f "$out/ttr.jsonl" "$out/closed_loop.jsonl" "$out/seg_bf16_iou.jsonl"
  if [ "$smoke" = 1 ]; then
    sweep_flags=(--smoke); b64=(--batch 2 --image 16 --steps 10 --repeats 1)
    b224=(--batch 2 --image 32 --steps 10 --repeats 1); t3_eps=2; t3_flags=(--smoke)
    iou=(--n 8 --size 32)
  else
    sweep_flags=(); b64=(--batch 1024 --image 64 --steps 150 --repeats 3)
    b224=(--batch 512 --image 224 --steps 150 --repeats 2); t3_eps=100; t3_flags=()
    iou=(--n 512 --size 64)
  fi
  ttr() {  # ttr NAME MIN_LEFT MAX_S CMD...: CMD if MIN_LEFT s of the budget are left
    local name=$1 need=$2 max=$3 left; shift 3
    [ -z "${ONLY:-}" ] || [[ " $ONLY " == *" $name "* ]] || return 0
    left=$((budget - ($(date +%s) - start)))
    if [ "$left" -lt "$need" ]; then
      echo "== $name: skipped ($left s left, needs $need)"
      echo "{\"step\": \"$name\", \"skipped\": true, \"left_s\": $left}" >>"$out/ttr.jsonl"; return
    fi
    max=$((max * scale)); max=$((max < left ? max : left))
    echo "== $name ($(date +%T), $left s left, limit $max s): $*"
    timed "$out/ttr.jsonl" "$name" "$max" "$@"; tail -n 3 "$out/$name.log"
  }
  sweep=("${py[@]}" -m mjxrow.sweep sweeps.yaml "${sweep_flags[@]}" --no-progress)
  ttr sweep_cold 60 300 "${sweep[@]}" --cache-dir "$cache" --out "$work/sweep_cold"
  ttr sweep_warm 20 120 "${sweep[@]}" --cache-dir "$cache" --out "$work/sweep_warm"
  cp "$work/sweep_warm/summary.csv" "$out/sweep_summary.csv" 2>/dev/null
  # in one call of 216 episodes, then also with the XLA renderer, each from an empty cache
  one=(--set batch_size=216); fused=("${sweep[@]}" --cache-dir "$work/cache_fused" "${one[@]}"
                                     --set render.kernel=fused)
  ttr sweep_b216_cold 60 300 "${sweep[@]}" --cache-dir "$work/cache_b216" "${one[@]}" \
    --out "$work/sweep_b216_cold"
  ttr sweep_fused_cold 60 300 "${fused[@]}" --out "$work/sweep_fused_cold"
  ttr sweep_fused_warm 20 120 "${fused[@]}" --out "$work/sweep_fused_warm"
  bench=("${py[@]}" -m mjxrow.bench closed_loop --out "$out/closed_loop.jsonl" --cache-dir "$cache")
  ttr closed_loop_64 60 200 "${bench[@]}" "${b64[@]}"
  ttr closed_loop_224 60 200 "${bench[@]}" "${b224[@]}"
  ttr closed_loop_64_bf16 60 200 "${bench[@]}" "${b64[@]}" --seg-dtype bfloat16
  ttr seg_bf16_iou 30 90 "${py[@]}" experiments/seg_bf16_iou.py "${iou[@]}" \
    --out "$out/seg_bf16_iou.jsonl"
  t3=("${py[@]}" experiments/table3_navigation.py "${t3_flags[@]}" --episodes "$t3_eps"
      --no-progress --doc "$work/table3.md")
  ttr table3_block_cold 60 200 "${t3[@]}" --cache-dir "$cache" --presets zucchini \
    --controllers segzeros_learned --out "$work/t3_cold"
  ttr table3_block_warm 20 60 "${t3[@]}" --cache-dir "$cache" --presets zucchini \
    --controllers segzeros_learned --out "$work/t3_warm"
  ttr table3_whole_cold "${FULL_TABLE3:-420}" 600 "${t3[@]}" --out "$work/t3_whole" \
    --cache-dir "$work/cache_t3"
  echo "== summary ($(( $(date +%s) - start )) s)"
  summary time_to_result "$out" "$OUT/device.txt"
  du -sh "$cache" 2>/dev/null
}

set_surfaces() {  # surfaces.md (success per cell, side by side), surfaces.tgz (the six sweeps)
  fresh_work; flags=(--no-progress --cache-dir "$work/cache"); [ "${SMOKE:-0}" = 1 ] && flags+=(--smoke)
  declare -A runs=(
    [drr_segzeros]="sweeps.yaml" [drr_policy]="sweeps/policy.yaml"
    [drr_oracle]="sweeps.yaml --set controller.name=oracle"
    [slope_segzeros]="sweeps/slope_roughness.yaml" [slope_policy]="sweeps/policy_slope_roughness.yaml"
    [slope_oracle]="sweeps/slope_roughness.yaml --set controller.name=oracle")
  # the sweeps share the GPU: each may take a sixth of its memory (JAX takes 75 % by default)
  export XLA_PYTHON_CLIENT_MEM_FRACTION=${XLA_PYTHON_CLIENT_MEM_FRACTION:-0.15}
  for name in "${!runs[@]}"; do
    read -r -a args <<<"${runs[$name]}"
    timeout "${LIMIT:-520}" "${py[@]}" -m mjxrow.sweep "${args[@]}" "${flags[@]}" \
      --out "$work/$name" >"$work/$name.log" 2>&1 &
  done
  wait
  for name in "${!runs[@]}"; do echo "== $name"; tail -n 2 "$work/$name.log"; done
  summary surfaces "$work" "$out"
  (cd "$work" && tar -czf "$out/surfaces.tgz" --exclude=cache --exclude=cells drr_* slope_*)
}

set_scaling() {  # scaling.jsonl (the sweeps), closed_loop.jsonl (bench rows), sweeps.tgz
  fresh_work; rm -f "$out/scaling.jsonl" "$out/closed_loop.jsonl"; cache="$work/cache"
  if [ "${SMOKE:-0}" = 1 ]; then
    sweep_flags=(--smoke); bench_flags=(--batch 4 --image 16 --steps 10 --repeats 1)
  else
    sweep_flags=(--set seeds=114 --set batch_size=1368)
    bench_flags=(--batch 2048 --image 64 --steps 150 --repeats 3)
  fi
  read -r -a bench_set <<<"${BENCH_SET:-}"; bench_flags+=("${bench_set[@]}")
  for n in 1 2; do  # one compilation cache for all runs; CUDA_VISIBLE_DEVICES=0, then 0,1
    devs=$([ "$n" = 1 ] && echo 0 || echo 0,1)
    echo "== sweep on $n GPU(s) ($(date +%T))"
    CUDA_VISIBLE_DEVICES=$devs timed --with "gpus=$n" "$out/scaling.jsonl" "sweep_$n" \
      "${SWEEP_LIMIT:-190}" "${py[@]}" -m mjxrow.sweep sweeps.yaml "${sweep_flags[@]}" \
      --no-progress --cache-dir "$cache" --out "$work/sweep_$n"
    tail -n 2 "$out/sweep_$n.log"
  done
  for n in 1 2; do
    devs=$([ "$n" = 1 ] && echo 0 || echo 0,1)
    echo "== closed loop on $n GPU(s) ($(date +%T))"
    CUDA_VISIBLE_DEVICES=$devs timeout "${BENCH_LIMIT:-180}" "${py[@]}" -m mjxrow.bench \
      closed_loop "${bench_flags[@]}" --cache-dir "$cache" --out "$out/closed_loop.jsonl" \
      >"$out/bench_$n.log" 2>&1 || echo "!! bench on $n GPU(s) failed (log $out/bench_$n.log)"
    tail -n 2 "$out/bench_$n.log"
  done
  tar czf "$out/sweeps.tgz" -C "$work" --ignore-failed-read sweep_1/summary.csv \
    sweep_1/results.csv sweep_2/summary.csv sweep_2/results.csv 2>/dev/null
  summary scaling "$out" "$work" "$OUT/device.txt"
}

set_scale_out() {  # scale_out.jsonl (one line per sweep), rows.jsonl (benchmarks rows)
  # every run is ONE batch of PER_GPU episodes per GPU (seeds = n·PER_GPU / 36), so its run
  # time is that of one call on n GPUs; the ratio of episodes per second of run time against
  # one GPU is the scale-out at that batch per GPU. Each run compiles into its own empty cache.
  fresh_work; rm -f "$out/scale_out.jsonl"
  local per n seeds
  for per in ${PER_GPU:-8208}; do
    if (( per % 36 )); then echo "!! PER_GPU=$per: not a multiple of 36"; continue; fi
    for n in ${GPUS:-1 2 4}; do
      if (( n > $(nvidia-smi -L 2>/dev/null | wc -l) )); then
        echo "!! $n GPUs asked for, $(nvidia-smi -L | wc -l) present"; continue
      fi
      seeds=$((n * per / 36)); devs=$(seq -s, 0 $((n - 1)))
      echo "== sweep: $n GPU(s), $((n * per)) episodes in one batch ($(date +%T))"
      CUDA_VISIBLE_DEVICES=$devs timed --with "gpus=$n" --with "per_gpu=$per" \
        --with "episodes=$((n * per))" "$out/scale_out.jsonl" "sweep_${n}_$per" \
        "${LIMIT:-280}" "${py[@]}" -m mjxrow.sweep sweeps.yaml --set "seeds=$seeds" \
        --set "batch_size=$((n * per))" --force --no-progress \
        --cache-dir "$work/cache_${n}_$per" --out "$work/sweep_${n}_$per"
      tail -n 2 "$out/sweep_${n}_$per.log"
    done
  done
  summary scale_out "$out" "$OUT/device.txt"
}

set_table3() {  # table3.md (the page), table3.tgz (every block's results and logs)
  fresh_work "$work/logs"
  read -r -a controllers <<<"${CONTROLLERS:-oracle segzeros_gt segzeros_learned policy}"
  read -r -a presets <<<"${PRESETS:-zucchini lettuce chard pear vineyard}"
  flags=(--no-progress --cache-dir "$work/cache" --out "$work/t3"); [ "${SMOKE:-0}" = 1 ] && flags+=(--smoke)
  export XLA_PYTHON_CLIENT_PREALLOCATE=false  # the processes share the GPU's memory
  export MJXROW_RENDER_KERNEL=${MJXROW_RENDER_KERNEL:-fused}  # XLA renderer: compiles sooner
  t3() {  # t3 NAME ARGS...: one block process in the background
    local name=$1; shift; procs=$((procs + 1))
    timeout "${BLOCK_LIMIT:-420}" "${py[@]}" experiments/table3_navigation.py "${flags[@]}" "$@" \
      --doc "$work/logs/$name.md" >"$work/logs/$name.log" 2>&1 &
  }
  t0=$(date +%s.%N); procs=0
  if [ "${SEPARATE:-0}" = 1 ]; then  # one process and one program per block
    for c in "${controllers[@]}"; do
      for p in "${presets[@]}"; do t3 "$c-$p" --separate --presets "$p" --controllers "$c"; done
    done
  else  # one process per preset, its controllers in one program; the policy's blocks apart
    shared=(); apart=()
    for c in "${controllers[@]}"; do
      if [ "$c" = policy ]; then apart+=("$c"); else shared+=("$c"); fi
    done
    for i in "${!presets[@]}"; do
      p=${presets[$i]}
      # staggered, the first presets' runs overlap the last ones' compiles
      [ "$i" -gt 0 ] && sleep "${STAGGER:-20}"
      [ ${#shared[@]} -gt 0 ] && t3 "shared-$p" --presets "$p" --controllers "${shared[@]}"
      for c in "${apart[@]}"; do t3 "$c-$p" --presets "$p" --controllers "$c"; done
    done
  fi
  wait; t1=$(date +%s.%N)
  "${py[@]}" experiments/table3_navigation.py "${flags[@]}" --controllers "${controllers[@]}" \
    --presets "${presets[@]}" --doc "$out/table3.md" >"$work/logs/assemble.log" 2>&1
  t2=$(date +%s.%N)
  failed=$(grep -L "^written:" "$work"/logs/*-*.log | xargs -r -n1 basename | tr '\n' ' ')
  dt() { awk -v a="$1" -v b="$2" 'BEGIN { printf "%.1f", b - a }'; }
  echo "blocks: $(( ${#controllers[@]} * ${#presets[@]} )) in $procs parallel processes," \
    "$(dt "$t0" "$t1") s wall (compilation included); assembling the page $(dt "$t1" "$t2") s;" \
    "blocks without a result: ${failed:-none}" | tee "$work/logs/summary.txt"
  grep -h "^| .* | ours\|^| .* | paper" "$out/table3.md" | head -40
  t3_out=t3; [ "${SMOKE:-0}" = 1 ] && t3_out=t3_smoke  # --smoke runs into OUT_smoke
  tar -czf "$out/table3.tgz" -C "$work" --exclude=cache --exclude=cells "$t3_out" logs
}

set_table3_kernels() {  # blocks.txt (kernel, controller, wall s, exit), table3_{pallas,fused}.md
  fresh_work "$work/logs"; preset=${PRESET:-zucchini}
  read -r -a controllers <<<"${CONTROLLERS:-oracle segzeros_gt segzeros_learned policy}"
  flags=(--no-progress --presets "$preset"); [ "${SMOKE:-0}" = 1 ] && flags+=(--smoke)
  export XLA_PYTHON_CLIENT_PREALLOCATE=false
  : > "$out/blocks.txt"
  for k in pallas fused; do
    for c in "${controllers[@]}"; do
      ( t0=$(date +%s.%N)
        MJXROW_RENDER_KERNEL=$k timeout "${BLOCK_LIMIT:-500}" "${py[@]}" \
          experiments/table3_navigation.py "${flags[@]}" --controllers "$c" --out "$work/t3_$k" \
          --cache-dir "$work/cache_${k}_$c" --doc "$work/logs/$k-$c.md" > "$work/logs/$k-$c.log" 2>&1
        rc=$?; t1=$(date +%s.%N)
        printf '%s %s %.1f %s\n' "$k" "$c" "$(awk "BEGIN{print $t1 - $t0}")" "$rc" >> "$out/blocks.txt" ) &
    done
  done
  wait
  for k in pallas fused; do
    "${py[@]}" experiments/table3_navigation.py "${flags[@]}" --controllers "${controllers[@]}" \
      --out "$work/t3_$k" --cache-dir "$work/cache_assemble_$k" --doc "$out/table3_$k.md" \
      > "$work/logs/assemble-$k.log" 2>&1
  done
  tar czf "$out/logs.tgz" -C "$work" logs
  echo "| kernel | controller | wall [s] | exit |"; echo "|---|---|---|---|"
  sort "$out/blocks.txt" | while read -r k c s rc; do echo "| $k | $c | $s | $rc |"; done
  for k in pallas fused; do echo "== $k"; grep "^| $preset" "$out/table3_$k.md" | head -8; done
}

set_speed_round() {  # benchmarks.jsonl (the new rows), NAME.log
  fresh_work; mark_rows; start=$(date +%s)
  export MJXROW_BENCH_LOCK="$work/timing.lock" XLA_PYTHON_CLIENT_PREALLOCATE=false
  bench_job render_z2 -- render --preset zucchini --res 64 128 --batch 1024
  bench_job render_z1 -- render --preset zucchini --res 64 128 --batch 1024 --set deep_split=1
  bench_job render_l2 -- render --preset lettuce --res 64 128 --batch 1024
  bench_job render_l1 -- render --preset lettuce --res 64 128 --batch 1024 --set deep_split=1
  bench_job loop_64 -- closed_loop --image 64 --batch 1024 2048 4096 --steps 150 --repeats 3
  bench_job loop_64_noautotune XLA_FLAGS=--xla_gpu_autotune_level=0 -- \
    closed_loop --image 64 --batch 1024 --steps 150 --repeats 3
  bench_job loop_224 -- closed_loop --image 224 --batch 512 1024 --steps 150 --repeats 2
  wait
  echo "all done in $(( $(date +%s) - start )) s"; new_rows
  for f in "$out"/*.log; do echo "== $(basename "$f")"; grep -E "B=|frames/s|exit|Error|error" "$f" | tail -8; done
  "${py[@]}" experiments/benchmarks_table.py --all --file "$out/benchmarks.jsonl"
}

set_loop_224() {  # rows.jsonl, NAME.log: a pair of processes per B, compiling side by side
  fresh_work; start=$(date +%s)
  export MJXROW_BENCH_LOCK="$work/timing.lock" XLA_PYTHON_CLIENT_PREALLOCATE=false
  read -r -a extra <<<"${SETS:---set render.deep_share=0.125}"
  loop=(closed_loop --image 224 --seg-dtype bfloat16 --steps "${STEPS:-60}" --repeats 3
        --out "$out/rows.jsonl")
  for b in ${BATCHES:-4096 6144}; do
    bench_job "default_$b" -- "${loop[@]}" --batch "$b"
    bench_job "sets_$b" -- "${loop[@]}" --batch "$b" "${extra[@]}"
    wait  # one pair at a time: two timed programs of this size do not fit the GPU together
    echo "B=$b done at $(( $(date +%s) - start )) s"
  done
  for f in "$out"/*.log; do echo "== $(basename "$f")"; grep -E "B=|exit|Error" "$f" | tail -4; done
  summary loop_224 "$out/rows.jsonl"
}

set_compile_flags() {  # VARIANT.log, summary.txt (exit, B= lines, compiler stage times)
  #  default: XLA's defaults; cmd: the control loop captured whole as CUDA graphs
  #  (--xla_gpu_enable_command_buffer=+WHILE); noat: no autotuning (its share of the compile)
  declare -A xla=([default]="" [cmd]="--xla_gpu_enable_command_buffer=+WHILE"
                  [noat]="--xla_gpu_autotune_level=0")
  read -r -a variants <<<"${VARIANTS:-default cmd noat}"
  for v in "${variants[@]}"; do
    [ -n "${xla[$v]+set}" ] || { echo "compile_flags: unknown variant '$v' (one of: ${!xla[*]})" >&2; return 2; }
  done
  export XLA_PYTHON_CLIENT_PREALLOCATE=false; mark_rows; rm -f "$out/summary.txt"
  for v in "${variants[@]}"; do  # one after another: each compiles on an otherwise idle host
    t0=$(date +%s)
    env XLA_FLAGS="${xla[$v]}" JAX_LOG_COMPILES=1 TF_CPP_MIN_LOG_LEVEL=0 \
      TF_CPP_VMODULE=gpu_compiler=1 timeout 300 "${py[@]}" -m mjxrow.bench closed_loop \
      --image 64 --batch 216 --steps 150 --repeats 3 --no-cache --set render.kernel=fused \
      > "$out/$v.log" 2>&1
    echo "$v: exit $? in $(( $(date +%s) - t0 )) s" | tee -a "$out/summary.txt"
    grep -E "^B=" "$out/$v.log" | tee -a "$out/summary.txt"
  done
  for v in "${variants[@]}"; do  # the compiler's stage times of the closed-loop program
    grep -E "(RunHloPasses|RunBackend) for jit_batch |tracing batch for|conversion jit\(batch\)|compilation of jit\(batch\)" \
      "$out/$v.log" | sed -E "s/^.*(GpuCompiler::|Finished )/$v: /; s/ \(cumul.*//" | tee -a "$out/summary.txt"
  done
  new_rows; cat "$out/summary.txt"
}

set_mjwarp() {  # benchmarks.jsonl (the new rows), mjwarp.log
  mark_rows; read -r -a args <<<"${MJWARP_ARGS:---batch 1024}"
  timeout 540 "${py[@]}" -m mjxrow.bench render_mjwarp "${args[@]}" 2>&1 | tee "$out/mjwarp.log" | \
    grep -v "^Module \|^Warp " | tail -40
  new_rows
}

set_seg_speed() {  # rows.jsonl, NAME.log
  #  seg224 / seg64: seg_variants.py, every variant compiled, then timed in interleaved rounds
  #  profile_loop_224 (defaults), profile_render_224 (command buffers off: every kernel's stage)
  fresh_work; only=""; start=$(date +%s)
  export XLA_PYTHON_CLIENT_PREALLOCATE=false MJXROW_CACHE_DIR="$work/cache"
  run_step seg224 240 "${py[@]}" experiments/seg_variants.py --size 224 --batch 1024 --rounds 5 \
    --out "$out/rows.jsonl"
  run_step seg64 150 "${py[@]}" experiments/seg_variants.py --size 64 --batch 4096 --rounds 5 \
    --out "$out/rows.jsonl" --variants float32:conv:conv float32:conv:dot float32:mixed:dot \
    float32:phases:dot bfloat16:phases:dot
  if [ -z "${SEG_ONLY:-}" ]; then
    run_step profile_loop_224 300 "${py[@]}" experiments/profile_closed_loop.py --image 224 \
      --batch 1024 --steps 20 --repeats 3 --calls 1 --out "$work/profile_loop"
    run_step profile_render_224 120 env XLA_FLAGS=--xla_gpu_enable_command_buffer= \
      "${py[@]}" experiments/profile_render.py --res 224 --batch 1024 --out "$work/profile_render"
  fi
  for f in seg224 seg64; do grep "^|" "$out/$f.log"; echo; done
  for f in "$out"/profile_*.log; do echo "== $(basename "$f")"; grep -v "Delay kernel" "$f" | tail -25; done
}

set_shading() {  # rows.jsonl, NAME.log
  #  render_variants: 64, 128, 224 px, settle none (the GPU default) and barrier, compiled in
  #  threads, timed in interleaved rounds; profile_render_224[_barrier]: command buffers off
  fresh_work; start=$(date +%s)
  only=${ONLY:-render_variants profile_render_224 profile_render_224_barrier loop_224}
  export XLA_PYTHON_CLIENT_PREALLOCATE=false MJXROW_CACHE_DIR="$work/cache"
  read -r -a loop_sets <<<"${LOOP_SETS:-}"
  run_step render_variants 300 "${py[@]}" experiments/render_variants.py --res 64 128 224 \
    --batch 1024 --variants "" settle=barrier --rounds 5 --out "$out/rows.jsonl"
  run_step profile_render_224 120 env XLA_FLAGS=--xla_gpu_enable_command_buffer= \
    "${py[@]}" experiments/profile_render.py --res 224 --batch 1024 --calls 2 --out "$work/pr"
  run_step profile_render_224_barrier 120 env XLA_FLAGS=--xla_gpu_enable_command_buffer= \
    "${py[@]}" experiments/profile_render.py --res 224 --batch 1024 --calls 2 --out "$work/prb" \
    --set settle=barrier
  run_step loop_224 240 "${py[@]}" -m mjxrow.bench closed_loop --image 224 --batch 1024 \
    --steps 150 --repeats 3 --out "$out/rows.jsonl" "${loop_sets[@]}"
  grep -h "^|" "$out/render_variants.log" 2>/dev/null
  for f in "$out"/profile_*.log "$out"/loop_*.log; do
    [ -f "$f" ] && { echo "== $(basename "$f")"; grep -v "Delay kernel" "$f" | tail -22; }
  done
}

log() { echo "== $* ($(date +%T))"; }
sweep_time() {  # the default sweep's wall time, a row in OUT/benchmarks.jsonl
  log sweep; local t0 t1; t0=$(date +%s.%N)
  "${py[@]}" -m mjxrow.sweep sweeps.yaml --set batch_size=216 --out "$out/sweep" --no-progress | tail -25
  t1=$(date +%s.%N); summary sweep_row "$out" "$t0" "$t1"
}
set_suite_bench() {  # benchmarks.jsonl, sweep.tgz
  b=(--out "$out/benchmarks.jsonl")
  log fields;   "${py[@]}" -m mjxrow.bench fields --batch 1024 "${b[@]}"
  log physics;  "${py[@]}" -m mjxrow.bench physics --batch 256 1024 4096 "${b[@]}"
  log render;   "${py[@]}" -m mjxrow.bench render "${b[@]}"
  log closed_loop; "${py[@]}" -m mjxrow.bench closed_loop --batch 256 1024 --image 64 --steps 150 "${b[@]}"
  sweep_time
  log dataset; timeout 200 "${py[@]}" -m mjxrow.bench dataset "${b[@]}"
  (cd "$out" && tar czf sweep.tgz sweep && rm -rf sweep)
}
set_suite_tables() {  # table2.md, table3.md, table3_runs.tgz
  log table2; "${py[@]}" experiments/table2_segmentation.py --n 512 --out "$out/table2.md"
  log table3; "${py[@]}" experiments/table3_navigation.py --episodes 100 --out runs/table3 \
    --doc "$out/table3.md" --no-progress
  tar czf "$out/table3_runs.tgz" runs/table3
}
set_suite_final() {  # benchmarks.jsonl, sweep.tgz, table3.md (also written to docs/), table3_runs.tgz
  b=(--out "$out/benchmarks.jsonl")
  log render; timeout 200 "${py[@]}" -m mjxrow.bench render --res 64 128 "${b[@]}"
  log closed_loop; timeout 150 "${py[@]}" -m mjxrow.bench closed_loop --batch 256 1024 --image 64 \
    --steps 150 "${b[@]}"
  timeout 150 bash -c "$(declare -p py out; declare -f log sweep_time summary); sweep_time"
  (cd "$out" && tar czf sweep.tgz sweep && rm -rf sweep)
  log table3; mkdir -p runs/table3
  for c in oracle segzeros_gt segzeros_learned; do
    XLA_PYTHON_CLIENT_MEM_FRACTION=0.3 timeout "${T3_LIMIT:-420}" "${py[@]}" \
      experiments/table3_navigation.py --episodes 100 --out runs/table3 --controllers "$c" \
      --doc "runs/table3/$c.md" --no-progress >"runs/table3_$c.log" 2>&1 &
  done
  wait
  tail -n 3 runs/table3_*.log
  timeout 60 "${py[@]}" experiments/table3_navigation.py --episodes 100 --out runs/table3 \
    --doc docs/table3.md --no-progress | tail -30
  cp docs/table3.md "$out/table3.md"
  tar czf "$out/table3_runs.tgz" runs/table3 runs/table3_*.log
}

set_seg_variety() {  # train.log, table2.md, seg_variety.tgz (the model as exported, its log)
  # One persistent cache for both processes: Table 2's renderers (8 frames per crop, as the
  # training's) load from it instead of compiling again.
  fresh_work; export JAX_COMPILATION_CACHE_DIR="$work/jax_cache"
  local t0; t0=$(date +%s); read -r -a sizes <<<"${SIZES:-128 64}"
  timeout "${TRAIN_LIMIT:-390}" "${py[@]}" -m mjxrow.seg.train --crop all --on-the-fly --init all \
    --size "${sizes[@]}" --steps "${STEPS:-2500}" --batch 40 --lr 4e-4 --warmup 200 \
    --eval-every 500 --log-every 100 --val-n 200 --out "$work/run" --no-progress \
    >"$out/train.log" 2>&1
  echo "train: exit $? at $(( $(date +%s) - t0 )) s" | tee -a "$out/train.log"
  "${py[@]}" -c "import sys; from mjxrow.seg.training import export; print(export(*sys.argv[1:]))" \
    "$work/run" "$work/ckpt/all" || return
  timeout "${T2_LIMIT:-150}" "${py[@]}" experiments/table2_segmentation.py \
    --ckpt-root "$work/ckpt" --n 512 --batch 8 --also-sizes "${sizes[@]:1}" \
    --out "$out/table2.md" >"$out/table2.log" 2>&1
  echo "table2: exit $? at $(( $(date +%s) - t0 )) s" | tee -a "$out/train.log"
  grep -E "val_iou" "$work/run/train_log.jsonl" | tail -n 5
  tar -czf "$out/seg_variety.tgz" -C "$work" ckpt
}

variety_ckpt() {  # the segmenter of the variety sets: CKPT, else seg_variety's, else shipped
  local c=${CKPT:-}; [ -z "$c" ] && [ -f "$WORK/seg_variety/ckpt/all/config.json" ] \
    && c=$WORK/seg_variety/ckpt/all
  [ -n "$c" ] && echo "--set perception.checkpoint=$c"
}

set_search_segzeros() {  # search.jsonl (bench rows), search.tgz (the run's outputs), search.log
  local ck; ck=$(variety_ckpt); rm -f "$out/search.jsonl"
  # shellcheck disable=SC2086  # ck: empty or one flag and its value
  timeout "${SEARCH_LIMIT:-560}" "${py[@]}" -m mjxrow.search searches/segzeros_variety.yaml \
    --confirm 20 --out "$work/run" $ck --no-progress --cache-dir "$work/cache" \
    --record "$out/search.jsonl" >"$out/search.log" 2>&1
  echo "exit $?"; tail -n 25 "$out/search.log"
  tar -czf "$out/search.tgz" -C "$work" --exclude=cache --exclude=state run
}

set_search_oracle() {  # search.jsonl, search.tgz, search.log: the same box, the oracle, MINUTES
  # [2] of CMA-ES and no baseline (the question is whether it finds any failure at all)
  rm -f "$out/search.jsonl"
  timeout "${SEARCH_LIMIT:-200}" "${py[@]}" -m mjxrow.search searches/oracle_variety.yaml \
    --set budget.minutes="${MINUTES:-2}" --set baseline=none --confirm 20 --out "$work/run" \
    --no-progress --cache-dir "$work/cache" --record "$out/search.jsonl" >"$out/search.log" 2>&1
  echo "exit $?"; tail -n 15 "$out/search.log"
  tar -czf "$out/search.tgz" -C "$work" --exclude=cache --exclude=state run
}

set_variety_surfaces() {  # NAME.log, surfaces.tgz (the four sweeps)
  local ck; ck=$(variety_ckpt); flags=(--no-progress --cache-dir "$work/cache")
  [ "${SMOKE:-0}" = 1 ] && flags+=(--smoke)
  export XLA_PYTHON_CLIENT_MEM_FRACTION=${XLA_PYTHON_CLIENT_MEM_FRACTION:-0.2}
  for y in curvature_gaps weeds; do
    # shellcheck disable=SC2086
    timeout "${LIMIT:-300}" "${py[@]}" -m mjxrow.sweep "sweeps/$y.yaml" $ck "${flags[@]}" \
      --out "$work/$y" >"$out/$y.log" 2>&1 &
  done
  wait
  for y in curvature_gaps weeds; do echo "== $y"; tail -n 4 "$out/$y.log"; done
  tar -czf "$out/surfaces.tgz" -C "$work" --exclude=cache --exclude=cells curvature_gaps weeds
}

set_render_curved() {  # render_curved.log
  timeout "${LIMIT:-240}" "${py[@]}" experiments/render_accuracy.py --fields straight arc sine \
    --fps --res 64 --views along headland >"$out/render_curved.log" 2>&1
  echo "exit $?" >> "$out/render_curved.log"; tail -n 30 "$out/render_curved.log"
}

# train_one OUT WORK [ARGS ...]: train_policy.py with the sets' defaults and ARGS into WORK
# (a second call resumes it), its log in OUT/train.log, and OUT/policy.tgz, OUT/learning_curve.png,
# OUT/logs.tgz (train_log.jsonl, adversary.jsonl, eval.md, eval.json, summary.json,
# benchmarks.jsonl: one file, since a device machine returns few); with --ship the shipped
# policy is in policy.tgz too; its exit status
train_one() {
  local o=$1 w=$2 status logs parts f; shift 2
  mkdir -p "$o" "$w"
  (nvidia-smi --query-gpu=name,driver_version --format=csv,noheader || true) > "$o/train.log"
  "${py[@]}" experiments/train_policy.py --out "$w" --budget-minutes 5 --deadline-minutes 9 \
    --bc-fraction 1 "$@" 2>&1 | tee -a "$o/train.log"
  status=${PIPESTATUS[0]}
  for f in learning_curve.png adversary.png; do [ -e "$w/$f" ] && cp "$w/$f" "$o/"; done
  logs=()
  for f in train_log.jsonl adversary.jsonl eval.md eval.json summary.json benchmarks.jsonl; do
    [ -e "$w/$f" ] && logs+=("$f")
  done
  [ ${#logs[@]} -gt 0 ] && tar -czf "$o/logs.tgz" -C "$w" "${logs[@]}"
  # the checkpoints as one file: a device machine returns few files and no deep folders
  parts=(); [ -d "$w/policy" ] && parts+=(-C "$w" policy)
  [ -d "$w/policy_last" ] && parts+=(-C "$w" policy_last)
  if [[ " $* " == *" --ship "* ]] && [ -d mjxrow/checkpoints/policy ]; then  # what it shipped
    rm -rf "$w/shipped_policy" && cp -r mjxrow/checkpoints/policy "$w/shipped_policy"
    parts+=(-C "$w" shipped_policy)
  fi
  [ ${#parts[@]} -gt 0 ] && tar -czf "$o/policy.tgz" "${parts[@]}"
  return "$status"
}

set_train_policy() {  # train.log, policy.tgz, learning_curve.png (adversary.png), logs.tgz
  # (train_one); the training state stays in WORK/train_policy (a second call resumes it), and
  # the policy is shipped into mjxrow/checkpoints/policy/; the set's status is the training's
  read -r -a args <<<"${TRAIN_ARGS:-}"
  train_one "$out" "$work" --ship "${args[@]}"
}

set_train_side() {  # I.log while it runs, then I.tgz (train_one's files), per command I
  # commands side by side, one GPU each: command I (0-3) where TRAIN_ARGS_I is set, on GPU I
  # (CUDA_VISIBLE_DEVICES), with XLA_FLAGS_I if set, pinned to its share of the cores; nothing
  # is shipped; the set's status is the first failing command's
  local ids=() i k n cores v x rc status=0 pids=()
  for i in 0 1 2 3; do v=TRAIN_ARGS_$i; [ -n "${!v:-}" ] && ids+=("$i"); done
  if [ ${#ids[@]} -eq 0 ]; then
    echo "train_side: set TRAIN_ARGS_0 (and TRAIN_ARGS_1 .. TRAIN_ARGS_3 for more)" >&2; return 2
  fi
  for i in "${ids[@]}"; do  # side by side, shipping commands would overwrite each other's
    v=TRAIN_ARGS_$i
    if [[ " ${!v} " == *" --ship "* ]]; then
      echo "train_side: TRAIN_ARGS_$i: --ship is not for commands side by side" >&2; return 2
    fi
  done
  n=${#ids[@]}; cores=$(( $(nproc) / n )); [ "$cores" -ge 1 ] || cores=1; k=0
  for i in "${ids[@]}"; do
    v=TRAIN_ARGS_$i; x=XLA_FLAGS_$i
    ( read -r -a args <<<"${!v}"
      export CUDA_VISIBLE_DEVICES=$i
      if [ -n "${!x:-}" ]; then export XLA_FLAGS="${!x}"; fi
      taskset -cp "$((k * cores))-$((k * cores + cores - 1))" "$BASHPID" > /dev/null
      train_one "$work/$i/files" "$work/$i/run" "${args[@]}" > "$out/$i.log" 2>&1
      rc=$?
      tar -czf "$out/$i.tgz" -C "$work/$i" files && rm -f "$out/$i.log"
      exit "$rc" ) &
    pids+=($!); k=$((k + 1))
  done
  for k in "${!pids[@]}"; do
    wait "${pids[$k]}"; rc=$?
    if [ "$rc" != 0 ]; then
      [ "$status" = 0 ] && status=$rc; echo "!! command ${ids[$k]}: exit status $rc"
    fi
  done
  for i in "${ids[@]}"; do
    v=TRAIN_ARGS_$i; echo "== command $i: ${!v}"
    tar -xzOf "$out/$i.tgz" files/train.log 2>/dev/null | grep -aE "^compiled [0-9]|on [a-z]+: success|env-steps/s during|wall time" | cut -c1-240
  done
  return "$status"
}

set_policy_surfaces() {  # NAME.log, surfaces.tgz
  read -r -a args <<<"${SWEEP_ARGS:-}"
  for y in sweeps/policy.yaml sweeps/policy_slope_roughness.yaml; do
    name=$(basename "$y" .yaml)
    "${py[@]}" -m mjxrow.sweep "$y" --out "$work/$name" --no-progress "${args[@]}" 2>&1 | tee "$out/$name.log"
  done
  tar -czf "$out/surfaces.tgz" -C "$work" policy policy_slope_roughness
}

set_sun() {  # sun_CONTROLLER[_LABEL].log, sun.tgz: sweeps/sun.yaml (pear, the sun turned about
  # the rows) for each of SUN_CONTROLLERS, the policy's checkpoint SUN_CHECKPOINT
  local c name status=0 names=()
  for c in ${SUN_CONTROLLERS:-segzeros policy}; do
    name=sun_$c${SUN_LABEL:+_$SUN_LABEL}; names+=("$name")
    "${py[@]}" -m mjxrow.sweep sweeps/sun.yaml --out "$work/$name" --no-progress \
      --set controller.name="$c" --set controller.checkpoint="${SUN_CHECKPOINT:-shipped}" \
      2>&1 | tee "$out/$name.log"
    [ "${PIPESTATUS[0]}" = 0 ] || status=1
  done
  tar -czf "$out/sun.tgz" -C "$work" --exclude='cells' "${names[@]}"
  return "$status"
}

set_compile_profile() {  # compile_profile.log (the operations, then XLA's events),
  # compile_profile.csv
  read -r -a parts <<<"${PARTS:-rollout}"
  "${py[@]}" experiments/env_parts.py --preset "${PRESET:-pear}" --batch "${BATCH:-3072}" \
    --parts "${parts[@]}" --compile-profile "$work/prof" 2>&1 | tee "$out/compile_profile.log"
  cp "$work/prof/compile_profile.csv" "$out/" 2>/dev/null
}

status=0
for s in "$@"; do
  out="$OUT/$s"; work="$WORK/$s"; mkdir -p "$out" "$work"; t=$(date +%s)
  echo "=== $s ($(date +%T)): $out"
  ( "set_$s" ); rc=$?
  echo "=== $s: exit $rc in $(( $(date +%s) - t )) s"
  [ "$status" = 0 ] && status=$rc
done
exit "$status"
