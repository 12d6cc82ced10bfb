"""Where a training step's time goes: the training environment of one preset at batch B (the
trainer's wrappers: episode, vmap, auto-reset), its parts timed as separate programs:

    python experiments/env_parts.py [--batch 2048] [--preset zucchini] [--repeats 5]
        [--record FILE.jsonl]

- `advance`: physics, end events, reward and the episode's log (every world, no frame);
- `observe`: the camera frame, the teacher's action and the observation;
- `render`: the frame alone (no sensor noise);
- `step`: the auto-reset step (advance, the resets of the worlds that ended, observe), with zero
  actions from the first state (no world ends, so no reset pass runs).

Each is timed by `mjxrow.bench.timing.time_call`: the first call (compiling) apart, then the
median of `--repeats` calls; env-steps/s is B over it. Run it with `MJXROW_NONDETERMINISTIC=1`
to time the same programs without XLA's deterministic ops.
`--record` appends one row per part (stage `env_parts`) in benchmarks.jsonl's form.
"""

from __future__ import annotations

import argparse
import datetime
import json
import os
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))  # run from a checkout, uninstalled


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(prog="python experiments/env_parts.py",
                                description=__doc__.split("\n")[0])
    p.add_argument("--batch", type=int, default=2048)
    p.add_argument("--preset", default="zucchini")
    p.add_argument("--repeats", type=int, default=5)
    p.add_argument("--record", type=Path, default=None)
    args = p.parse_args(argv)
    if args.batch < 1 or args.repeats < 1:
        print("error: --batch and --repeats must be ≥ 1", file=sys.stderr)
        return 2
    import jax
    import jax.numpy as jnp

    from mjxrow import crops
    from mjxrow.bench.timing import time_call
    from mjxrow.train import loop

    if args.preset not in crops.names():
        print(f"error: --preset: {args.preset!r} is not one of {', '.join(crops.names())}",
              file=sys.stderr)
        return 2
    B = args.batch
    raw, wrapped = loop.make_envs(loop.TrainConfig(presets=(args.preset,), num_envs=B))
    env, e = wrapped[0], raw[0]
    vm = env.env
    st = jax.jit(env.reset)(jax.random.key(0))
    a = jnp.zeros((B, 2))
    parts = {
        "advance": (jax.jit(vm.advance), (st, a)),
        "observe": (jax.jit(vm.observe), (st,)),
        "render": (jax.jit(lambda s: jax.vmap(lambda d: e.frame(d, d.sim, None))(s.data)), (st,)),
        "step": (jax.jit(env.step), (st, a)),
    }
    det = not os.environ.get("MJXROW_NONDETERMINISTIC")
    rows = []
    for name, (fn, fargs) in parts.items():
        t = time_call(fn, *fargs, repeats=args.repeats)
        med = t["median_s"]
        rows.append({"date": datetime.date.today().isoformat(),
                     "device": jax.devices()[0].device_kind, "stage": "env_parts",
                     "config": f"training env, {args.preset}, {name}, deterministic ops "
                               f"{'on' if det else 'off'}", "batch": B,
                     "value": B / med, "unit": "env-steps/s", "run_ms": 1e3 * med,
                     "compile_s": t["compile_s"], "runs_s": t["runs_s"],
                     "command": "python experiments/env_parts.py " + " ".join(sys.argv[1:])})
        print(f"{name:8s} first call {rows[-1]['compile_s']:6.1f} s  run {1e3 * med:8.2f} ms  "
              f"{B / med:10,.0f} env-steps/s", flush=True)
    if args.record is not None:
        with args.record.open("a") as f:
            for r in rows:
                f.write(json.dumps(r) + "\n")
    return 0


if __name__ == "__main__":
    sys.exit(main())
