"""Tile culling for `render.py`: the plants a group of neighbouring pixels can see, found once
per tile, then intersected exactly by every ray of the tile with pure arithmetic.

The image is cut into square tiles of `ts × ts` pixels (static; the last row and column of
tiles are padded with rays outside the image). Rays are laid out tile-major, `[T, P]` (T tiles,
P = ts² pixels), so a tile's candidates broadcast to its rays: no per-ray gathers, no per-ray
sorts. A tile's rays are bounded by a "sweep" around a centre ray o + s·c: the points within
g + s·τ of it on every axis. Camera tiles: o the camera, c the tile's centre direction,
τ = tan of the cone half-angle (static in the camera frame; a point q of a tile ray projects at
s = (q − o)·c ≤ |q − o| and lies within s·τ of the centre ray), g = 0. Shadow rays of a tile
(parallel, along the sun direction l): o the centre of the box B holding the tile's surface
points, c = l, g = B's half extents, τ = 0 (a Minkowski sum: exact for boxes).

Culling (`cull`), all in closed form or over small static lists:
1. Rows (`_window`): per row, where the sweep can be inside the row's slab (|y − row_y| ≤ the
   plants' lateral reach, z in the row's height band, x within the rows' extent; linear
   inequalities in s) gives the x range and so the plant indices it can meet; the first
   `row_blocks` blocks of BLOCK plants of that range along the ray are kept.
2. Blocks: their boxes, grown by the sweep at the box's farthest projection, give a lower bound
   of every swept ray's entry; the `block_keep` entered first (before t_max: the farthest
   terrain/obstacle hit of the tile's rays) give their plants.
3. Plants: the same bound on each plant's box; the `n` entered first are the tile's candidates.
Every ray intersects its tile's candidates exactly (`exact`). Where a later plant may still be
nearer than a ray's hit (views along a row or over many far rows, where one tile's rays meet
plants at many depths), the tile is "deep": the deep tiles with the most such plants are
culled again with longer windows and lists, cut at their rays' current hits.

Limits: a plant is missed when it is beyond a row's window of `row_blocks` blocks, or beyond a
tile's kept blocks or candidates, on a tile that is not among the deep ones (tiles over many
small, far plants: lettuce and chard seen along the rows); see `render.py` for the measured
agreement with an all-plants reference. Pure jnp, one field and one camera; no jit here.
"""

from __future__ import annotations

import functools

import jax
import jax.numpy as jnp
import numpy as np

from mjxrow.crops import prims as crops_prims
from mjxrow.render import geom, pallas
from mjxrow.render import rows as render_rows

INF = jnp.inf


@functools.cache
def tile_layout(width: int, height: int, fovy: float, ts: int):
    """Static camera-frame tile geometry of an image, padded up to whole tiles.
    Returns (dirs float32 [T, P, 3] unit pixel directions (camera frame), norm float32 [T, P]
    (|pixel ray| of the z = −1 ray, for depth), centre float32 [T, 3] unit centre directions,
    tan_a float32 [T] (tan of the cone half-angle), tiles (ny, nx))."""
    ny, nx = -(-height // ts), -(-width // ts)
    ty = np.tan(np.deg2rad(fovy) / 2)
    tx = ty * width / height
    j = (2 * (np.arange(nx * ts) + 0.5) / width - 1) * tx
    i = (1 - 2 * (np.arange(ny * ts) + 0.5) / height) * ty
    xx, yy = np.meshgrid(j, i)
    ray = np.stack([xx, yy, -np.ones_like(xx)], -1)  # [Hp, Wp, 3]
    ray = ray.reshape(ny, ts, nx, ts, 3).transpose(0, 2, 1, 3, 4).reshape(ny * nx, ts * ts, 3)
    norm = np.linalg.norm(ray, axis=-1)
    dirs = ray / norm[..., None]
    c, tan_a = cone(dirs, np)
    return (dirs.astype(np.float32), norm.astype(np.float32), c.astype(np.float32),
            tan_a.astype(np.float32), (ny, nx))


def cone(dirs, xp=jnp):
    """The cone around a tile's unit ray directions dirs [T, P, 3] (numpy or jax, `xp`): its
    unit centre direction [T, 3] and the tangent of its half-angle [T] (grown a little, so that
    every ray lies inside)."""
    c = dirs.mean(1)
    c = c / xp.linalg.norm(c, axis=-1, keepdims=True)
    cos_a = xp.clip(xp.min(xp.sum(dirs * c[:, None], -1), 1), 1e-6, 1.0)
    return c, xp.sqrt(1.0 - cos_a ** 2) / cos_a * 1.001 + 1e-6


def untile(x: jax.Array, tiles: tuple[int, int], height: int, width: int) -> jax.Array:
    """[T, P, ...] tile-major values → [height, width, ...] image."""
    ny, nx = tiles
    ts = int(round(np.sqrt(x.shape[1])))
    rest = x.shape[2:]
    img = x.reshape((ny, nx, ts, ts) + rest)
    img = jnp.moveaxis(img, 2, 1).reshape((ny * ts, nx * ts) + rest)
    return img[:height, :width]


def _sweep_entry(o, c, g, tau, box, t_max, s_min=None):
    """Entry s along centre rays o + s·c ([T, 3]) of the swept set of a tile (the points
    within g + s·tan α of the centre ray, per axis: g [T, 3], tau [T]) into boxes (6 arrays
    [T, M] or [M]), cut at t_max [T] and (s_min [T], or None: 0) below: [T, M] (+inf: missed,
    empty box, or behind). The growth is taken at the box's farthest projection on the centre
    ray, so the entry is a lower bound of every swept ray's entry."""
    ctr = [0.5 * (box[2 * a] + box[2 * a + 1]) for a in range(3)]
    half = [0.5 * (box[2 * a + 1] - box[2 * a]) for a in range(3)]
    s_max = sum((ctr[a] - o[:, a:a + 1]) * c[:, a:a + 1] + half[a] * jnp.abs(c[:, a:a + 1])
                for a in range(3))
    cone = jnp.maximum(s_max, 0.0) * tau[:, None] + 1e-4
    t_in = jnp.zeros(cone.shape, jnp.float32)
    if s_min is not None:
        t_in = jnp.maximum(t_in, s_min[:, None])
    t_out = jnp.broadcast_to(t_max[:, None], cone.shape)
    for a in range(3):
        grow = cone + g[:, a:a + 1]
        t0, t1 = geom.slab(o[:, a:a + 1], c[:, a:a + 1], box[2 * a] - grow, box[2 * a + 1] + grow)
        t_in, t_out = jnp.maximum(t_in, t0), jnp.minimum(t_out, t1)
    return jnp.where((box[0] <= box[1]) & (t_in <= t_out), t_in, INF)


def _interval(oa, ca, ga, tau, t_max, lo, hi):
    """Interval [s0, s1] of the centre ray where the swept set can reach the slab
    lo ≤ coordinate ≤ hi along one direction: oa + s·ca ∈ [lo − ga − s·τ, hi + ga + s·τ], two
    linear inequalities in s (oa, ca: the centre ray's origin and direction along it, ga the
    sweep's growth along it, [T, 1] or [T, M]; tau, t_max [T]; lo, hi [M] or scalars)."""
    t = tau[:, None]
    s0 = jnp.zeros(jnp.broadcast_shapes(jnp.shape(oa), jnp.shape(ca), jnp.shape(lo)),
                   jnp.float32)
    s1 = jnp.broadcast_to(t_max[:, None], s0.shape)
    for k, b in ((ca - t, hi + ga - oa), (-ca - t, oa - lo + ga)):  # k·s ≤ b
        q = b / jnp.where(k == 0, 1.0, k)
        s1 = jnp.where(k > 0, jnp.minimum(s1, q), jnp.where((k == 0) & (b < 0), -1.0, s1))
        s0 = jnp.where(k < 0, jnp.maximum(s0, q), s0)
    return s0, s1


def _window(tab: geom.PlantTable, n_plants: int, o, c, g, tau, t_max, row_blocks: int,
            s_min=None):
    """Blocks a tile's sweep can meet, through the row structure: per row segment
    (`render.rows`), the stretch of the centre ray where the sweep reaches the segment's strip
    (across and along its chord, its height band) gives the range along the chord and so the
    plant slots it can meet; per row, the first `row_blocks` blocks of the slots met are kept,
    counted from the end where the ray comes in (the way it runs along the chord of the
    segment it enters first). The sweep's growth: g per world axis, turned onto the chord as a
    box, and s·τ (Euclidean: the same along any direction); the centre ray's stretch starts at
    s_min [T] (None: 0). Returns (block id int32 [T, R·row_blocks], ok bool)."""
    R = tab.row_y.shape[0]
    nb = tab.block_t.shape[1] // R
    sg = tab.seg_t
    ns = sg.shape[1] // R
    ex, ey = sg[render_rows.SEG_EX], sg[render_rows.SEG_EY]
    rx, ry = o[:, 0:1] - sg[render_rows.SEG_AX], o[:, 1:2] - sg[render_rows.SEG_AY]  # [T, M]
    cx, cy, gx, gy = c[:, 0:1], c[:, 1:2], g[:, 0:1], g[:, 1:2]
    oe, on = rx * ex + ry * ey, ry * ex - rx * ey
    ce, cn = cx * ex + cy * ey, cy * ex - cx * ey
    ge = gx * jnp.abs(ex) + gy * jnp.abs(ey)
    gn = gx * jnp.abs(ey) + gy * jnp.abs(ex)
    sn0, sn1 = _interval(on, cn, gn, tau, t_max, sg[render_rows.SEG_LAT_LO],
                         sg[render_rows.SEG_LAT_HI])
    se0, se1 = _interval(oe, ce, ge, tau, t_max, sg[render_rows.SEG_AL_LO],
                         sg[render_rows.SEG_AL_HI])
    sz0, sz1 = _interval(o[:, 2:3], c[:, 2:3], g[:, 2:3], tau, t_max, sg[render_rows.SEG_Z_LO],
                         sg[render_rows.SEG_Z_HI])
    s0 = jnp.maximum(jnp.maximum(sn0, se0), sz0)
    if s_min is not None:
        s0 = jnp.maximum(s0, s_min[:, None])
    s1 = jnp.minimum(jnp.minimum(sn1, se1), sz1)
    # slots m of the segment whose boxes lie within reach of the centre ray's stretch
    aa, ab = oe + s0 * ce, oe + s1 * ce
    reach = ge + s1 * tau[:, None] + sg[render_rows.SEG_REACH]
    step = sg[render_rows.SEG_STEP]
    first = jnp.asarray(np.tile(np.arange(ns, dtype=np.float32) * tab.seg, R))  # [M]
    last = jnp.minimum(first + (tab.seg - 1), float(n_plants - 1))
    i_lo = first + jnp.ceil((jnp.minimum(aa, ab) - reach) / step)
    i_hi = first + jnp.floor((jnp.maximum(aa, ab) + reach) / step)
    hit = ((s0 <= s1) & (sg[render_rows.SEG_Z_LO] <= sg[render_rows.SEG_Z_HI])
           & (i_lo <= i_hi) & (i_hi >= first) & (i_lo <= last))
    i_lo, i_hi = jnp.maximum(i_lo, first), jnp.minimum(i_hi, last)
    T = o.shape[0]
    per_row = lambda v: v.reshape(T, R, ns)  # noqa: E731
    hit, s0, ce, i_lo, i_hi = map(per_row, (hit, s0, ce, i_lo, i_hi))
    # the row's slots met, kept from the end where the ray comes in: the way it runs along
    # the chord of the segment it enters first
    s_in = jnp.where(hit, s0, INF)
    fwd = jnp.take_along_axis(ce, jnp.argmin(s_in, -1)[..., None], -1)[..., 0] >= 0  # [T, R]
    ok = jnp.any(hit, -1)
    lo = jnp.where(ok, jnp.min(jnp.where(hit, i_lo, INF), -1), 0.0)
    hi = jnp.where(ok, jnp.max(jnp.where(hit, i_hi, -INF), -1), 0.0)
    b_lo, b_hi = jnp.floor(lo / geom.BLOCK), jnp.floor(hi / geom.BLOCK)
    j = jnp.arange(row_blocks, dtype=jnp.float32)
    b = jnp.where(fwd[..., None], b_lo[..., None] + j, b_hi[..., None] - j)  # [T, R, row_blocks]
    ok = ok[..., None] & (b >= b_lo[..., None]) & (b <= b_hi[..., None])
    bid = jnp.arange(R, dtype=jnp.int32)[:, None] * nb + jnp.clip(b, 0, nb - 1).astype(jnp.int32)
    return bid.reshape(T, -1), ok.reshape(T, -1)


def _first(key, ids, n: int):
    """The n ids of smallest key per row, sorted: (ids [T, n], key [T, n])."""
    neg, j = jax.lax.top_k(-key, min(n, key.shape[1]))
    return jnp.take_along_axis(ids, j, 1), -neg


def cull(tab: geom.PlantTable, n_plants: int, o, c, g, tau, t_max, row_blocks: int,
         block_keep: int, n: int, s_min=None):
    """The n plants a tile's sweep enters first (see the module docstring), from s_min [T]
    along the centre ray on (None: 0; a later layer of plants, `reach`).
    o, c [T, 3] (|c| = 1), g [T, 3], tau [T], t_max [T] (nothing beyond matters) [m].
    Returns (ids int32 [T, n], entry lower bound [T, n] (+inf: none), both sorted by entry,
    and `rest` int32 [T]: plants (counted by whole blocks past the kept ones) whose entry
    lies before t_max but who are not among the n), and `reach` [T]: how far the
    kept plants hold every plant the tile's rays can meet, in distance along any of its rays
    (the entry of the last kept plant or block when its list is full, else t_max; the row
    windows aside), so a later cull of the same rays can start there."""
    T = o.shape[0]
    bid, ok = _window(tab, n_plants, o, c, g, tau, t_max, row_blocks, s_min)
    bkey = jnp.where(ok, _sweep_entry(o, c, g, tau, [tab.block_t[j][bid] for j in range(6)],
                                      t_max, s_min), INF)
    bsel, bent = _first(bkey, bid, block_keep)
    R = tab.row_y.shape[0]
    nb = tab.block_t.shape[1] // R
    r, blk = bsel // nb, bsel % nb
    i = blk[..., None] * geom.BLOCK + jnp.arange(geom.BLOCK)  # [T, KB, BLOCK]
    pok = jnp.isfinite(bent)[..., None] & (i < n_plants)
    flat = (r[..., None] * n_plants + jnp.minimum(i, n_plants - 1)).reshape(T, -1)
    key = jnp.where(pok.reshape(T, -1),
                    _sweep_entry(o, c, g, tau, [tab.box_t[j][flat] for j in range(6)], t_max,
                                 s_min), INF)
    ids, ent = _first(key, flat, n)
    dropped = jnp.sum(jnp.isfinite(bkey), 1) - jnp.sum(jnp.isfinite(bent), 1)
    rest = jnp.sum(jnp.isfinite(key), 1) - jnp.sum(jnp.isfinite(ent), 1) + geom.BLOCK * dropped
    # a plant left out enters after the last kept plant (of the kept blocks) or after the
    # last kept block (of the others): lower bounds of its distance along every tile ray
    left = jnp.sum(jnp.isfinite(key), 1) - jnp.sum(jnp.isfinite(ent), 1)
    reach = jnp.minimum(jnp.where(left > 0, ent[:, -1], INF),
                        jnp.where(dropped > 0, bent[:, -1], INF))
    return ids, ent, rest, jnp.minimum(reach, t_max)


def _cull_boxes(box, o, c, g, tau, t_max, n: int):
    """The n of a frame's boxes (6 arrays [M]) a tile's sweep enters first, by the same entry
    bound as the plants': (ids int32 [T, n] into the boxes, entry [T, n] (+inf: none))."""
    ent = _sweep_entry(o, c, g, tau, box, t_max)
    ids = jnp.broadcast_to(jnp.arange(ent.shape[1], dtype=jnp.int32), ent.shape)
    return _first(ent, ids, n)


def cull_obstacles(obst, o, c, g, tau, t_max, n: int):
    """The n obstacles of a frame's table (`render_geom.obstacle_table`) a tile's sweep enters
    first: (ids int32 [T, n], entry [T, n] (+inf: none))."""
    return _cull_boxes(geom.obstacle_boxes(obst), o, c, g, tau, t_max, n)


def cull_weeds(wt, o, c, g, tau, t_max, n: int):
    """The n weeds of a frame's weed table (`render.weeds.table`) a tile's sweep enters
    first: (ids int32 [T, n], entry [T, n] (+inf: none))."""
    return _cull_boxes([wt.box_t[j] for j in range(6)], o, c, g, tau, t_max, n)


def camera_sweep(cam, c, tan_a):
    """Sweep of camera tiles: (o [T, 3], c [T, 3], g [T, 3], tau [T])."""
    return jnp.broadcast_to(cam, c.shape), c, jnp.zeros_like(c), tan_a


def shadow_sweep(lo, hi, sun):
    """Sweep of the shadow rays of tiles whose surface points lie in boxes [lo, hi] ([T, 3];
    lo > hi: none): the box moved along the sun direction sun [3] (a Minkowski sum: exact
    for boxes). Returns (o, c, g, tau) and whether the tile has points, bool [T]."""
    m, h = 0.5 * (lo + hi), jnp.maximum(0.5 * (hi - lo), 0.0)
    live = jnp.all(lo <= hi, axis=-1)
    m = jnp.where(live[:, None], m, 0.0)
    return (m, jnp.broadcast_to(sun, m.shape), h, jnp.zeros(m.shape[:1])), live


def _nearest(t):
    """Minimum over axis 0 of t [M, T, P] (t > 0 or +inf) and the index where it is reached,
    in one plain min-reduction (which the hit tests producing t fuse into, so t never lands in
    memory; the reduced axis leads, so every ray has its own lane): the index replaces the low
    mantissa bits of t's float32 bits, which order like the floats. The minimum loses those
    bits (relative error below 2^(b − 23) for M ≤ 2^b: 6e-5 for 512 candidates' primitives),
    and among hits closer than that the lower index wins. Returns (t_min [T, P] (+inf: none),
    m int32 [T, P])."""
    nbits = max(1, (t.shape[0] - 1).bit_length())
    if nbits > 16:
        raise ValueError(f"render: {t.shape[0]} primitive tests per tile ray, at most 65536")
    low = (1 << nbits) - 1
    idx = jax.lax.broadcasted_iota(jnp.int32, t.shape, 0)
    bits = jax.lax.bitcast_convert_type(t.astype(jnp.float32), jnp.int32)
    key = jnp.where(jnp.isfinite(t), (bits & ~low) | idx, jnp.iinfo(jnp.int32).max)
    best = jnp.min(key, axis=0)
    t_min = jax.lax.bitcast_convert_type(best & ~low, jnp.float32)
    hit = best != jnp.iinfo(jnp.int32).max
    return jnp.where(hit, t_min, INF), jnp.where(hit, best & low, 0)


def _exact_fused(tab: geom.PlantTable, ids, entry, o, d, t_min, t_max, any_hit: bool = False):
    """`exact` as one [M = K·C, T, P] computation reduced over M in one pass (`_nearest`).
    The rays are put in memory first: computed in the same jit, they would otherwise be
    recomputed for each of the M tests."""
    nt, C = ids.shape
    o, d, t_min, t_max = geom.materialise((o, d, t_min, t_max))
    ray = lambda v: tuple(x[None] for x in v)  # noqa: E731  [T, P] → [1, T, P]
    o, d, t_lo, t_hi = ray(o), ray(d), t_min[None], t_max[None]
    t_best = jnp.full(t_max.shape, INF)
    plant = jnp.zeros(t_max.shape, jnp.int32)
    k_best = jnp.zeros(t_max.shape, jnp.int32)
    for kd in (crops_prims.ELLIPSOID, crops_prims.CAPSULE):
        ks = np.flatnonzero(tab.kind == kd)
        if not len(ks):
            continue
        # [M, T, 12], m = j·C + c: primitive ks[j] of candidate c
        q = jnp.swapaxes(tab.prim[ks][:, ids], 1, 2).reshape(len(ks) * C, nt, 12)
        ok = jnp.tile(entry.T, (len(ks), 1))[..., None] < t_hi  # [M, T, P]
        t = geom.prim_hit(kd, o, d, [q[..., i:i + 1] for i in range(12)], t_lo)
        t = jnp.where(ok & (t < t_hi), t, INF)  # [M, T, P]
        if any_hit:
            t_best = jnp.minimum(t_best, jnp.min(t, axis=0))
            continue
        tm, m = _nearest(t)
        better = tm < t_best
        t_best = jnp.where(better, tm, t_best)
        plant = jnp.where(better, jnp.take_along_axis(ids, m % C, 1), plant)
        k_best = jnp.where(better, jnp.asarray(ks, jnp.int32)[m // C], k_best)
    if any_hit:
        return t_best
    return t_best, plant, k_best


def _exact_scan(tab: geom.PlantTable, ids, entry, o, d, t_min, t_max, any_hit: bool = False,
                group: int = 4):
    """`exact` as a scan over `group` candidates at a time (one primitive slot k of each),
    elementwise over [T, group, P] (faster on CPU)."""
    K = len(tab.kind)
    nt, C = ids.shape
    g = max(1, min(group, C))
    ng = -(-C // g)
    pad = ng * g - C
    if pad:
        ids = jnp.concatenate([ids, jnp.zeros((nt, pad), ids.dtype)], 1)
        entry = jnp.concatenate([entry, jnp.full((nt, pad), INF, entry.dtype)], 1)
    ids_g = jnp.swapaxes(ids.reshape(nt, ng, g), 0, 1)  # [ng, T, g]
    ent_g = jnp.swapaxes(entry.reshape(nt, ng, g), 0, 1)[..., None]  # [ng, T, g, 1]
    ray = lambda v: tuple(x[:, None, :] for x in v)  # noqa: E731  [T, P] → [T, 1, P]
    o, d, t_lo = ray(o), ray(d), t_min[:, None, :]
    t_best = jnp.full(t_max.shape, INF)
    s_best = jnp.zeros(t_max.shape, jnp.int32)
    for kd in (crops_prims.ELLIPSOID, crops_prims.CAPSULE):
        ks = np.flatnonzero(tab.kind == kd)
        if not len(ks):
            continue
        data = tab.prim[ks][:, ids_g].reshape((-1, nt, g, 12))  # [nk·ng, T, g, 12]
        ent = jnp.broadcast_to(ent_g, (len(ks),) + ent_g.shape).reshape((-1, nt, g, 1))
        kk, gg = np.meshgrid(ks, np.arange(ng), indexing="ij")
        base = jnp.asarray((gg * g * K + kk).reshape(-1), jnp.int32)  # step → (group, k)

        def body(carry, x, kd=kd):
            t_b, s_b = carry
            q, ent_q, b = x
            t = geom.prim_hit(kd, o, d, [q[..., i:i + 1] for i in range(12)], t_lo)
            t = jnp.where(ent_q < t_max[:, None, :], t, INF)  # [T, g, P]
            tm = jnp.min(t, axis=1)
            better = tm < jnp.minimum(t_b, t_max)
            if any_hit:
                return (jnp.where(better, tm, t_b), s_b), None
            first = jnp.min(jnp.where(t == tm[:, None], jnp.arange(g)[:, None], g), axis=1)
            s = b + first.astype(jnp.int32) * K
            return (jnp.where(better, tm, t_b), jnp.where(better, s, s_b)), None

        n_steps = base.shape[0]
        (t_best, s_best), _ = jax.lax.scan(body, (t_best, s_best), (data, ent, base),
                                           unroll=min(n_steps, 64) if geom.unroll() else 1)
    if any_hit:
        return t_best
    plant = jnp.take_along_axis(ids, s_best // K, 1)
    return t_best, plant, s_best % K


def exact(tab: geom.PlantTable, ids, entry, o, d, t_min, t_max, any_hit: bool = False, *,
          kernel: str):
    """Nearest exact primitive hit of tile rays among their tile's candidates.
    ids int32 [T, C]; entry float32 [T, C]: a lower bound of every tile ray's distance to
    the candidate (`cull`'s; +inf: no candidate; a ray tests only the candidates whose bound
    lies before its t_max, and the Pallas kernel skips those beyond its hits so far);
    o, d: (x, y, z) tuples of [T, P] arrays (or [1, 1]: the same for every ray), |d| = 1;
    t_min, t_max: [T, P]. Returns (t [T, P] (+inf: none in (t_min, t_max)), plant int32
    [T, P], k int32 [T, P]); with any_hit, t only.
    kernel (`render.KERNELS`; `render.resolve` picks it): "fused" (every ray against every
    candidate primitive in one reduction, `_exact_fused`), "scan" (over groups of candidates,
    `_exact_scan`) or "pallas" (one Triton kernel, `render_pallas.exact`)."""
    fn = {"fused": _exact_fused, "scan": _exact_scan, "pallas": pallas.exact}[kernel]
    return fn(tab, ids, jnp.asarray(entry, jnp.float32), o, d, t_min, t_max, any_hit=any_hit)
