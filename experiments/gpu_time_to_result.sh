#!/usr/bin/env bash
# Time to result and closed-loop throughput on one GPU, in at most ~9 minutes of wall time.
# Run from the project root (mujoco importable, e.g. PYTHONPATH=/tmp/site:$PWD):
#
#   bash experiments/gpu_time_to_result.sh           # figures in $OUT (default /tmp/ttr_out)
#   SMOKE=1 BUDGET=3000 bash experiments/gpu_time_to_result.sh   # tiny sizes: checks the
#                                                    script on a CPU (step limits x LIMIT_SCALE=5)
#
# Steps, in order of priority; a step starts only while enough of the budget (BUDGET seconds,
# default 530) is left, and is cut at what is left:
#  1. `python -m mjxrow.sweep sweeps.yaml` with an empty compilation cache (cold), then again
#     in a new process with the same cache into a fresh --out (warm): wall time and the sweep's
#     own compile / run / write split;
#     Then in one call of 216 episodes (batch_size=216), cold, and with the XLA renderer
#     (render.kernel=fused) cold and warm, each with its own empty cache;
#  2. `python -m mjxrow.bench closed_loop` at 64 x 64 (B = 1024), segmenter float32: control
#     steps/s, episodes/min of 600 steps, compile apart;
#  3. the same at 224 x 224 (B = 512);
#  4. the same at 64 x 64 with the segmenter in bfloat16, and experiments/seg_bf16_iou.py (the
#     shipped zucchini segmenter's IoU in float32 and bfloat16 on the same renders);
#  5. one Table 3 block (SegZeros on the learned segmenter, zucchini, 100 episodes) cold, then
#     warm; the whole Table 3 (15 blocks, one program per crop and controller) when the budget
#     is at least FULL_TABLE3 seconds (set FULL_TABLE3=0 to force it after the rest).
# Raw figures: $OUT/ttr.jsonl (one line per step: wall time, the command's own compile / run /
# write split, programs, cache hits), $OUT/closed_loop.jsonl (bench rows), $OUT/seg_bf16_iou.jsonl,
# logs $OUT/<step>.log. Ends with a short table of the figures. ONLY="step step ..." runs only
# the steps named (e.g. ONLY="closed_loop_64_bf16 seg_bf16_iou").
set -uo pipefail
out=${OUT:-/tmp/ttr_out}; mkdir -p "$out"
py=${PY:-python3}
budget=${BUDGET:-530}
smoke=${SMOKE:-0}
scale=${LIMIT_SCALE:-$([ "$smoke" = 1 ] && echo 5 || echo 1)}  # per-step limits x scale
work=${WORK:-/tmp/ttr_work}
cache="$work/cache"
rm -rf "$work"; mkdir -p "$work"
rm -f "$out/ttr.jsonl" "$out/closed_loop.jsonl" "$out/seg_bf16_iou.jsonl"
start=$(date +%s)
left() { echo $((budget - ($(date +%s) - start))); }

if [ "$smoke" = 1 ]; then  # tiny sizes, same commands
  sweep_flags=(--smoke); b64=(--batch 2 --image 16 --steps 10 --repeats 1)
  b224=(--batch 2 --image 32 --steps 10 --repeats 1); t3_eps=2; t3_flags=(--smoke)
  iou=(--n 8 --size 32)
else
  sweep_flags=(); b64=(--batch 1024 --image 64 --steps 150 --repeats 3)
  b224=(--batch 512 --image 224 --steps 150 --repeats 2); t3_eps=100; t3_flags=()
  iou=(--n 512 --size 64)
fi

{ command -v nvidia-smi >/dev/null && nvidia-smi --query-gpu=name,memory.total,driver_version \
    --format=csv,noheader; $py -c "import jax, mujoco; print('jax', jax.__version__, 'mujoco', \
mujoco.__version__, jax.devices())"; } 2>&1 | tee "$out/device.txt"

# step NAME MIN_LEFT MAX_S CMD...: run CMD (log $out/NAME.log) if MIN_LEFT seconds are left,
# for at most MAX_S seconds and what is left; one JSON line to $out/ttr.jsonl.
step() {
  local name=$1 need=$2 max=$3; shift 3
  if [ -n "${ONLY:-}" ] && [[ " $ONLY " != *" $name "* ]]; then return; fi
  local l; l=$(left)
  if [ "$l" -lt "$need" ]; then
    echo "== $name: skipped ($l s left, needs $need)"
    echo "{\"step\": \"$name\", \"skipped\": true, \"left_s\": $l}" >>"$out/ttr.jsonl"
    return
  fi
  max=$(( max * scale ))
  local limit=$(( max < l ? max : l ))
  echo "== $name ($(date +%T), $l s left, limit $limit s): $*"
  local t0; t0=$(date +%s.%N)
  timeout "$limit" "$@" >"$out/$name.log" 2>&1
  local rc=$?
  local t1; t1=$(date +%s.%N)
  $py - "$name" "$rc" "$t0" "$t1" "$out/$name.log" >>"$out/ttr.jsonl" <<'PY'
import json, re, sys
name, rc, t0, t1, log = sys.argv[1:]
rec = {"step": name, "rc": int(rc), "wall_s": round(float(t1) - float(t0), 2)}
text = open(log, errors="replace").read()
m = re.findall(r"time: ([\d.]+) s = (?:start-up ([\d.]+) s \+ )?compile ([\d.]+) s \(.*?; (\d+) XLA programs"
               r"(?:, cache (\d+) hits, (\d+) misses)?\) \+ run ([\d.]+) s \+ write ([\d.]+) s",
               text)
if m:
    tot, start, comp, progs, hits, misses, run, write = m[-1]
    rec.update(inside_s=float(tot), startup_s=float(start or 0), compile_s=float(comp),
               run_s=float(run),
               write_s=float(write), xla_programs=int(progs), cache_hits=int(hits or 0),
               cache_misses=int(misses or 0))
m = re.findall(r"(\d+) blocks, (\d+) closed-loop programs", text)
if m:
    rec.update(blocks=int(m[-1][0]), closed_loop_programs=int(m[-1][1]))
print(json.dumps(rec))
PY
  tail -n 3 "$out/$name.log"
  [ "$rc" = 0 ] || echo "!! $name: exit status $rc (log $out/$name.log)"
}

sweep=($py -m mjxrow.sweep sweeps.yaml "${sweep_flags[@]}" --no-progress --cache-dir "$cache")
step sweep_cold 60 300 "${sweep[@]}" --out "$work/sweep_cold"
step sweep_warm 20 120 "${sweep[@]}" --out "$work/sweep_warm"
cp "$work/sweep_warm/summary.csv" "$out/sweep_summary.csv" 2>/dev/null
# the same sweep in one call of 216 episodes, then also with the XLA renderer (render.kernel
# fused: no Pallas kernels to compile, and the traced program can be kept beside the cache)
one=(--set batch_size=216)
step sweep_b216_cold 60 300 "${sweep[@]/$cache/$work/cache_b216}" "${one[@]}" \
  --out "$work/sweep_b216_cold"
fused=("${sweep[@]/$cache/$work/cache_fused}" "${one[@]}" --set render.kernel=fused)
step sweep_fused_cold 60 300 "${fused[@]}" --out "$work/sweep_fused_cold"
step sweep_fused_warm 20 120 "${fused[@]}" --out "$work/sweep_fused_warm"

bench=($py -m mjxrow.bench closed_loop --out "$out/closed_loop.jsonl" --cache-dir "$cache")
step closed_loop_64 60 200 "${bench[@]}" "${b64[@]}"
step closed_loop_224 60 200 "${bench[@]}" "${b224[@]}"
step closed_loop_64_bf16 60 200 "${bench[@]}" "${b64[@]}" --seg-dtype bfloat16
step seg_bf16_iou 30 90 $py experiments/seg_bf16_iou.py "${iou[@]}" \
  --out "$out/seg_bf16_iou.jsonl"

t3=($py experiments/table3_navigation.py "${t3_flags[@]}" --episodes "$t3_eps" --no-progress
    --cache-dir "$cache" --doc "$work/table3.md")
step table3_block_cold 60 200 "${t3[@]}" --presets zucchini --controllers segzeros_learned \
  --out "$work/t3_cold"
step table3_block_warm 20 60 "${t3[@]}" --presets zucchini --controllers segzeros_learned \
  --out "$work/t3_warm"
step table3_whole_cold "${FULL_TABLE3:-420}" 600 "${t3[@]}" --out "$work/t3_whole" \
  --cache-dir "$work/cache_t3"

echo "== summary ($(( $(date +%s) - start )) s)"
$py - "$out" <<'PY'
import json, pathlib, sys
out = pathlib.Path(sys.argv[1])
def rows(name):
    p = out / name
    return [json.loads(l) for l in p.read_text().splitlines() if l.strip()] if p.exists() else []
def f(x, fmt="{:.1f}"):
    return "" if x is None else fmt.format(x)
print((out / "device.txt").read_text().strip().splitlines()[0])
print("\n| step | rc | wall [s] | start-up [s] | compile [s] | run [s] | write [s] | XLA programs |"
      " cache hits | closed-loop programs |\n|---|---|---|---|---|---|---|---|---|---|")
for r in rows("ttr.jsonl"):
    if r.get("skipped"):
        print(f"| {r['step']} | skipped ({r['left_s']} s left) | | | | | | | | |")
        continue
    print(f"| {r['step']} | {r['rc']} | {f(r['wall_s'])} | {f(r.get('startup_s'))} | "
          f"{f(r.get('compile_s'))} | "
          f"{f(r.get('run_s'))} | {f(r.get('write_s'))} | {r.get('xla_programs', '')} | "
          f"{r.get('cache_hits', '')} | {r.get('closed_loop_programs', '')} |")
print("\n| closed loop | B | control steps/s | episodes/min | compile [s] | median run [s] |"
      "\n|---|---|---|---|---|---|")
for r in rows("closed_loop.jsonl"):
    runs = sorted(r["runs_s"])
    print(f"| {r['config']} | {r['batch']} | {r['value']:,.0f} | {r['episodes_per_min']:,.0f} "
          f"| {r['compile_s']:.1f} | {runs[len(runs) // 2]:.3f} |")
print("\n| segmenter | images | IoU float32 | IoU bfloat16 | float32 vs bfloat16 |"
      "\n|---|---|---|---|---|")
for r in rows("seg_bf16_iou.jsonl"):
    print(f"| {r['crop']} {r['size']} px | {r['images']} | {r['iou_float32']:.4f} | "
          f"{r['iou_bfloat16']:.4f} | {r['iou_between']:.4f} |")
PY
du -sh "$cache" 2>/dev/null
