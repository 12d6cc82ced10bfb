"""The reports of `experiments/gpu.sh`: one JSON line per timed step, read from its log, and the
short tables that end a measurement set.

    python experiments/gpu_summary.py step NAME RC T0 T1 LOG [--with KEY=INT ...]
    python experiments/gpu_summary.py time_to_result OUT DEVICE_TXT
    python experiments/gpu_summary.py scaling OUT WORK DEVICE_TXT
    python experiments/gpu_summary.py surfaces WORK OUT
    python experiments/gpu_summary.py loop_224 ROWS_JSONL
    python experiments/gpu_summary.py sweep_row OUT T0 T1
"""

from __future__ import annotations

import argparse
import datetime
import json
import re
import subprocess
from pathlib import Path

# the `time:` line that a sweep, an episode batch or Table 3 prints at its end (stopwatch.Stopwatch)
TIME = re.compile(r"time: ([\d.]+) s = (?:start-up ([\d.]+) s \+ )?compile ([\d.]+) s \(.*?; "
                  r"(\d+) XLA programs(?:, cache (\d+) hits, (\d+) misses)?\) \+ run ([\d.]+) s "
                  r"\+ write ([\d.]+) s")
BLOCKS = re.compile(r"(\d+) blocks, (\d+) closed-loop programs")


def step(name: str, rc: int, t0: float, t1: float, log: Path, extra: dict) -> dict:
    """A step's record: exit status, wall time, and the command's own split where it printed one."""
    rec = {"step": name, **extra, "rc": rc, "wall_s": round(t1 - t0, 2)}
    text = log.read_text(errors="replace") if log.exists() else ""
    if m := TIME.findall(text):
        tot, start, comp, progs, hits, misses, run, write = m[-1]
        rec.update(inside_s=float(tot), startup_s=float(start or 0), compile_s=float(comp),
                   run_s=float(run), write_s=float(write), xla_programs=int(progs),
                   cache_hits=int(hits or 0), cache_misses=int(misses or 0))
    if m := BLOCKS.findall(text):
        rec.update(blocks=int(m[-1][0]), closed_loop_programs=int(m[-1][1]))
    return rec


def rows(path: Path) -> list[dict]:
    return [json.loads(line) for line in path.read_text().splitlines()
            if line.strip()] if path.exists() else []


def _f(x, fmt: str = "{:.1f}") -> str:
    return "" if x is None else fmt.format(x)


def time_to_result(out: Path, device: Path) -> None:
    print(device.read_text().strip().splitlines()[0] if device.exists() else "")
    print("\n| step | rc | wall [s] | start-up [s] | compile [s] | run [s] | write [s] | "
          "XLA programs | cache hits | closed-loop programs |\n" + "|---" * 10 + "|")
    for r in rows(out / "ttr.jsonl"):
        if r.get("skipped"):
            print(f"| {r['step']} | skipped ({r['left_s']} s left) | | | | | | | | |")
            continue
        print(f"| {r['step']} | {r['rc']} | {_f(r['wall_s'])} | {_f(r.get('startup_s'))} | "
              f"{_f(r.get('compile_s'))} | {_f(r.get('run_s'))} | {_f(r.get('write_s'))} | "
              f"{r.get('xla_programs', '')} | {r.get('cache_hits', '')} | "
              f"{r.get('closed_loop_programs', '')} |")
    print("\n| closed loop | B | control steps/s | episodes/min | compile [s] | median run [s] |"
          "\n|---|---|---|---|---|---|")
    for r in rows(out / "closed_loop.jsonl"):
        runs = sorted(r["runs_s"])
        print(f"| {r['config']} | {r['batch']} | {r['value']:,.0f} | {r['episodes_per_min']:,.0f} "
              f"| {r['compile_s']:.1f} | {runs[len(runs) // 2]:.3f} |")
    print("\n| segmenter | images | IoU float32 | IoU bfloat16 | float32 vs bfloat16 |"
          "\n|---|---|---|---|---|")
    for r in rows(out / "seg_bf16_iou.jsonl"):
        print(f"| {r['crop']} {r['size']} px | {r['images']} | {r['iou_float32']:.4f} | "
              f"{r['iou_bfloat16']:.4f} | {r['iou_between']:.4f} |")


def scaling(out: Path, work: Path, device: Path) -> None:
    import pandas as pd

    print(device.read_text().strip() if device.exists() else "")
    a, b = work / "sweep_1" / "summary.csv", work / "sweep_2" / "summary.csv"
    if a.exists() and b.exists():
        x, y = pd.read_csv(a), pd.read_csv(b)
        same = a.read_bytes() == b.read_bytes()
        print(f"\nsummary.csv on 1 and 2 GPUs: {'byte-identical' if same else 'different'}")
        if not same:
            for c in x.columns:
                if x[c].dtype.kind in "fi" and c in y:
                    d = (x[c] - y[c]).abs().max()
                    if d > 0:
                        print(f"  {c}: largest difference {d:.3g}")
        ra, rb = (pd.read_csv(work / f"sweep_{n}" / "results.csv") for n in (1, 2))
        num = [c for c in ra.columns if ra[c].dtype.kind in "fi" and c in rb]
        diff = (ra[num] - rb[num]).abs().max()
        print(f"results.csv ({len(ra)} episodes): {int((diff > 0).sum())} numeric columns differ"
              + (f", largest {diff.max():.3g} ({diff.idxmax()})" if (diff > 0).any() else ""))
    sweeps, bench = rows(out / "scaling.jsonl"), rows(out / "closed_loop.jsonl")
    nan = float("nan")
    print("\n| run | GPUs | wall [s] | compile [s] | run [s] | write [s] |\n" + "|---" * 6 + "|")
    for r in sweeps:
        print(f"| sweep | {r['gpus']} | {r['wall_s']:.1f} | {r.get('compile_s', nan):.1f} | "
              f"{r.get('run_s', nan):.1f} | {r.get('write_s', nan):.1f} |")
    print("\n| closed loop | GPUs | B | control steps/s | episodes/min | compile [s] |"
          "\n|---|---|---|---|---|---|")
    for r in bench:
        print(f"| {r['config']} | {r.get('devices', '?')} | {r['batch']} | {r['value']:,.0f} | "
              f"{r.get('episodes_per_min', nan):,.0f} | {r['compile_s']:.1f} |")
    sw = {r["gpus"]: r for r in sweeps if "run_s" in r}
    if 1 in sw and 2 in sw:
        print(f"\nsweep run-time speed-up on 2 GPUs: {sw[1]['run_s'] / sw[2]['run_s']:.2f}x "
              f"(wall {sw[1]['wall_s'] / sw[2]['wall_s']:.2f}x)")
    bd = {r.get("devices"): r for r in bench}
    if 1 in bd and 2 in bd:
        print(f"closed-loop speed-up on 2 GPUs: {bd[2]['value'] / bd[1]['value']:.2f}x")


def scale_out(out: Path, device: Path) -> None:
    """The scale-out table (gpu.sh scale_out) and its benchmarks rows (OUT/rows.jsonl): per
    batch per GPU, episodes per second of run time on n GPUs against one."""
    lines = device.read_text().strip().splitlines() if device.exists() else []
    name = lines[0].split(",")[0].strip() if lines else "?"
    runs = [r for r in rows(out / "scale_out.jsonl") if r.get("rc") == 0 and "run_s" in r]
    print(device.read_text().strip() if device.exists() else "")
    print("\n| episodes per GPU | GPUs | episodes | compile [s] | run [s] | episodes/s | "
          "vs 1 GPU |\n" + "|---" * 7 + "|")
    recs = []
    for r in sorted(runs, key=lambda r: (r["per_gpu"], r["gpus"])):
        base = next((b for b in runs if b["per_gpu"] == r["per_gpu"] and b["gpus"] == 1), None)
        rate = r["episodes"] / r["run_s"]
        ratio = rate / (base["episodes"] / base["run_s"]) if base else float("nan")
        print(f"| {r['per_gpu']} | {r['gpus']} | {r['episodes']} | {r['compile_s']:.1f} | "
              f"{r['run_s']:.1f} | {rate:.1f} | {ratio:.2f}x |")
        n = r["gpus"]
        recs.append({"date": datetime.date.today().isoformat(),
                     "device": name if n == 1 else f"{n} x {name}", "stage": "sweep_scaling",
                     "batch": r["episodes"], "per_gpu": r["per_gpu"], "gpus": n,
                     "unit": "episodes/s (run)", "value": round(rate, 2),
                     "speedup_vs_1gpu": None if base is None else round(ratio, 3),
                     "command": f"python -m mjxrow.sweep sweeps.yaml --set seeds="
                                f"{r['episodes'] // 36} --set batch_size={r['episodes']} --force "
                                "(CUDA_VISIBLE_DEVICES: n GPUs; bash experiments/gpu.sh "
                                "scale_out)",
                     "config": f"sweeps.yaml, one batch of {r['per_gpu']} episodes per GPU on "
                               f"{n} GPU(s), empty cache",
                     "compile_s": r["compile_s"], "run_s": r["run_s"], "wall_s": r["wall_s"]})
    (out / "rows.jsonl").write_text("".join(json.dumps(x) + "\n" for x in recs))


def surfaces(work: Path, out: Path) -> None:
    import pandas as pd

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
            lines += [f"\n### {surface}: {ctrl} (success per cell; rows {axes[1]}, columns "
                      f"{axes[0]})\n", t.round(2).to_string(),
                      f"\nmean success {t.values.mean():.3f}; cells under 0.95: "
                      f"{int((t.values < 0.95).sum())} of {t.size}"]
    text = "\n".join(lines)
    (out / "surfaces.md").write_text(text + "\n")
    print(text)


def loop_224(path: Path) -> None:
    print("\n| config | batch | control steps/s | episodes/min | first call [s] | runs [s] | "
          "compile [s] |\n|---|---|---|---|---|---|---|")
    for r in rows(path):
        print(f"| {r['config']} | {r['batch']} | {r['value']:,.0f} | "
              f"{r['episodes_per_min']:,.0f} | {r.get('first_run_s', 0):.2f} | "
              f"{', '.join(f'{x:.2f}' for x in r['runs_s'])} | {r['compile_s']:.1f} |")


def sweep_row(out: Path, t0: float, t1: float) -> None:
    """The default sweep's wall time as a benchmarks.jsonl row (OUT/benchmarks.jsonl)."""
    dev = subprocess.run(["nvidia-smi", "--query-gpu=name", "--format=csv,noheader"],
                         capture_output=True, text=True).stdout.strip().splitlines()[0]
    row = {"date": datetime.date.today().isoformat(), "device": dev, "stage": "closed_loop",
           "config": "python -m mjxrow.sweep sweeps.yaml (all cells, compile included)",
           "batch": 216, "value": t1 - t0, "unit": "s wall",
           "command": "python -m mjxrow.sweep sweeps.yaml --set batch_size=216"}
    with open(out / "benchmarks.jsonl", "a") as f:
        f.write(json.dumps(row) + "\n")
    print(f"sweeps.yaml wall time {t1 - t0:.1f} s")


def _extra(item: str) -> tuple[str, int]:
    key, sep, value = item.partition("=")
    if not sep or not value.lstrip("-").isdigit():
        raise argparse.ArgumentTypeError(f"--with {item}: expected KEY=INT")
    return key, int(value)


def main(argv: list[str] | None = None) -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    sub = ap.add_subparsers(dest="kind", required=True)
    p = sub.add_parser("step", help="one JSON line: exit status, wall time, the printed split")
    p.add_argument("name")
    p.add_argument("rc", type=int)
    p.add_argument("t0", type=float)
    p.add_argument("t1", type=float)
    p.add_argument("log", type=Path)
    p.add_argument("--with", dest="extra", type=_extra, action="append", default=[])
    p = sub.add_parser("time_to_result")
    p.add_argument("out", type=Path)
    p.add_argument("device", type=Path)
    p = sub.add_parser("scaling")
    p.add_argument("out", type=Path)
    p.add_argument("work", type=Path)
    p.add_argument("device", type=Path)
    p = sub.add_parser("scale_out")
    p.add_argument("out", type=Path)
    p.add_argument("device", type=Path)
    p = sub.add_parser("surfaces")
    p.add_argument("work", type=Path)
    p.add_argument("out", type=Path)
    p = sub.add_parser("loop_224")
    p.add_argument("rows", type=Path)
    p = sub.add_parser("sweep_row")
    p.add_argument("out", type=Path)
    p.add_argument("t0", type=float)
    p.add_argument("t1", type=float)
    a = ap.parse_args(argv)
    if a.kind == "step":
        print(json.dumps(step(a.name, a.rc, a.t0, a.t1, a.log, dict(a.extra))))
    elif a.kind == "time_to_result":
        time_to_result(a.out, a.device)
    elif a.kind == "scaling":
        scaling(a.out, a.work, a.device)
    elif a.kind == "scale_out":
        scale_out(a.out, a.device)
    elif a.kind == "surfaces":
        surfaces(a.work, a.out)
    elif a.kind == "loop_224":
        loop_224(a.rows)
    else:
        sweep_row(a.out, a.t0, a.t1)


if __name__ == "__main__":
    main()
