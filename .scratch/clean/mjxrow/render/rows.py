"""The rows' structure for culling (`render.tiles`): every row cut into segments of a static
number of plant slots, each bounded by a strip along its chord. Pure jnp, one field; no jit.

Rows follow the field's centre line (`mjxrow.field.lanes`: straight, a sinusoid, concentric
arcs), so no single slab across y bounds a row. A segment's chord runs from the nominal place
of its first plant slot to that of its last (`lanes.to_world`); the strip is everything within
the segment's plants' boxes measured along the chord (e) and across it (n = e turned by +90°),
and within their height band: an oriented box around the segment that holds every one of its
plants' primitives, whatever the rows' shape (the bounds come from the actual boxes). Along
the chord a plant's place is modelled as linear in its slot, m·δ (δ: the chord's length per
slot); `reach` bounds every plant box's distance from that model (jitter, the plant's size and
the bend of the row inside the segment), so that an interval along the chord gives the slots it
can meet in closed form. On a straight field every chord is the row's line (e = (1, 0) exactly)
and the strips are the old per-row slabs cut into pieces.

Segments hold `segment_plants(crop, P)` slots (whole blocks of `BLOCK`): about SEG_LENGTH metres
at the crop's preset spacing, short enough that an arc or a sinusoid stays near its chord, long
enough that a tile tests a few per row.
"""

from __future__ import annotations

import jax
import jax.numpy as jnp
import numpy as np

from mjxrow import crops
from mjxrow import field as mjxrow_field
from mjxrow.field import lanes as field_lanes
from mjxrow.field import params as field_params

BLOCK = 4  # plants per block of the first culling level (geom.BLOCK)
SEG_LENGTH = 6.0  # m, nominal length of a segment at the crop's preset plant spacing
# rows of the segment table `segments` returns
(SEG_AX, SEG_AY, SEG_EX, SEG_EY, SEG_LAT_LO, SEG_LAT_HI, SEG_AL_LO, SEG_AL_HI, SEG_Z_LO, SEG_Z_HI,
 SEG_STEP, SEG_REACH) = range(12)
BIG = 1e9


def segment_plants(crop: str, n_plants: int) -> int:
    """Plant slots per segment (static): whole blocks covering about SEG_LENGTH metres at the
    crop's preset spacing, at least one block, at most the row."""
    d_pp = float(crops.get(crop).preset["d_pp"]) * float(crops.get(crop).preset["scale"])
    blocks = max(1, int(round(SEG_LENGTH / (BLOCK * d_pp))))
    return BLOCK * min(blocks, -(-n_plants // BLOCK))


def segments(field: mjxrow_field.Field, lo: jax.Array, hi: jax.Array, active: jax.Array,
             seg: int) -> jax.Array:
    """The segment table of one field: float32 [12, R·NS] (rows SEG_*: chord origin (x, y),
    unit direction (x, y), the plants' boxes across and along the chord relative to the origin
    (lo, hi), their height band (lo, hi; lo > hi: no plant), the chord's length per slot δ, the
    along reach), segment j of row r in column r·NS + j, NS = ceil(P / seg).
    lo, hi: float32 [R, P, 3], the plants' axis-aligned boxes [m]; active: bool [R, P]."""
    R, P = active.shape
    ns = -(-P // seg)
    pad = ns * seg - P
    bend = field_lanes.field_bend(field)
    d_pp = field_params._scaled(field.params)["d_pp"]
    j = jnp.arange(ns, dtype=jnp.float32)
    s0 = field.row_x[0] + (j * seg) * d_pp  # [NS], the first and the last slot of a segment
    s1 = field.row_x[0] + (j * seg + (seg - 1)) * d_pp
    u = field.row_y[:, None]
    ax, ay = field_lanes.to_world(bend, s0[None, :], u)  # [R, NS]
    bx, by = field_lanes.to_world(bend, s1[None, :], u)
    dx, dy = bx - ax, by - ay
    chord = jnp.sqrt(dx * dx + dy * dy)
    safe = jnp.maximum(chord, 1e-9)
    ex = jnp.where(chord > 0, dx / safe, 1.0)
    ey = jnp.where(chord > 0, dy / safe, 0.0)
    step = jnp.maximum(chord / (seg - 1), 1e-6)

    def per_seg(v, fill):  # [R, P, ...] → [R, NS, seg, ...]
        width = [(0, 0), (0, pad)] + [(0, 0)] * (v.ndim - 2)
        v = jnp.pad(v, width, constant_values=fill)
        return v.reshape((R, ns, seg) + v.shape[2:])

    act = per_seg(active, False)
    blo, bhi = per_seg(lo, 0.0), per_seg(hi, 0.0)
    cx, cy = 0.5 * (blo[..., 0] + bhi[..., 0]), 0.5 * (blo[..., 1] + bhi[..., 1])
    hx, hy = 0.5 * (bhi[..., 0] - blo[..., 0]), 0.5 * (bhi[..., 1] - blo[..., 1])
    ex_, ey_ = ex[..., None], ey[..., None]
    rx, ry = cx - ax[..., None], cy - ay[..., None]
    pe = rx * ex_ + ry * ey_  # box centre along the chord
    pn = ry * ex_ - rx * ey_  # and across it
    he = hx * jnp.abs(ex_) + hy * jnp.abs(ey_)  # box half extents along and across
    hn = hx * jnp.abs(ey_) + hy * jnp.abs(ex_)
    m = jnp.arange(seg, dtype=jnp.float32)
    reach = jnp.max(jnp.where(act, jnp.abs(pe - m * step[..., None]) + he, 0.0), -1)

    def lo_hi(a, b):
        return (jnp.min(jnp.where(act, a, BIG), -1), jnp.max(jnp.where(act, b, -BIG), -1))

    lat = lo_hi(pn - hn, pn + hn)
    along = lo_hi(pe - he, pe + he)
    z = lo_hi(blo[..., 2], bhi[..., 2])
    tab = jnp.stack([ax, ay, ex, ey, *lat, *along, *z, step, reach])  # [12, R, NS]
    return tab.reshape(12, R * ns).astype(jnp.float32)


def first_slots(n_seg: int, seg: int) -> np.ndarray:
    """float32 [n_seg]: the first slot of each segment column of a row (static)."""
    return (np.arange(n_seg) * seg).astype(np.float32)
