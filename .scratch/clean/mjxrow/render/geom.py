"""Ray casting against a field's plants and obstacles for `render.py` (the terrain is in
`render_terrain.py`; which plants each ray tests is decided in `render_tiles.py`). Pure jnp,
one field; no jit here.

Exact ray tests of ellipsoids and capsules on (x, y, z) tuples of broadcastable arrays, the
plant table (`plant_table`: every plant's primitives, bounding box, blocks of BLOCK plants,
row bounds; compute it once per field and pass it to `render` when many frames see one
field), normals and primitive-frame points at hits, and the obstacles (stones and branches,
the few nearest the camera, tested one at a time against every ray).
"""

from __future__ import annotations

import jax
import jax.numpy as jnp
import numpy as np
from flax import struct

from mjxrow import field as mjxrow_field
from mjxrow.crops import prims as crops_prims
from mjxrow.field import lanes as field_lanes
from mjxrow.render import rows as render_rows

INF = jnp.inf
BLOCK = render_rows.BLOCK  # plants per block of the first culling level
_EPS_DIR = 1e-9  # |direction component| below this counts as parallel


def _safe(d: jax.Array) -> jax.Array:
    return jnp.where(d >= 0, jnp.maximum(d, _EPS_DIR), jnp.minimum(d, -_EPS_DIR))


def slab(o: jax.Array, d: jax.Array, lo: jax.Array, hi: jax.Array):
    """Parameter interval (t0, t1) of o + t·d inside lo ≤ coordinate ≤ hi (broadcasting)."""
    inv = 1.0 / _safe(d)
    ta, tb = (lo - o) * inv, (hi - o) * inv
    return jnp.minimum(ta, tb), jnp.maximum(ta, tb)


def _dot(a: jax.Array, b: jax.Array) -> jax.Array:
    return jnp.sum(a * b, -1)


def materialise(tree):
    """The same arrays, computed once into memory before any consumer runs.

    Per-ray gathers from a table computed in the same jit (a plant table, a freshly generated
    terrain) otherwise let XLA fuse the table's computation into the gather and redo it for
    every gathered element; `lax.optimization_barrier` does not stop that on every backend.
    A while loop whose trip count XLA cannot know is a fusion boundary everywhere: it runs once
    (twice if the first value is NaN; the body is the identity on finite and non-finite values
    alike)."""
    leaves, treedef = jax.tree.flatten(tree)
    kinds = [x.dtype for x in leaves]
    nums = [x.astype(jnp.int8) if x.dtype == jnp.bool_ else x for x in leaves]
    first = jnp.ravel(nums[0])[0]
    n = 1 + jnp.isnan(first.astype(jnp.float32)).astype(jnp.int32)

    def body(c):
        i, ys = c
        return i + 1, [y + y * 0 for y in ys]

    _, nums = jax.lax.while_loop(lambda c: c[0] < n, body, (jnp.int32(0), nums))
    out = [y.astype(k) if k == jnp.bool_ else y for y, k in zip(nums, kinds, strict=True)]
    return jax.tree.unflatten(treedef, out)


def _dot3(a, b):
    return a[0] * b[0] + a[1] * b[1] + a[2] * b[2]


def _sub3(a, b):
    return (a[0] - b[0], a[1] - b[1], a[2] - b[2])


def xyz(v: jax.Array):
    """[..., 3] → (x, y, z) components."""
    return v[..., 0], v[..., 1], v[..., 2]


# ---------------------------------------------------------------------------------------------
# Primitives (exact). Vectors are (x, y, z) tuples of broadcastable arrays: on CPU and GPU the
# component arrays vectorise far better than [..., 3] arrays.


def ellipsoid_hit(o, d, c, A, t_min):
    """Nearest t > t_min where o + t·d meets the ellipsoid {p : |A (p − c)| = 1}, else +inf.

    o, d, c: (x, y, z) tuples; A: 9 components row-major (row i = axis_i / semi-axis_i)."""
    r = _sub3(o, c)
    oo = [A[3 * i] * r[0] + A[3 * i + 1] * r[1] + A[3 * i + 2] * r[2] for i in range(3)]
    dd = [A[3 * i] * d[0] + A[3 * i + 1] * d[1] + A[3 * i + 2] * d[2] for i in range(3)]
    a = jnp.maximum(_dot3(dd, dd), 1e-30)
    tc = -_dot3(oo, dd) / a
    q = [oo[i] + tc * dd[i] for i in range(3)]  # closest point to the centre, unit-sphere space
    rest = 1.0 - _dot3(q, q)
    t = tc - jnp.sqrt(jnp.maximum(rest, 0.0) / a)
    return jnp.where((rest >= 0.0) & (t > t_min), t, INF)


def capsule_hit(o, d, c, axis, radius, half, t_min):
    """Nearest t > t_min where o + t·d meets the capsule (segment c ± half·axis, radius), else
    +inf; a zero `half` is a sphere. o, d, c, axis: (x, y, z) tuples; |d| = |axis| = 1."""
    oc = _sub3(o, c)
    r2 = radius * radius
    # infinite cylinder around the axis, then the segment's extent
    bard, baoc = _dot3(axis, d), _dot3(axis, oc)
    a = 1.0 - bard * bard
    b = _dot3(d, oc) - baoc * bard
    cc = _dot3(oc, oc) - baoc * baoc - r2
    h = b * b - a * cc
    ok_a = a > 1e-9
    t_cyl = (-b - jnp.sqrt(jnp.maximum(h, 0.0))) / jnp.where(ok_a, a, 1.0)
    y = baoc + t_cyl * bard  # position along the axis
    cyl = ok_a & (h >= 0.0) & (jnp.abs(y) <= half) & (t_cyl > t_min)
    # the two end spheres
    t_caps = INF
    for sgn in (-1.0, 1.0):
        e = (oc[0] - sgn * half * axis[0], oc[1] - sgn * half * axis[1],
             oc[2] - sgn * half * axis[2])
        bs = _dot3(d, e)
        hs = bs * bs - (_dot3(e, e) - r2)
        ts = -bs - jnp.sqrt(jnp.maximum(hs, 0.0))
        t_caps = jnp.minimum(t_caps, jnp.where((hs >= 0.0) & (ts > t_min), ts, INF))
    return jnp.minimum(jnp.where(cyl, t_cyl, INF), t_caps)


def prim_hit(kind: int, o, d, q, t_min):
    """Nearest t > t_min where o + t·d meets one plant primitive of `kind` (plants.ELLIPSOID or
    plants.CAPSULE) whose 12 table values are q (a sequence of broadcastable arrays: centre,
    then A row-major for an ellipsoid, or axis, radius, half length for a capsule), else +inf."""
    if kind == crops_prims.CAPSULE:
        return capsule_hit(o, d, q[0:3], q[3:6], q[6], q[7], t_min)
    return ellipsoid_hit(o, d, q[0:3], q[3:12], t_min)


def capsule_normal(p, c, axis, half):
    """Outward unit normal [N, 3] at p [N, 3] on a capsule's surface (c, axis [N, 3], half [N])."""
    s = jnp.clip(_dot(p - c, axis), -half, half)
    n = p - (c + s[..., None] * axis)
    return n / jnp.maximum(jnp.linalg.norm(n, axis=-1, keepdims=True), 1e-12)


# ---------------------------------------------------------------------------------------------
# Plants


@struct.dataclass
class PlantTable:
    """A field's plants prepared for ray casting (one field; R rows, P plants, K primitives).

    `prim` holds 12 numbers per primitive, one [R·P, 12] table per primitive slot k (a tile's
    gather of its candidates' slot k is one gather of whole rows, already in the order the
    exact tests consume): ellipsoid = centre (3), A (3×3 row-major, row i = axis_i /
    semi-axis_i); capsule = centre (3), axis (3), radius, half length, 4 zeros. `box_t` is each
    plant's axis-aligned bounding box (x lo, x hi, y lo, y hi, z lo, z hi); an inactive plant
    has an empty box. `block_t` holds the boxes of blocks of BLOCK consecutive plants of a
    row, `seg_t` the strips around segments of `seg` consecutive plant slots of a row
    (`render.rows`), through which a tile finds the blocks it can meet on straight and curved
    rows alike."""

    prim: jax.Array  # float32 [K, R·P, 12]
    box_t: jax.Array  # float32 [6, R·P] [m]
    block_t: jax.Array  # float32 [6, R·NB] [m], boxes of BLOCK consecutive plants of a row
    seg_t: jax.Array  # float32 [12, R·NS], segments of `seg` plant slots (`rows.segments`)
    base: jax.Array  # float32 [R·P, 3]: base z [m], height [m], phase [0, 1)
    row_y: jax.Array  # float32 [R], row centre lines: their u in field coordinates [m]
    row_zlo: jax.Array  # float32 [R], lowest point of any plant of the row [m]
    row_zhi: jax.Array  # float32 [R], highest point of any plant of the row [m]
    reach_y: jax.Array  # float32 [], largest reach of a plant's box corner across its row
    # (in u) [m]
    bend: field_lanes.Bend  # the rows' centre line (`mjxrow.field.lanes`)
    kind: np.ndarray = struct.field(pytree_node=False)  # int [K], plants.ELLIPSOID / CAPSULE
    material: np.ndarray = struct.field(pytree_node=False)  # int [K], plants.LEAF ...
    seg: int = struct.field(pytree_node=False, default=BLOCK)  # plant slots per segment


def prim_rows(pr: crops_prims.Prims) -> tuple[jax.Array, jax.Array, jax.Array]:
    """The ray-casting rows of primitives `pr` ([..., K] leading axes flattened to N items):
    (prim float32 [K, N, 12] (see PlantTable), lo, hi float32 [N, 3]: each item's axis-aligned
    box over its K primitives, from the primitives themselves)."""
    K = pr.kind.shape[0]
    rot, size, c = pr.rot, pr.size, pr.centre
    lead = c.shape[:-2]
    is_caps = jnp.asarray(pr.kind == crops_prims.CAPSULE)
    # ellipsoid A = diag(1/size) · rotᵀ ; capsule (axis, r, h)
    A = jnp.swapaxes(rot, -1, -2) / jnp.maximum(size[..., :, None], 1e-6)
    axis = rot[..., :, 2]
    caps = jnp.concatenate([axis, size[..., :1], size[..., 2:3], jnp.zeros(size.shape[:-1] + (4,))],
                           -1)
    data = jnp.where(is_caps[:, None], caps, A.reshape(A.shape[:-2] + (9,)))
    prim = jnp.moveaxis(jnp.concatenate([c, data], -1).reshape(-1, K, 12), 1, 0)
    # axis-aligned half extents of each primitive (elementwise: no tiny matrix products)
    rs = rot * size[..., None, :]
    ext_e = jnp.sqrt(rs[..., 0] ** 2 + rs[..., 1] ** 2 + rs[..., 2] ** 2)
    ext_c = jnp.abs(axis) * size[..., 2:3] + size[..., :1]
    ext = jnp.where(is_caps[:, None], ext_c, ext_e)  # [..., K, 3]
    lo = jnp.min(c - ext, axis=-2).reshape(lead + (3,))
    hi = jnp.max(c + ext, axis=-2).reshape(lead + (3,))
    return prim, lo, hi


def plant_table(field: mjxrow_field.Field, shape: mjxrow_field.FieldShape) -> PlantTable:
    """Primitive table, bounding boxes and row segments of one field (pure; cost ~R·P·K,
    small next to the rays). Every bound comes from the actual primitives, so culling never
    drops a plant that reaches into a box."""
    pr = crops_prims.plant_prims(field, shape)
    R, P, K = pr.active.shape
    prim, lo, hi = prim_rows(pr)
    act = field.plant_active
    big = jnp.float32(1e9)
    lo = jnp.where(act[..., None], lo, big)
    hi = jnp.where(act[..., None], hi, -big)
    box = jnp.stack([lo[..., 0], hi[..., 0], lo[..., 1], hi[..., 1], lo[..., 2], hi[..., 2]])
    nb = -(-P // BLOCK)
    pad = jnp.stack([jnp.full((R, nb * BLOCK - P), v) for v in (big, -big) * 3])
    blk = jnp.concatenate([box, pad], -1).reshape(6, R, nb, BLOCK)
    blk = jnp.concatenate([jnp.min(blk[0::2], -1), jnp.max(blk[1::2], -1)])[jnp.array(
        [0, 3, 1, 4, 2, 5])]
    seg = render_rows.segment_plants(shape.crop, P)
    seg_t = render_rows.segments(field, lo, hi, act, seg)
    # reach across the rows (the ground's occlusion): the boxes' corners in field coordinates
    # (on a straight field u = y, and this is max(y hi − row_y, row_y − y lo))
    bend = field_lanes.field_bend(field)
    lat = jnp.full((R, P), -jnp.inf)
    for cx in (lo[..., 0], hi[..., 0]):
        for cy in (lo[..., 1], hi[..., 1]):
            u = field_lanes.to_field(bend, cx, cy)[1] - field.row_y[:, None]
            lat = jnp.maximum(lat, jnp.maximum(u, -u))
    reach_y = jnp.max(jnp.where(act, lat, 0.0))
    base = jnp.stack([field.plant_pos[..., 2], field.plant_size[..., 2], field.plant_phase], -1)
    prim, box_t, block_t, seg_t, base = materialise(
        (prim, box.reshape(6, R * P), blk.reshape(6, R * nb), seg_t, base.reshape(R * P, 3)))
    return PlantTable(prim=prim, box_t=box_t, block_t=block_t, seg_t=seg_t, base=base,
                      row_y=field.row_y, row_zlo=jnp.min(lo[..., 2], axis=1),
                      row_zhi=jnp.max(hi[..., 2], axis=1), reach_y=reach_y, bend=bend,
                      kind=np.asarray(pr.kind), material=np.asarray(pr.material), seg=seg)


def unroll() -> bool:
    """Unroll loops over primitives on accelerators (speed); keep them rolled on CPU, where
    compile time dominates the small batches it runs."""
    return jax.default_backend() != "cpu"


def nearest_prim(tab: PlantTable, flat, o, d, t_min, t_max):
    """Nearest primitive hit of each candidate plant `flat` (int32 [N, C] indices into the
    table), one gather per primitive (reference and tests; the renderer uses
    `render_tiles.exact`). o, d: (x, y, z) tuples of [N, 1]; t_min, t_max: [N, 1].
    Returns (t [N, C] (+inf: none in (t_min, t_max)), k int32 [N, C])."""
    t_best = jnp.full(flat.shape, INF)
    k_best = jnp.zeros(flat.shape, jnp.int32)
    for kd in (crops_prims.ELLIPSOID, crops_prims.CAPSULE):
        ks = np.flatnonzero(tab.kind == kd)
        if len(ks) == 0:
            continue

        def body(carry, x, kd=kd):
            t_b, k_b = carry
            rows, k = x
            t = prim_hit(kd, o, d, [rows[:, i][flat] for i in range(12)], t_min)  # [N, C]
            better = t < jnp.minimum(t_b, t_max)
            return (jnp.where(better, t, t_b), jnp.where(better, k, k_b)), None

        xs = (tab.prim[ks], jnp.asarray(ks, jnp.int32))
        (t_best, k_best), _ = jax.lax.scan(body, (t_best, k_best), xs,
                                           unroll=len(ks) if unroll() else 1)
    return t_best, k_best


def plant_normal(tab: PlantTable, plant, k, p):
    """At hit points p [N, 3] of primitive k [N] of plant [N]: (outward unit normal [N, 3],
    the point in the primitive's own frame [N, 3]: on an ellipsoid the unit-sphere point
    (semi-axis units), on a capsule (0, 0, position along the axis / half length))."""
    K, RP = tab.prim.shape[:2]
    row = tab.prim.reshape(K * RP, 12)[k * RP + plant]  # [N, 12]
    c, A = row[:, :3], [row[:, 3 + i] for i in range(9)]
    r = xyz(p - c)
    u = [A[3 * i] * r[0] + A[3 * i + 1] * r[1] + A[3 * i + 2] * r[2] for i in range(3)]  # A r
    n_e = [A[j] * u[0] + A[3 + j] * u[1] + A[6 + j] * u[2] for j in range(3)]  # Aᵀ A r
    axis = xyz(row[:, 3:6])
    half = row[:, 7]
    along = _dot3(r, axis)
    s = jnp.clip(along, -half, half)
    n_c = [r[j] - s * axis[j] for j in range(3)]
    is_caps = jnp.asarray(tab.kind == crops_prims.CAPSULE)[k]
    n = [jnp.where(is_caps, n_c[j], n_e[j]) for j in range(3)]
    inv = 1.0 / jnp.maximum(jnp.sqrt(_dot3(n, n)), 1e-12)
    u_c = along / jnp.maximum(half, 1e-6)
    zero = jnp.zeros_like(u_c)
    local = [jnp.where(is_caps, zero, u[0]), jnp.where(is_caps, zero, u[1]),
             jnp.where(is_caps, u_c, u[2])]
    return jnp.stack([x * inv for x in n], -1), jnp.stack(local, -1)


# ---------------------------------------------------------------------------------------------
# Obstacles (stones = capsules of zero length, branches = horizontal capsules)


def obstacle_table(field: mjxrow_field.Field, cam_pos, forward, n: int):
    """The `n` active obstacles nearest the camera and not behind it: (centre [n, 3],
    axis [n, 3], radius [n], half length [n], ok bool [n], is_branch bool [n])."""
    rel = field.obst_pos - cam_pos
    dist = jnp.linalg.norm(rel, axis=-1)
    ahead = _dot(rel, forward) > -field.obst_size[:, 1] - field.obst_size[:, 0] - 0.5
    score = jnp.where(field.obst_active & ahead, dist, INF)
    _, idx = jax.lax.top_k(-score, n)
    yaw = field.obst_yaw[idx]
    axis = jnp.stack([jnp.cos(yaw), jnp.sin(yaw), jnp.zeros_like(yaw)], -1)
    half = jnp.where(field.obst_kind[idx] == mjxrow_field.BRANCH, field.obst_size[idx, 1], 0.0)
    return (field.obst_pos[idx], axis, field.obst_size[idx, 0], half, jnp.isfinite(score[idx]),
            field.obst_kind[idx] == mjxrow_field.BRANCH)


def obstacle_boxes(obst):
    """Axis-aligned boxes of an obstacle table's capsules (6 arrays [n]: x lo, x hi, y lo, ...;
    empty (lo > hi) where not ok)."""
    c, axis, rad, half, ok, _ = obst
    ext = jnp.abs(axis) * half[:, None] + rad[:, None]
    lo = jnp.where(ok[:, None], c - ext, 1e9)
    hi = jnp.where(ok[:, None], c + ext, -1e9)
    return [lo[:, 0], hi[:, 0], lo[:, 1], hi[:, 1], lo[:, 2], hi[:, 2]]


def trace_obstacles_tiled(obst, ids, entry, o, d, t_min, any_hit: bool = False):
    """Nearest obstacle hit of tile rays ([T, P] arrays; o, d: (x, y, z) tuples, o may be
    [1, 1]) among their tile's obstacles: ids int32 [T, m] into the table (`obstacle_table`),
    entry [T, m] a lower bound of the tile rays' distances (+inf: none). One obstacle slot at
    a time (elementwise over the rays). Returns (t [T, P] (+inf: none), normal [T·P, 3]
    (flat), is_branch [T, P]); with any_hit, t only."""
    c, axis, rad, half, _, branch = obst
    col = lambda v: v[:, None]  # noqa: E731  [T] → [T, 1]

    def body(carry, x):
        t_b, j_b = carry
        j, ent = x
        t = capsule_hit(o, d, tuple(map(col, xyz(c[j]))), tuple(map(col, xyz(axis[j]))),
                        col(rad[j]), col(half[j]), t_min)
        better = col(jnp.isfinite(ent)) & (t < t_b)
        return (jnp.where(better, t, t_b), jnp.where(better, col(j), j_b)), None

    m = ids.shape[1]
    init = (jnp.full(t_min.shape, INF), jnp.zeros(t_min.shape, jnp.int32))
    (t_best, j_best), _ = jax.lax.scan(body, init, (ids.T, entry.T),
                                       unroll=m if unroll() else 1)
    if any_hit:
        return t_best
    t0 = jnp.where(jnp.isfinite(t_best), t_best, 0.0)
    p = jnp.stack([o[i] + t0 * d[i] for i in range(3)], -1).reshape(-1, 3)
    jb = j_best.reshape(-1)
    normal = capsule_normal(p, c[jb], axis[jb], half[jb])
    return t_best, normal, branch[jb].reshape(t_best.shape)


def trace_obstacles(obst, o, d, t_min, any_hit: bool = False):
    """Nearest hit of rays o, d [N, 3] (t_min [N]) among all of a table's obstacles:
    (t [N] (+inf: none), normal [N, 3], is_branch bool [N]); with any_hit, t only.
    `trace_obstacles_tiled` with one tile holding every ray and every obstacle."""
    n = obst[0].shape[0]
    ids = jnp.arange(n, dtype=jnp.int32)[None]
    entry = jnp.where(obst[4], 0.0, INF)[None]
    row = lambda v: tuple(v[None, :, i] for i in range(3))  # noqa: E731  [N, 3] → [1, N] ×3
    out = trace_obstacles_tiled(obst, ids, entry, row(o), row(d), t_min[None], any_hit)
    if any_hit:
        return out[0]
    t, normal, branch = out
    return t[0], normal, branch[0]
