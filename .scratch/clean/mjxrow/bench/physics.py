"""Physics-only environment steps per second: jit(vmap(scan(sim.step))) over B worlds of a preset.

Every world is its own field (own terrain, obstacles, lane; one key each) written into the one
MJX model of the shape (sim.world_model, batched with sim.model_axes). Each world drives a
constant command (v = 0.5 m/s, ω drawn in ±0.3 rad/s) for `--steps` control periods; an
env-step is one PHYSICS step of one world, so the figure is B · steps · substeps / run time
(control steps per second are reported beside it). Compile time (first call) is reported apart
from the median of `--repeats` further calls. Worlds that went bad (NaN / exploded) are counted.

GPU default: --batch 256 1024 4096; a small CPU run: --batch 16 --steps 20 --repeats 3.
"""

from __future__ import annotations

import argparse
import dataclasses

import jax
import jax.numpy as jnp

from mjxrow import crops, field
from mjxrow.bench.timing import time_call
from mjxrow.physics import sim as physics_sim


def add_args(p: argparse.ArgumentParser) -> None:
    p.add_argument("--preset", default="pear", choices=crops.names())
    p.add_argument("--batch", type=int, nargs="+", default=[256, 1024, 4096])
    p.add_argument("--steps", type=int, default=100, help="control periods per call")
    p.add_argument("--repeats", type=int, default=5)
    p.add_argument("--seed", type=int, default=0)
    for f in dataclasses.fields(physics_sim.SimConfig):
        if f.type in ("int", "float"):
            p.add_argument("--" + f.name.replace("_", "-"), type=int if f.type == "int" else float,
                           default=f.default, help=f"SimConfig.{f.name} (default {f.default})")
    p.add_argument("--chassis-contacts", action="store_true", help="SimConfig.chassis_contacts")


def sim_config(args: argparse.Namespace) -> physics_sim.SimConfig:
    kw = {f.name: getattr(args, f.name) for f in dataclasses.fields(physics_sim.SimConfig)
          if hasattr(args, f.name)}
    return physics_sim.SimConfig(**kw)


def make_worlds(preset: str, batch: int, cfg: physics_sim.SimConfig, seed: int = 0):
    """(mjx world models [B], initial SimStates [B], commands float32 [B, 2], model axes,
    shape) for `batch` fields of `preset`, one PRNG key each."""
    params = jax.tree.map(lambda x: jnp.broadcast_to(x, (batch,)), field.make_params(preset))
    shape = field.fit_shape(params, preset)
    _, mx = physics_sim.make_model(shape, cfg)
    axes = physics_sim.model_axes(mx)
    k_field, k_reset, k_cmd = jax.random.split(jax.random.key(seed), 3)

    def world(p, kf, kr):
        fld = field.generate(p, shape, kf)
        lane = field.robot_lane(fld)
        mw = physics_sim.world_model(mx, fld, lane, cfg)
        return mw, physics_sim.reset(mw, fld, lane, kr, cfg, physics_sim.pose_noise(0.05, 0.05))

    build = jax.jit(jax.vmap(world, out_axes=(axes, 0)))
    mws, states = build(params, jax.random.split(k_field, batch), jax.random.split(k_reset, batch))
    omega = jax.random.uniform(k_cmd, (batch,), minval=-0.3, maxval=0.3)
    cmds = jnp.stack([jnp.full((batch,), 0.5), omega], -1)
    return mws, states, cmds, axes, shape


def rollout_fn(cfg: physics_sim.SimConfig, axes, steps: int):
    """jit(vmap(scan(step))): (models [B], states [B], cmds [B, 2]) → (final states, bad [B])."""

    def one(mw, state, cmd):
        def body(s, _):
            return physics_sim.step(mw, s, cmd, cfg), None

        state, _ = jax.lax.scan(body, state, None, length=steps)
        return state, physics_sim.is_bad(state, cfg)

    return jax.jit(jax.vmap(one, in_axes=(axes, 0, 0)))


def run(args: argparse.Namespace) -> list[dict]:
    cfg = sim_config(args)
    rows = []
    for b in args.batch:
        mws, states, cmds, axes, shape = make_worlds(args.preset, b, cfg, args.seed)
        fn = rollout_fn(cfg, axes, args.steps)
        t = time_call(fn, mws, states, cmds, repeats=args.repeats)
        _, bad = fn(mws, states, cmds)
        physics = b * args.steps * cfg.substeps / t["median_s"]
        control = b * args.steps / t["median_s"]
        ny, nx = cfg.patch_cells
        config = (f"{args.preset}, {args.steps}x{cfg.substeps} steps of "
                  f"{cfg.physics_dt * 1e3:.2f} ms, hfield {ny}x{nx}, "
                  f"{min(cfg.obstacle_slots, shape.obstacle_slots)} obstacle contact slots, "
                  f"iterations {cfg.iterations}/{cfg.ls_iterations}")
        row = {"stage": "physics", "config": config, "batch": b, "value": physics,
               "unit": "env-steps/s", "control_steps_per_s": control,
               "compile_s": t["compile_s"], "runs_s": t["runs_s"],
               "bad_worlds": int(jnp.sum(bad))}
        print(f"B={b}: {physics:,.0f} physics env-steps/s, {control:,.0f} control steps/s, "
              f"compile {t['compile_s']:.1f} s, median run {t['median_s']:.3f} s, "
              f"bad worlds {row['bad_worlds']}/{b}")
        rows.append(row)
    return rows
