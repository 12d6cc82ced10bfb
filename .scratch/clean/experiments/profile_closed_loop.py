"""Where a closed-loop control step's time goes: device time per stage, from a profiler trace.

    python experiments/profile_closed_loop.py [--preset zucchini] [--batch 216 1024]
        [--image 64] [--steps 50] [--set render.kernel=fused] [--out runs/profile_loop]

Builds the closed-loop program of `python -m mjxrow.bench closed_loop` (SegZeros on the
learned segmenter unless `--set` says otherwise; `--steps` control steps per call), times
`--repeats` calls, records `--calls` more with `jax.profiler.trace` and sums the device time of
every kernel by the stage that issued it: the renderer (`rd_*` scopes, or `cl_render`), the
segmenter (`cl_segment`), the rest of the policy (`cl_policy`: the controller), the physics
(`cl_physics`), the end checks (`cl_events`), and "loop" for what lies outside them (start-up,
selects, the per-step records). Also the kernels per control step and the device's busy share
of the wall time: a low share means the step waits on kernel launches, not on the GPU's work.
Writes OUT/profile.json and prints a table per batch size.
"""

from __future__ import annotations

import argparse
import collections
import json
import re
import statistics
import sys
import tempfile
import time
from pathlib import Path

import jax

from mjxrow import crops
from mjxrow.bench import closed_loop as CL
from mjxrow.rollout import build as B

sys.path.insert(0, str(Path(__file__).resolve().parent))
from profile_render import kernel_events, op_names  # noqa: E402

STAGES = (("render", re.compile(r"\brd_[a-z_]+|\bcl_render\b")),
          ("segment", re.compile(r"\bcl_segment\b")), ("policy", re.compile(r"\bcl_policy\b")),
          ("physics", re.compile(r"\bcl_physics\b")), ("events", re.compile(r"\bcl_events\b")))
CONTAINER = re.compile(r"^(while|conditional|call|async)[\w.-]*$")


def stage_of(op_name: str) -> str:
    """The stage of a kernel's op_name: the first of STAGES whose scope it lies in."""
    for name, pattern in STAGES:
        if pattern.search(op_name):
            return name
    return "loop"


def profile(built: B.Built, cfg, b: int, repeats: int, calls: int) -> dict:
    batch = built.batch([(cfg, e) for e in range(b)])
    args = batch.args(built.mx)
    t0 = time.perf_counter()
    exe = built.compiled().lower(*args).compile()
    compile_s = time.perf_counter() - t0
    names = op_names(exe.as_text())
    jax.block_until_ready(exe(*args))
    runs = []
    for _ in range(repeats):
        t0 = time.perf_counter()
        jax.block_until_ready(exe(*args))
        runs.append(time.perf_counter() - t0)
    with tempfile.TemporaryDirectory() as tmp:
        with jax.profiler.trace(tmp, create_perfetto_trace=True):
            for _ in range(calls):
                jax.block_until_ready(exe(*args))
        # loops and calls hold other kernels (the CPU's trace has them too): leaves only
        events = [e for e in kernel_events(Path(tmp))
                  if not CONTAINER.match(e["args"]["hlo_op"])]
    steps = built.episode.n_steps
    by_stage, by_kernel = collections.Counter(), collections.Counter()
    for e in events:
        op = e["args"]["hlo_op"]
        ms = e.get("dur", 0) / 1e3 / calls / steps
        by_stage[stage_of(names.get(op, ""))] += ms
        by_kernel[(op, names.get(op, "")[-110:])] += ms
    wall = statistics.median(runs)
    busy = sum(by_stage.values())
    return {"batch": b, "steps": steps, "compile_s": compile_s,
            "wall_ms_per_step": wall / steps * 1e3, "device_ms_per_step": busy,
            "busy_share": busy / (wall / steps * 1e3), "control_steps_s": b * steps / wall,
            "kernels_per_step": len(events) / calls / steps,
            "stages_ms_per_step": dict(by_stage.most_common()),
            "kernels_ms_per_step": [[k[0], k[1], v] for k, v in by_kernel.most_common(20)]}


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--preset", default="zucchini", choices=crops.names())
    p.add_argument("--batch", type=int, nargs="+", default=[216, 1024])
    p.add_argument("--image", type=int, default=64)
    p.add_argument("--steps", type=int, default=50, help="control steps per call")
    p.add_argument("--set", action="append", default=[], metavar="KEY=VALUE",
                   help="a key of the sweep YAML, e.g. --set render.kernel=fused")
    p.add_argument("--repeats", type=int, default=3, help="timed calls")
    p.add_argument("--calls", type=int, default=2, help="profiled calls (after the timed ones)")
    p.add_argument("--out", default="runs/profile_loop")
    args = p.parse_args(argv)
    if min(args.batch) < 1 or args.steps < 1:
        p.error("--batch and --steps must be positive")
    cl_args = argparse.Namespace(preset=args.preset, controller="segzeros",
                                 perception="learned", image=args.image, steps=args.steps,
                                 set=args.set)
    cfg = CL.run_config(cl_args)
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    result = {"device": str(jax.devices()[0]), "preset": args.preset, "image": args.image,
              "command": "python experiments/profile_closed_loop.py "
                         + " ".join(argv if argv is not None else sys.argv[1:]), "runs": []}
    for b in args.batch:
        built = B.build(cfg)
        r = profile(built, cfg, built.padded(b), args.repeats, args.calls)
        result["runs"].append(r)
        (out / "profile.json").write_text(json.dumps(result, indent=1))
        print(f"\n{args.preset} {args.image}x{args.image}, B={r['batch']} {' '.join(args.set)}: "
              f"{r['control_steps_s']:,.0f} control steps/s, wall {r['wall_ms_per_step']:.2f} "
              f"ms/step, device busy {r['device_ms_per_step']:.2f} ms/step "
              f"({r['busy_share']:.0%}), {r['kernels_per_step']:.0f} kernels/step, compile "
              f"{r['compile_s']:.1f} s")
        print("| stage | device ms/step | share |\n|---|---|---|")
        tot = r["device_ms_per_step"] or 1.0
        for k, v in r["stages_ms_per_step"].items():
            print(f"| {k} | {v:.3f} | {v / tot:.0%} |")
        print("top kernels (ms/step):")
        for op, name, v in r["kernels_ms_per_step"][:12]:
            print(f"  {v:7.3f}  {op:28s} {name}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
