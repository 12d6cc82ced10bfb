"""Where the renderer's time goes: device time per stage of `render.render`, from a profiler trace.

    python experiments/profile_render.py [--preset zucchini] [--batch 1024] [--res 64 128]
                                         [--out runs/profile_render]

Renders B worlds as `python -m mjxrow.bench render` does (the dataset's fields, poses and
conditions), records `--calls` calls with `jax.profiler.trace`, and sums the device time of every
kernel by the renderer stage that issued it: the `rd_*` named scopes of `render.py` (setup, plant
table, terrain, obstacles, camera-tile culling, exact plant tests, deep tiles, plant normals,
shadow culling and tests; ops outside any scope are the shading and image assembly, "shade").
A kernel is attributed through the `op_name` of its fusion in the compiled HLO. Writes
`OUT/profile.json` (per resolution: wall time per call, per-stage device ms, top kernels) and
prints a table per resolution.
"""

from __future__ import annotations

import argparse
import collections
import dataclasses
import gzip
import json
import re
import sys
import tempfile
from pathlib import Path

import jax

from mjxrow import crops
from mjxrow import render as RD
from mjxrow.bench import render as BR
from mjxrow.bench.timing import time_call

SCOPE = re.compile(r"\brd_[a-z_]+")
FUSION = re.compile(r"^\s*(?:ROOT )?%?([\w.\-]+) = .*?metadata=\{[^}]*op_name=\"([^\"]*)\"",
                    re.MULTILINE)


def scope_of(op_name: str) -> str:
    """Innermost `rd_*` scope of an op_name path ('shade' when none)."""
    found = SCOPE.findall(op_name)
    return found[-1][3:] if found else "shade"


def op_names(hlo_text: str) -> dict[str, str]:
    """HLO instruction name → op_name of its metadata (compiled module text)."""
    return {m.group(1): m.group(2) for m in FUSION.finditer(hlo_text)}


def kernel_events(trace_dir: Path) -> list[dict]:
    """Complete events with an `hlo_op` from the device lanes of a perfetto trace (the lanes of
    the process with the most such time when no process is named as a GPU)."""
    files = sorted(trace_dir.rglob("*.trace.json.gz")) + sorted(trace_dir.rglob("*perfetto*"))
    if not files:
        raise FileNotFoundError(f"no trace file under {trace_dir}")
    data = json.load(gzip.open(files[0]))
    events = data["traceEvents"] if isinstance(data, dict) else data
    names = {e["pid"]: e["args"].get("name", "") for e in events
             if e.get("ph") == "M" and e.get("name") == "process_name"}
    hlo = [e for e in events if e.get("ph") == "X" and "hlo_op" in e.get("args", {})]
    gpu = {p for p, n in names.items() if "GPU" in n or "gpu" in n}
    if gpu:
        return [e for e in hlo if e["pid"] in gpu]
    total = collections.Counter()
    for e in hlo:
        total[e["pid"]] += e.get("dur", 0)
    if not total:
        return []
    pid = total.most_common(1)[0][0]
    return [e for e in hlo if e["pid"] == pid]


def profile(fn, inputs, calls: int) -> tuple[dict, list]:
    """Device ms per stage and per kernel, averaged over `calls` profiled calls."""
    hlo_text = fn.lower(*inputs).compile().as_text()
    names = op_names(hlo_text)
    with tempfile.TemporaryDirectory() as tmp:
        with jax.profiler.trace(tmp, create_perfetto_trace=True):
            for _ in range(calls):
                jax.block_until_ready(fn(*inputs))
        events = kernel_events(Path(tmp))
    by_stage, by_kernel = collections.Counter(), collections.Counter()
    for e in events:
        op = e["args"]["hlo_op"]
        ms = e.get("dur", 0) / 1e3 / calls
        by_stage[scope_of(names.get(op, ""))] += ms
        by_kernel[(op, names.get(op, "")[-120:])] += ms
    return dict(by_stage.most_common()), by_kernel.most_common(25)


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--preset", default="zucchini", choices=crops.names())
    p.add_argument("--batch", type=int, default=1024)
    p.add_argument("--res", type=int, nargs="+", default=[64, 128])
    p.add_argument("--tile", type=int, default=RD.DEFAULT_CONFIG.tile)
    p.add_argument("--set", action="append", default=[], metavar="KEY=VALUE",
                   help="a RenderConfig field, e.g. --set terrain_steps=16 (repeatable)")
    p.add_argument("--calls", type=int, default=3, help="profiled calls (after the timed ones)")
    p.add_argument("--out", default="runs/profile_render")
    args = p.parse_args(argv)
    if args.batch < 1:
        p.error(f"--batch: must be positive, got {args.batch}")
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    shape, fields, pos, rot, conds = BR.worlds(args.preset, args.batch)
    inputs = (fields, pos, rot, conds)
    try:
        cfg = dataclasses.replace(RD.RenderConfig(tile=args.tile), **BR.parse_sets(args.set))
    except ValueError as e:
        p.error(str(e))
    result = {"preset": args.preset, "batch": args.batch, "device": str(jax.devices()[0]),
              "command": "python experiments/profile_render.py " + " ".join(argv or sys.argv[1:]),
              "res": {}}
    for res in args.res:
        intr = RD.Intrinsics(res, res)
        fn = BR.batched_render(shape, intr, cfg, args.batch, args.batch)
        timing = time_call(fn, *inputs, repeats=5)
        compile_s, wall = timing["compile_s"], timing["median_s"]
        stages, kernels = profile(fn, inputs, args.calls)
        result["res"][res] = {"compile_s": compile_s, "wall_ms": wall * 1e3,
                              "frames_per_s": args.batch / wall, "stages_ms": stages,
                              "kernels_ms": [[k[0], k[1], v] for k, v in kernels]}
        (out / "profile.json").write_text(json.dumps(result, indent=1))
        used = RD.resolve(cfg, shape.crop, intr)
        print(f"\n{args.preset} {res}x{res}, B={args.batch}, tile {used.tile}, {used.kernel} "
              f"{' '.join(args.set)}: compile "
              f"{compile_s:.1f} s, wall {wall * 1e3:.1f} ms/call ({args.batch / wall:,.0f} "
              f"frames/s), device {sum(stages.values()):.1f} ms/call")
        print("| stage | device ms | share |\n|---|---|---|")
        tot = sum(stages.values()) or 1.0
        for k, v in stages.items():
            print(f"| {k} | {v:.2f} | {v / tot:.0%} |")
        print("top kernels:")
        for (op, name), v in kernels[:12]:
            print(f"  {v:7.2f} ms  {op:28s} {name}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
