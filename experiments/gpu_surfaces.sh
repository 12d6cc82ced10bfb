#!/usr/bin/env bash
# The navigation surfaces of the learned policy beside SegZeros and the oracle, in one GPU
# command: the default d_rr x |ΔH| sweep (sweeps.yaml) and the lateral slope x |ΔH| sweep
# (sweeps/slope_roughness.yaml), each with SegZeros on the learned segmenter, the shipped
# policy (sweeps/policy*.yaml) and the oracle (--set controller.name=oracle). The six sweeps
# run side by side (their compilations overlap on the host's cores). Run from the project root
# (mujoco importable, e.g. PYTHONPATH=/tmp/site:$PWD):
#
#   OUT=DIR bash experiments/gpu_surfaces.sh            # default OUT=/tmp/surfaces_out
#   SMOKE=1 OUT=DIR bash experiments/gpu_surfaces.sh    # --smoke sweeps: checks the script
#
# OUT receives surfaces.tgz (each sweep's summary.csv, results.csv, report.md, heatmaps and
# log) and surfaces.md (success per cell, the three controllers side by side).
set -uo pipefail
out=${OUT:-/tmp/surfaces_out}; mkdir -p "$out"
py=${PY:-python3}
work=${WORK:-/tmp/surfaces_work}
limit=${LIMIT:-520}
rm -rf "$work"; mkdir -p "$work"
flags=(--no-progress --cache-dir "$work/cache")
[ "${SMOKE:-0}" = 1 ] && flags+=(--smoke)

declare -A runs=(
  [drr_segzeros]="sweeps.yaml"
  [drr_policy]="sweeps/policy.yaml"
  [drr_oracle]="sweeps.yaml --set controller.name=oracle"
  [slope_segzeros]="sweeps/slope_roughness.yaml"
  [slope_policy]="sweeps/policy_slope_roughness.yaml"
  [slope_oracle]="sweeps/slope_roughness.yaml --set controller.name=oracle"
)
# the sweeps share the GPU: each may take a sixth of its memory (JAX takes 75 % by default)
export XLA_PYTHON_CLIENT_MEM_FRACTION=${XLA_PYTHON_CLIENT_MEM_FRACTION:-0.15}
for name in "${!runs[@]}"; do
  # shellcheck disable=SC2086
  timeout "$limit" $py -m mjxrow.sweep ${runs[$name]} "${flags[@]}" --out "$work/$name" \
    >"$work/$name.log" 2>&1 &
done
wait
for name in "${!runs[@]}"; do echo "== $name"; tail -n 2 "$work/$name.log"; done

$py - "$work" "$out" <<'PY'
import pathlib, sys
import pandas as pd
work, out = map(pathlib.Path, sys.argv[1:])
lines = []
for surface, axes in (("drr", ("field.d_rr", "field.terrain_dh")),
                      ("slope", ("field.slope_y", "field.terrain_dh"))):
    tables = {}
    for ctrl in ("segzeros", "policy", "oracle"):
        p = work / f"{surface}_{ctrl}" / "summary.csv"
        if not p.exists():
            lines.append(f"{surface} {ctrl}: no summary.csv (see its log)")
            continue
        s = pd.read_csv(p)
        tables[ctrl] = s.pivot_table(index=axes[1], columns=axes[0], values="success")
    for ctrl, t in tables.items():
        cells = t.size
        lines += [f"\n### {surface}: {ctrl} (success per cell; rows {axes[1]}, columns {axes[0]})\n",
                  t.round(2).to_string(),
                  f"\nmean success {t.values.mean():.3f}; cells under 0.95: "
                  f"{int((t.values < 0.95).sum())} of {cells}"]
text = "\n".join(lines)
(out / "surfaces.md").write_text(text + "\n")
print(text)
PY
tar -czf "$out/surfaces.tgz" -C "$work" --exclude=cache --exclude=cells \
  $(cd "$work" && ls -d drr_* slope_* 2>/dev/null)
