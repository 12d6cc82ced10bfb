"""Fields generated per second: one jit(vmap(generate)) call over B fields of a preset."""

from __future__ import annotations

import argparse

import jax

from mjxrow import crops, field
from mjxrow.bench.timing import time_call
from mjxrow.rollout import build as rollout_build


def add_args(p: argparse.ArgumentParser) -> None:
    p.add_argument("--preset", default="zucchini", choices=crops.names())
    p.add_argument("--batch", type=int, nargs="+", default=[1024])
    p.add_argument("--repeats", type=int, default=5)


def run(args: argparse.Namespace) -> list[dict]:
    shape = field.preset_shape(args.preset)
    gen = rollout_build.generate_fn()
    rows = []
    for b in args.batch:
        params = jax.tree.map(lambda x, b=b: jax.numpy.broadcast_to(x, (b,)),
                              field.make_params(args.preset))
        keys = jax.random.split(jax.random.key(0), b)
        t = time_call(lambda p, k: gen(p, shape, k), params, keys, repeats=args.repeats)
        config = f"{args.preset} {shape.max_rows}x{shape.max_plants_per_row} plants, " \
                 f"terrain {shape.terrain_cells[0]}x{shape.terrain_cells[1]}"
        rows.append({"stage": "fields", "config": config, "batch": b,
                     "value": b / t["median_s"], "unit": "fields/s",
                     "compile_s": t["compile_s"], "runs_s": t["runs_s"]})
    return rows
