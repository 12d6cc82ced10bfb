"""Per-ray tests of `render.py` as Pallas (Triton) kernels: the exact plant tests of tile rays
against their tile's candidates, and the terrain march.

XLA runs the same arithmetic (`render_tiles.exact`, `render_terrain.trace_terrain`) as chains of
whole-array kernels and reductions; here a program takes a block of tiles, keeps its rays in
registers and loops over the candidates (or march samples), gathering the few table values it
needs, so nothing but the inputs and the result touches memory. Same results as the XLA paths
(the tests compare them); the geometry is the same code (`render_geom.prim_hit`,
`render_terrain.march`).

Tile layout as in `render_tiles`: rays [T, P] (T tiles of P pixels). A program takes
`block_rays // P` tiles (a power of two, as Triton requires; P must be one too, i.e. tiles of
1, 2, 4, 8 or 16 pixels a side). Jittable and vmappable (a vmap adds a grid axis); on CPU the
kernels run in Pallas' interpreter (slow: tests only). Pure jnp around the kernels.
"""

from __future__ import annotations

import functools

import jax
import jax.numpy as jnp
import numpy as np
from jax.experimental import pallas as pl

from mjxrow.crops import prims as crops_prims
from mjxrow.render import geom
from mjxrow.render import terrain as render_terrain

INF = jnp.inf
BLOCK_RAYS = 512  # rays per program


def supported(pixels_per_tile: int) -> bool:
    """Whether the kernels take tiles of this many pixels (a power of two)."""
    return pixels_per_tile >= 1 and pixels_per_tile & (pixels_per_tile - 1) == 0


def _interpret() -> bool:
    return jax.default_backend() == "cpu"


def _inputs(args):
    """Kernel inputs; for the interpreter put in memory first (XLA on CPU would otherwise fuse
    their producers, e.g. a whole trace, into the interpreted kernel's loads, and its compile
    time explodes)."""
    return geom.materialise(args) if _interpret() else args


def _params():
    if _interpret():
        return {"interpret": True}
    from jax.experimental.pallas import triton as plt
    return {"compiler_params": plt.CompilerParams(num_warps=4, num_stages=1)}


def _blocks(nt: int, P: int, block_rays: int) -> tuple[int, int]:
    """(tiles per program, padded tile count)."""
    if not supported(P):
        raise ValueError(f"render: the Pallas kernels need a power-of-two number of pixels per "
                         f"tile, got {P} (tile sides 1, 2, 4, 8, 16)")
    tb = max(1, block_rays // P)
    tb = min(tb, 1 << max(0, (nt - 1).bit_length()))  # no larger than the tiles (rounded up)
    return tb, -(-nt // tb) * tb


def _pad(x, n: int, value=0, axis: int = 0):
    """Pad `axis` of x up to n."""
    if x.shape[axis] == n:
        return x
    width = [(0, 0)] * x.ndim
    width[axis] = (0, n - x.shape[axis])
    return jnp.pad(x, width, constant_values=value)


def _exact_kernel(prim_ref, ids_ref, ent_ref, ray_ref, lo_ref, hi_ref, *out_refs, groups,
                  n_cand, any_hit):
    o = tuple(ray_ref[i] for i in range(3))  # [TB, P]
    d = tuple(ray_ref[3 + i] for i in range(3))
    t_lo, t_hi = lo_ref[...], hi_ref[...]
    best = jnp.full(t_lo.shape, INF, jnp.float32)
    cand = jnp.zeros(t_lo.shape, jnp.int32)
    kbest = jnp.zeros(t_lo.shape, jnp.int32)

    for kd, ks in groups:

        def test(c, ent, carry, kd=kd, ks=ks):
            best, cand, kbest = carry
            row = ids_ref[c, :]  # [TB]
            ok = ent[:, None] < t_hi
            for k in ks:
                q = [prim_ref[k, row, i][:, None] for i in range(12)]  # gathers of [TB]
                t = geom.prim_hit(kd, o, d, q, t_lo)
                t = jnp.where(ok & (t < t_hi), t, INF)
                better = t < best
                best = jnp.where(better, t, best)
                if not any_hit:
                    cand = jnp.where(better, c, cand)
                    kbest = jnp.where(better, k, kbest)
            return best, cand, kbest

        def body(c, carry, test=test):
            # the block skips a candidate none of its rays can still use: its entry bound is
            # beyond every ray's hit so far (or, for any-hit rays, every open ray's reach);
            # the candidates come sorted by that bound, so after the first skip all are
            # skipped (a while loop that stops there crashes the Triton compiler of jax 0.11)
            ent = ent_ref[c, :]  # [TB], +inf: no candidate
            best = carry[0]
            if any_hit:
                live = (best == INF) & (ent[:, None] < t_hi)
            else:
                live = ent[:, None] < jnp.minimum(best, t_hi)
            go = jnp.max(live.astype(jnp.int32)) > 0
            return jax.lax.cond(go, functools.partial(test, c, ent), lambda x: x, carry)

        best, cand, kbest = jax.lax.fori_loop(0, n_cand, body, (best, cand, kbest))
    out_refs[0][...] = best
    if not any_hit:
        out_refs[1][...] = cand
        out_refs[2][...] = kbest


def exact(tab: geom.PlantTable, ids, entry, o, d, t_min, t_max, any_hit: bool = False,
          block_rays: int = BLOCK_RAYS):
    """`render_tiles.exact` as one kernel (same arguments and results): each program holds a
    block of tiles' rays and loops over their candidates, gathering each candidate's
    primitives from the table, and skips the candidates whose entry bound lies beyond all its
    rays' hits."""
    nt, C = ids.shape
    P = t_max.shape[1]
    tb, ntp = _blocks(nt, P, block_rays)
    ray = jnp.stack([jnp.broadcast_to(v, t_max.shape).astype(jnp.float32)
                     for v in tuple(o) + tuple(d)])  # [6, T, P]
    ray = _pad(ray, ntp, axis=1)
    ent = jnp.asarray(entry, jnp.float32)
    ids_t = _pad(jnp.where(jnp.isfinite(ent), ids, 0).astype(jnp.int32), ntp).T  # [C, Tp]
    ent_t = _pad(ent, ntp, INF).T
    lo = _pad(t_min.astype(jnp.float32), ntp)
    hi = _pad(t_max.astype(jnp.float32), ntp, -1.0)
    groups = tuple((kd, tuple(int(k) for k in np.flatnonzero(tab.kind == kd)))
                   for kd in (crops_prims.ELLIPSOID, crops_prims.CAPSULE) if np.any(tab.kind == kd))
    tile = pl.BlockSpec((tb, P), lambda i: (i, 0))
    cand = pl.BlockSpec((C, tb), lambda i: (0, i))
    out_shape = [jax.ShapeDtypeStruct((ntp, P), jnp.float32)]
    if not any_hit:
        out_shape += [jax.ShapeDtypeStruct((ntp, P), jnp.int32)] * 2
    kernel = functools.partial(_exact_kernel, groups=groups, n_cand=C, any_hit=any_hit)
    out = pl.pallas_call(
        kernel, grid=(ntp // tb,),
        in_specs=[pl.BlockSpec(tab.prim.shape, lambda i: (0, 0, 0)), cand, cand,
                  pl.BlockSpec((6, tb, P), lambda i: (0, i, 0)), tile, tile],
        out_specs=[tile] * len(out_shape), out_shape=out_shape, **_params(),
    )(*_inputs([tab.prim, ids_t, ent_t, ray, lo, hi]))
    t = out[0][:nt]
    if any_hit:
        return t
    plant = jnp.take_along_axis(ids, out[1][:nt], 1)
    return t, plant, out[2][:nt]


def _terrain_kernel(sc_ref, hf_ref, ray_ref, lo_ref, hi_ref, t_ref, n_ref, *, shape, steps,
                    refine):
    o = tuple(ray_ref[i] for i in range(3))  # [TB, P]
    d = tuple(ray_ref[3 + i] for i in range(3))
    t, n = render_terrain.march(
        lambda idx: hf_ref[idx],
        shape,
        (sc_ref[0], sc_ref[1]),
        (sc_ref[2], sc_ref[3]),
        o,
        d,
        lo_ref[...],
        hi_ref[...],
        steps,
        refine,
        unrolled=True,
    )
    t_ref[...] = t
    for i in range(3):
        n_ref[i] = n[i]


def trace_terrain(terrain, size, o, d, t_min, t_max, steps: int, refine: int, P: int,
                  block_rays: int = BLOCK_RAYS):
    """`render_terrain.trace_terrain` as one kernel (same arguments and results; the flat rays
    are tile-major, P per tile): each program marches a block of rays, gathering heights from
    the terrain."""
    n = d.shape[0]
    nt = n // P
    tb, ntp = _blocks(nt, P, block_rays)
    ray = _pad(jnp.concatenate([o, d], 1).T.reshape(6, nt, P).astype(jnp.float32), ntp, axis=1)
    lo = _pad(t_min.reshape(nt, P).astype(jnp.float32), ntp)
    hi = _pad(t_max.reshape(nt, P).astype(jnp.float32), ntp, -1.0)
    terrain = jnp.asarray(terrain, jnp.float32)
    sc = jnp.stack([jnp.asarray(size[0], jnp.float32), jnp.asarray(size[1], jnp.float32),
                    jnp.min(terrain), jnp.max(terrain)])
    tile = pl.BlockSpec((tb, P), lambda i: (i, 0))
    kernel = functools.partial(_terrain_kernel, shape=terrain.shape, steps=steps, refine=refine)
    t, nrm = pl.pallas_call(
        kernel, grid=(ntp // tb,),
        in_specs=[pl.BlockSpec((4,), lambda i: (0,)),
                  pl.BlockSpec((terrain.size,), lambda i: (0,)),
                  pl.BlockSpec((6, tb, P), lambda i: (0, i, 0)), tile, tile],
        out_specs=[tile, pl.BlockSpec((3, tb, P), lambda i: (0, i, 0))],
        out_shape=[jax.ShapeDtypeStruct((ntp, P), jnp.float32),
                   jax.ShapeDtypeStruct((3, ntp, P), jnp.float32)], **_params(),
    )(*_inputs([sc, terrain.reshape(-1), ray, lo, hi]))
    return t[:nt].reshape(n), nrm[:, :nt].reshape(3, n).T
