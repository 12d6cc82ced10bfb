"""Camera frames rendered per second: one jit(vmap(render)) call over B worlds, each with its own
field (the preset varied as in the dataset), camera pose and lighting condition."""

from __future__ import annotations

import argparse
import dataclasses

import jax
import jax.numpy as jnp
import yaml

from mjxrow import crops, field
from mjxrow import render as mjxrow_render
from mjxrow.bench.timing import time_call
from mjxrow.seg import synthesis as seg_synth

MAX_RAYS = 1 << 24  # rays per vmapped chunk when --chunk is 0 (bounds the [rays, ...] buffers)


def add_args(p: argparse.ArgumentParser) -> None:
    p.add_argument("--preset", default="zucchini", choices=crops.names())
    p.add_argument("--batch", type=int, nargs="+", default=[1024], help="worlds per call")
    p.add_argument("--res", type=int, nargs="+", default=[64, 128, 224],
                   help="square image sides [px]")
    p.add_argument("--repeats", type=int, default=5)
    p.add_argument("--no-shadows", action="store_true", help="skip the shadow rays")
    p.add_argument("--tile", type=int, default=mjxrow_render.DEFAULT_CONFIG.tile,
                   help="tile side [px] of the renderer's culling (default: by resolution, "
                        "8 at 64 px, 16 from 128)")
    p.add_argument("--table", action="store_true",
                   help="plant tables computed outside the timed call (as an episode does once "
                        "per field)")
    p.add_argument("--set", action="append", default=[], metavar="KEY=VALUE",
                   help="a RenderConfig field, e.g. --set terrain_steps=16 (repeatable)")
    p.add_argument("--chunk", type=int, default=0,
                   help="frames per vmapped chunk (lax.map over chunks); 0: as many as keep "
                        f"the rays per chunk at most {MAX_RAYS}")


def parse_sets(items: list[str]) -> dict:
    """`KEY=VALUE` overrides of RenderConfig fields, values read as YAML scalars (numbers,
    true/false, null); an unknown key, a missing `=` or another value raises ValueError naming
    it."""
    names = {f.name for f in dataclasses.fields(mjxrow_render.RenderConfig)}
    out = {}
    for item in items:
        key, sep, val = item.partition("=")
        if not sep or key not in names:
            raise ValueError(f"--set {item!r}: expected KEY=VALUE with KEY one of "
                             f"{sorted(names)}")
        v = yaml.safe_load(val)
        choices = mjxrow_render.RenderConfig.CHOICES.get(key)
        if choices and v not in choices + (None,):
            raise ValueError(f"--set {item!r}: expected one of {', '.join(choices)} or null")
        if not choices and v is not None and not isinstance(v, (bool, int, float)):
            raise ValueError(f"--set {item!r}: {val!r} is not a number, true, false or null")
        out[key] = v
    return out


def render_config(args: argparse.Namespace) -> mjxrow_render.RenderConfig:
    """RenderConfig of the command line (--no-shadows, --tile, --set)."""
    return dataclasses.replace(
        mjxrow_render.RenderConfig(shadows=not args.no_shadows, tile=args.tile),
        **parse_sets(args.set),
    )


def worlds(preset: str, b: int, seed: int = 0, variety: str = "fields"):
    """B fields, camera poses (the dataset's sampler) and conditions (the four in turn).
    variety: the dataset's ("fields": curved rows, gap runs and weeds in a share of them) or
    "none" (straight rows, no weeds: the fields the render benchmark has always timed)."""
    shape = seg_synth.dataset_shape(preset, variety)
    keys = jax.random.split(jax.random.key(seed), 4 * b).reshape(b, 4)

    def one(k):
        fld = field.generate(seg_synth.random_params(preset, k[0], variety), shape, k[1])
        pos, rot, _ = seg_synth.sample_pose(fld, k[2])
        return fld, pos, rot

    fields, pos, rot = jax.jit(jax.vmap(one))(keys)
    conds = jax.vmap(mjxrow_render.condition_by_index)(
        jnp.arange(b) % len(mjxrow_render.CONDITIONS), keys[:, 3]
    )
    return shape, fields, pos, rot, conds


def auto_chunk(res: int, b: int, chunk: int = 0) -> int:
    """Frames per vmapped chunk: `chunk`, or (0) the largest power of two keeping the rays of a
    chunk of res × res images at most MAX_RAYS; never more than the batch `b`."""
    return min(b, chunk or max(1, 1 << ((MAX_RAYS // (res * res)).bit_length() - 1)))


def batched_render(
    shape: field.FieldShape,
    intr: mjxrow_render.Intrinsics,
    cfg: mjxrow_render.RenderConfig,
    b: int,
    chunk: int,
    shared_field: bool = False,
):
    """jit of render over [B] worlds: one vmap, or lax.map over chunks of `chunk` frames.
    Arguments (fields, pos, rot, conds) or, with plant tables, (fields, pos, rot, conds,
    tables). With `shared_field`, `fields` is ONE field that every world renders (vmap in_axes
    None: what depends on the field alone, e.g. its plant table, is computed once per call)."""
    def one(f, x):
        p, r, c, *tab = x
        return mjxrow_render.render(f, shape, p, r, intr, c, cfg=cfg, table=tab[0] if tab else None)

    def frames(f, *x):
        if shared_field:
            per, xs = (lambda y: one(f, y)), x
        else:
            per, xs = (lambda y: one(y[0], y[1:])), (f, *x)
        if chunk >= b:
            return jax.vmap(lambda *y: per(y))(*xs)
        return jax.lax.map(per, xs, batch_size=chunk)

    return jax.jit(frames)


def run(args: argparse.Namespace) -> list[dict]:
    try:
        cfg = render_config(args)
    except ValueError as e:
        raise SystemExit(f"bench render: {e}") from None
    rows = []
    for b in args.batch:
        # straight rows without weeds, as every earlier figure (comparable across rounds)
        shape, fields, pos, rot, conds = worlds(args.preset, b, variety="none")
        inputs = (fields, pos, rot, conds)
        if args.table:
            tables = jax.jit(
                jax.vmap(mjxrow_render.plant_table, in_axes=(0, None)), static_argnums=1
            )
            inputs += (tables(fields, shape),)
        for res in args.res:
            intr = mjxrow_render.Intrinsics(res, res)
            chunk = auto_chunk(res, b, args.chunk)
            fn = batched_render(shape, intr, cfg, b, chunk)
            t = time_call(fn, *inputs, repeats=args.repeats)
            used = mjxrow_render.resolve(cfg, shape.crop, intr)
            config = (f"{args.preset} {res}x{res}, fovy {intr.fovy:g}, "
                      f"{'no shadows' if args.no_shadows else 'shadows'}, tile {used.tile}, "
                      f"{used.kernel} kernels, "
                      f"{'tables given, ' if args.table else ''}chunk {chunk}"
                      + "".join(f", {x}" for x in args.set))
            rows.append({"stage": "render", "config": config, "batch": b,
                         "value": b / t["median_s"], "unit": "frames/s",
                         "compile_s": t["compile_s"], "runs_s": t["runs_s"]})
            print(f"render {config}, B={b}: compile {t['compile_s']:.1f} s, run median "
                  f"{t['median_s'] * 1e3:.1f} ms -> {b / t['median_s']:,.0f} frames/s", flush=True)
    return rows
