"""Closed-loop control steps per second: render → segment → SegZeros → physics for B worlds.

One control step = one rendered frame, one segmenter call, one controller call and the physics
substeps of a control period (7 at 15 Hz). Uses the episode CLI's own set-up, so the measured
program is the one `python -m mjxrow.episode` and the sweep run.
"""

from __future__ import annotations

import argparse
import time

import jax
import jax.numpy as jnp
import numpy as np

from mjxrow import field as F
from mjxrow.physics import sim
from mjxrow.rollout import episode as E


def add_args(p: argparse.ArgumentParser) -> None:
    p.add_argument("--preset", default="zucchini", choices=F.CROPS)
    p.add_argument("--batch", type=int, nargs="+", default=[256, 1024])
    p.add_argument("--image", type=int, default=64, help="camera image side [px]")
    p.add_argument("--steps", type=int, default=150, help="control steps per episode")
    p.add_argument("--perception", default="learned", choices=("learned", "ground_truth"))
    p.add_argument("--controller", default="segzeros", choices=("segzeros", "segmin", "oracle"))
    p.add_argument("--repeats", type=int, default=3)


def run(args: argparse.Namespace) -> list[dict]:
    rows = []
    for b in args.batch:
        ep_args = E._parser().parse_args([
            "--preset", args.preset, "--controller", args.controller, "--n", str(b),
            "--out", "unused", "--perception", args.perception,
            "--image", f"{args.image}x{args.image}", "--steps", str(args.steps), "--no-progress"])
        params = jax.tree.map(lambda x, b=b: jnp.broadcast_to(x, (b,)),
                              F.make_params(args.preset))
        shape = F.fit_shape(params, args.preset)
        cfg = E.EpisodeConfig(crop=args.preset, n_steps=args.steps, sim=sim.SimConfig())
        policy, pparams, axes = E.make_policy(args.controller, shape, ep_args)
        keys = jax.random.split(jax.random.key(0), 2 * b).reshape(b, 2)
        fields = jax.jit(jax.vmap(F.generate, in_axes=(0, None, 0)), static_argnums=1)(
            params, shape, keys[:, 0])
        _, mx = sim.make_model(shape, cfg.sim)
        call_args = E.rollout_args(mx, fields, None, keys[:, 1], pparams, axes,
                                   sim.pose_noise(0.0, 0.0))
        t0 = time.perf_counter()
        exe = E.compiled(policy, cfg, axes).lower(*call_args).compile()
        compile_s = time.perf_counter() - t0
        runs = []
        for _ in range(args.repeats):
            t0 = time.perf_counter()
            log = jax.block_until_ready(exe(*call_args))
            runs.append(time.perf_counter() - t0)
        med = float(np.median(runs))
        summary = E.summarise(log, cfg)
        config = (f"{args.preset}, {args.controller} on {args.perception} masks, "
                  f"{args.image}x{args.image} px, {args.steps} control steps")
        print(f"B={b}: {b * args.steps / med:,.0f} control steps/s (compile {compile_s:.1f} s, "
              f"median run {med:.2f} s), alive at end {int(np.sum(np.asarray(log.alive[:, -1])))}"
              f", success {float(np.mean(np.asarray(summary['success']))):.2f}")
        rows.append({"stage": "closed_loop", "config": config, "batch": b,
                     "value": b * args.steps / med, "unit": "control steps/s",
                     "compile_s": compile_s, "runs_s": runs})
    return rows
