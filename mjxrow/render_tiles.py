"""Tile culling for `render.py`: the plants a group of neighbouring pixels can see, found once
per tile, then intersected exactly by every ray of the tile with pure arithmetic.

The image is cut into square tiles of `ts × ts` pixels (static). Rays are laid out tile-major,
`[T, P]` (T tiles, P = ts² pixels each), so a tile's data broadcast to its rays (no per-ray
gathers). A tile's rays lie inside a cone around its centre direction `c` (half-angle α, static
in the camera frame): a point q of a tile ray projects onto the centre ray at s = (q − o)·c ≤ |q
− o| and lies within s·tan α of it. So the centre ray's interval in a box grown by s_max·tan α
(s_max: the box's farthest projection) holds every tile ray's hit in the box, and its entry is a
lower bound of their entry distances. Per tile: every block of BLOCK plants is tested that way,
the `block_keep` blocks entered first give their plants, the `keep + deep_keep` plants entered
first (before the farthest terrain or obstacle hit of the tile's rays) are the tile's
candidates, sorted by entry. Every ray intersects the first `keep` exactly (`exact`); tiles
where a later candidate can still be nearer than a ray's hit (grazing views along a row, where
one tile's rays meet many plants at different depths) are the "deep" tiles: the `deep_tiles`
tiles with the most such candidates test the next `deep_keep` ones too.

Shadow rays from a tile's surface points are parallel (the sun direction l): a plant box can
shadow a point of the tile's bounding box B iff the ray from B's centre along l meets the box
grown by B's half extents (a Minkowski sum: exact for boxes). The `shadow_keep` plants entered
first along l are tested exactly by each shadow ray.

Pure jnp, one field and one camera; no jit here.
"""

from __future__ import annotations

import functools

import jax
import jax.numpy as jnp
import numpy as np

from mjxrow import plants as PL
from mjxrow import render_geom as G

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
    c = dirs.mean(1)
    c /= np.linalg.norm(c, axis=-1, keepdims=True)
    cos_a = np.clip(np.min(np.sum(dirs * c[:, None], -1), 1), 1e-6, 1.0)
    tan_a = np.sqrt(1.0 - cos_a ** 2) / cos_a * 1.001 + 1e-6
    return (dirs.astype(np.float32), norm.astype(np.float32), c.astype(np.float32),
            tan_a.astype(np.float32), (ny, nx))


def untile(x: jax.Array, tiles: tuple[int, int], height: int, width: int) -> jax.Array:
    """[T, P, ...] tile-major values → [height, width, ...] image."""
    ny, nx = tiles
    ts = int(round(np.sqrt(x.shape[1])))
    rest = x.shape[2:]
    img = x.reshape((ny, nx, ts, ts) + rest)
    img = jnp.moveaxis(img, 2, 1).reshape((ny * ts, nx * ts) + rest)
    return img[:height, :width]


def _grown_entry(o, c, grow, box, t_max):
    """Entry t of rays o + t·c ([T, 3] each, or o [3]) into boxes (6 arrays [M]) grown by
    `grow` [T, M] (or [T, 3, M] per axis) on every side, cut at t_max [T]: [T, M] (+inf:
    missed, empty box, or behind)."""
    t_in = jnp.zeros(grow.shape[:1] + grow.shape[-1:], jnp.float32)
    t_out = jnp.broadcast_to(t_max[:, None], t_in.shape)
    for a in range(3):
        g = grow[:, a] if grow.ndim == 3 else grow
        oa = o[..., a:a + 1] if o.ndim == 1 else o[:, a:a + 1]
        t0, t1 = G.slab(oa, c[:, a:a + 1], box[2 * a] - g, box[2 * a + 1] + g)
        t_in, t_out = jnp.maximum(t_in, t0), jnp.minimum(t_out, t1)
    return jnp.where((box[0] <= box[1]) & (t_in <= t_out), t_in, INF)


def _cone_grow(o, c, tan_a, box):
    """Growth s_max·tan α [T, M] that makes the centre ray's box hold the cone's part in it."""
    ctr = [0.5 * (box[2 * a] + box[2 * a + 1]) for a in range(3)]
    half = [0.5 * (box[2 * a + 1] - box[2 * a]) for a in range(3)]
    s = sum((ctr[a] - o[a]) * c[:, a:a + 1] + half[a] * jnp.abs(c[:, a:a + 1]) for a in range(3))
    return jnp.maximum(s, 0.0) * tan_a[:, None] + 1e-4


def _first(key, ids, n: int):
    """The n ids of smallest key per row, sorted: (ids [T, n], key [T, n])."""
    neg, j = jax.lax.top_k(-key, min(n, key.shape[1]))
    return jnp.take_along_axis(ids, j, 1), -neg


def _cull(tab: G.PlantTable, n_plants: int, entry_fn, n_tiles: int, block_keep: int, n: int):
    """The n plants entered first per tile, through blocks: (ids int32 [T, n], entry [T, n])."""
    R = tab.row_y.shape[0]
    nb = tab.block_t.shape[1] // R
    bkey = entry_fn([tab.block_t[j] for j in range(6)])  # [T, R·nb]
    bid = jnp.broadcast_to(jnp.arange(R * nb, dtype=jnp.int32), bkey.shape)
    bsel, bent = _first(bkey, bid, block_keep)
    r, blk = bsel // nb, bsel % nb
    i = blk[..., None] * G.BLOCK + jnp.arange(G.BLOCK)  # [T, KB, BLOCK]
    ok = jnp.isfinite(bent)[..., None] & (i < n_plants)
    flat = (r[..., None] * n_plants + jnp.minimum(i, n_plants - 1)).reshape(n_tiles, -1)
    box = [tab.box_t[j][flat] for j in range(6)]  # [T, KB·BLOCK]
    key = jnp.where(ok.reshape(n_tiles, -1), entry_fn(box), INF)
    return _first(key, flat, n)


def camera_candidates(tab, n_plants, o, c, tan_a, t_cut, block_keep: int, n: int):
    """Candidate plants of each camera tile (see the module docstring). o [3] camera position,
    c [T, 3] unit centre directions (world), tan_a [T], t_cut [T] farthest terrain/obstacle
    hit of the tile's rays [m]. Returns (ids int32 [T, n], entry lower bound [T, n] (+inf:
    no candidate), both sorted by entry)."""
    def entry(box):
        box = [b if b.ndim == 2 else b[None] for b in box]
        return _grown_entry(o, c, _cone_grow(o, c, tan_a, box), box, t_cut)
    return _cull(tab, n_plants, entry, c.shape[0], block_keep, n)


def shadow_candidates(tab, n_plants, lo, hi, sun, t_max: float, block_keep: int, n: int):
    """Candidate shadow casters of each tile: plants whose box meets the sun ray from some
    point of the tile's box [lo, hi] ([T, 3] each; empty when lo > hi). sun [3] unit.
    Returns (ids int32 [T, n], entry [T, n] (+inf: none))."""
    m, h = 0.5 * (lo + hi), jnp.maximum(0.5 * (hi - lo), 0.0)
    l = jnp.broadcast_to(sun, m.shape)
    empty = jnp.any(lo > hi, axis=-1)
    t_max = jnp.where(empty, -1.0, t_max)

    def entry(box):
        return _grown_entry(m, l, jnp.broadcast_to(h[..., None], h.shape + box[0].shape[-1:]),
                            box, t_max)
    return _cull(tab, n_plants, entry, m.shape[0], block_keep, n)


def exact(tab: G.PlantTable, ids, valid, o, d, t_min, t_max, group: int = 4,
          any_hit: bool = False):
    """Nearest exact primitive hit of tile rays among their tile's candidates, `group`
    candidates at a time (one primitive slot k of each), elementwise over [T, group, P].
    ids int32 [T, C], valid bool [T, C]; o, d: (x, y, z) tuples of [T, P] arrays (or [1, 1]:
    the same for every ray), |d| = 1; t_min, t_max: [T, P]. Returns (t [T, P] (+inf: none in
    (t_min, t_max)), plant int32 [T, P], k int32 [T, P]); with any_hit, t only."""
    K = len(tab.kind)
    nt, C = ids.shape
    g = max(1, min(group, C))
    ng = -(-C // g)
    pad = ng * g - C
    if pad:
        ids = jnp.concatenate([ids, jnp.zeros((nt, pad), ids.dtype)], 1)
        valid = jnp.concatenate([valid, jnp.zeros((nt, pad), bool)], 1)
    ids_g = jnp.swapaxes(ids.reshape(nt, ng, g), 0, 1)  # [ng, T, g]
    ok_g = jnp.swapaxes(valid.reshape(nt, ng, g), 0, 1)[..., None]  # [ng, T, g, 1]
    ray = lambda v: tuple(x[:, None, :] for x in v)  # noqa: E731  [T, P] → [T, 1, P]
    o, d, t_lo = ray(o), ray(d), t_min[:, None, :]
    t_best = jnp.full(t_max.shape, INF)
    s_best = jnp.zeros(t_max.shape, jnp.int32)
    for kd in (PL.ELLIPSOID, PL.CAPSULE):
        ks = np.flatnonzero(tab.kind == kd)
        if not len(ks):
            continue
        data = tab.prim[ks][:, ids_g].reshape((-1, nt, g, 12))  # [nk·ng, T, g, 12]
        ok = jnp.broadcast_to(ok_g, (len(ks),) + ok_g.shape).reshape((-1, nt, g, 1))
        kk, gg = np.meshgrid(ks, np.arange(ng), indexing="ij")
        base = jnp.asarray((gg * g * K + kk).reshape(-1), jnp.int32)  # step → (group, k)

        def body(carry, x, kd=kd):
            t_b, s_b = carry
            q, okq, b = x
            p = [q[..., i:i + 1] for i in range(12)]  # [T, g, 1]
            if kd == PL.CAPSULE:
                t = G.capsule_hit(o, d, p[0:3], p[3:6], p[6], p[7], t_lo)
            else:
                t = G.ellipsoid_hit(o, d, p[0:3], p[3:12], t_lo)
            t = jnp.where(okq, t, INF)  # [T, g, P]
            tm = jnp.min(t, axis=1)
            better = tm < jnp.minimum(t_b, t_max)
            if any_hit:
                return (jnp.where(better, tm, t_b), s_b), None
            first = jnp.min(jnp.where(t == tm[:, None], jnp.arange(g)[:, None], g), axis=1)
            s = b + first.astype(jnp.int32) * K
            return (jnp.where(better, tm, t_b), jnp.where(better, s, s_b)), None

        n_steps = base.shape[0]
        (t_best, s_best), _ = jax.lax.scan(body, (t_best, s_best), (data, ok, base),
                                           unroll=min(n_steps, 64) if G.unroll() else 1)
    if any_hit:
        return t_best
    plant = jnp.take_along_axis(ids, s_best // K, 1)
    return t_best, plant, s_best % K
