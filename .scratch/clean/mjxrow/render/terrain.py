"""Ray casting against the heightfield terrain for `render.py`: MuJoCo's triangulation of the
exported hfield (as `field.terrain_height`), marched and refined to the exact triangle.
Pure jnp, rays flattened to [N]; no jit here. `march` is the geometry, shared with the Pallas
kernel (`render_pallas.trace_terrain`)."""

from __future__ import annotations

import jax
import jax.numpy as jnp

from mjxrow.render.geom import INF, slab, unroll


def _eval(heights, shape, size, x, y):
    """Height h [m] and slopes dh/dx, dh/dy of the triangle under (x, y) (any shape);
    heights(flat index) → the terrain's heights there (row-major [ny, nx])."""
    ny, nx = shape
    sx, sy = (nx - 1) / size[0], (ny - 1) / size[1]
    u = jnp.clip((x / size[0] + 0.5) * (nx - 1), 0.0, nx - 1 - 1e-4)
    v = jnp.clip((y / size[1] + 0.5) * (ny - 1), 0.0, ny - 1 - 1e-4)
    i = jnp.floor(u).astype(jnp.int32)
    j = jnp.floor(v).astype(jnp.int32)
    fu, fv = u - i.astype(u.dtype), v - j.astype(v.dtype)
    base = j * nx + i
    h00, h10 = heights(base), heights(base + 1)
    h01, h11 = heights(base + nx), heights(base + nx + 1)
    low = fu >= fv  # triangle (00, 10, 11)
    gu = jnp.where(low, h10 - h00, h11 - h01)
    gv = jnp.where(low, h11 - h10, h01 - h00)
    return h00 + fu * gu + fv * gv, gu * sx, gv * sy


def terrain_eval(terrain, size, x, y):
    """Height h [m] and slopes dh/dx, dh/dy of the triangle under (x, y) (any shape)."""
    terrain = jnp.asarray(terrain)
    return _eval(terrain.reshape(-1).__getitem__, terrain.shape, size, x, y)


def march(heights, shape, size, band, o, d, t_min, t_max, steps: int, refine: int,
          unrolled: bool):
    """First hit of rays o + t·d with the terrain (heights(flat index), static shape (ny, nx),
    size (x, y) [m], height band (zmin, zmax) [m]); o, d: (x, y, z) tuples of arrays of one
    shape, t_min, t_max of that shape. Returns (t (+inf: none), unit normal (x, y, z)).
    unrolled: the samples one after another (a kernel keeping its rays in registers), else all
    at once on a new leading axis (whole-array XLA)."""
    tx0, tx1 = slab(o[0], d[0], -0.5 * size[0], 0.5 * size[0])
    ty0, ty1 = slab(o[1], d[1], -0.5 * size[1], 0.5 * size[1])
    tz0, tz1 = slab(o[2], d[2], band[0] - 1e-4, band[1] + 1e-4)
    t0 = jnp.maximum(jnp.maximum(tx0, ty0), jnp.maximum(tz0, t_min))
    t1 = jnp.minimum(jnp.minimum(tx1, ty1), jnp.minimum(tz1, t_max))
    live = t0 < t1
    span = jnp.where(live, t1, t0) - t0

    def f(t):  # height of the ray above the terrain at t (broadcast against the rays)
        return o[2] + t * d[2] - _eval(heights, shape, size, o[0] + t * d[0], o[1] + t * d[1])[0]

    # the first sample below the surface, in closed form: no gathers from the samples
    if unrolled:
        first = jnp.full(t0.shape, steps + 1, jnp.int32)
        for s in range(steps + 1):
            below = f(t0 + span * (s / steps)) <= 0.0
            first = jnp.where((first > steps) & below, s, first)
    else:  # samples lead ([S + 1, N]): the reduction runs over a major axis, a lane per ray
        frac = (jnp.arange(0, steps + 1, dtype=jnp.float32) / steps)[:, None]
        below = f(t0 + span * frac) <= 0.0
        first = jnp.min(jnp.where(below, jnp.arange(steps + 1)[:, None], steps + 1), axis=0)
    found = live & (first <= steps)
    b = t0 + span * (first.astype(jnp.float32) / steps)
    a = jnp.where(first > 0, t0 + span * ((first - 1).astype(jnp.float32) / steps), t0)

    def bisect(_, ab):
        a, b = ab
        m = 0.5 * (a + b)
        above = f(m) > 0.0
        return jnp.where(above, m, a), jnp.where(above, b, m)

    if unrolled:
        for _ in range(refine):
            a, b = bisect(0, (a, b))
    else:
        a, b = jax.lax.fori_loop(0, refine, bisect, (a, b), unroll=refine if unroll() else 1)
    m = 0.5 * (a + b)
    pm = [o[i] + m * d[i] for i in range(3)]
    h, gx, gy = _eval(heights, shape, size, pm[0], pm[1])
    den = d[2] - gx * d[0] - gy * d[1]
    num = h + gx * (o[0] - pm[0]) + gy * (o[1] - pm[1]) - o[2]
    t_plane = num / jnp.where(den < -1e-9, den, -1e-9)
    t = jnp.where(den < -1e-9, jnp.clip(t_plane, a, b), m)
    inv = 1.0 / jnp.sqrt(gx * gx + gy * gy + 1.0)
    return jnp.where(found, t, INF), (-gx * inv, -gy * inv, inv)


def trace_terrain(terrain, size, o, d, t_min, t_max, steps: int, refine: int):
    """First hit of each ray with the heightfield (inside its rectangle): a march of `steps`
    uniform samples over the ray's part inside the terrain's height band, `refine` bisections
    of the first bracket, then the exact plane of the triangle there. Features thinner than a
    march step can be stepped over (far, grazing rays).
    o, d: [N, 3]; t_min, t_max: [N]. Returns (t [N] (+inf: none), unit normal [N, 3])."""
    terrain = jnp.asarray(terrain)
    band = (jnp.min(terrain), jnp.max(terrain))
    t, n = march(terrain.reshape(-1).__getitem__, terrain.shape, size, band,
                 tuple(o[:, i] for i in range(3)), tuple(d[:, i] for i in range(3)),
                 t_min, t_max, steps, refine, unrolled=False)
    return t, jnp.stack(n, -1)
