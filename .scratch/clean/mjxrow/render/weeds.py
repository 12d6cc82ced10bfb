"""Weeds for the renderer: the frame's nearest weeds in view, culled per tile and intersected
exactly by the plants' kernels. Pure jnp, one field and one camera; no jit here.

A field holds hundreds to thousands of weeds (`Field.weed_*`, W = `FieldShape.weed_slots`;
none when W = 0, and then the renderer does no weed work at all). Each frame keeps the
`RenderConfig.weeds` active weeds nearest the camera whose bounding spheres (radius: the weed's
diameter plus (1 + SHADOW_HEIGHTS) heights, so that a weed just outside the view still casts
its shadow into it) reach into the camera's view cone (`table`): a weed under a camera that
looks down is in it, one behind the camera is not. Their primitives (`crops.prims.weed_local`,
K = 5 ellipsoids of material WEED) make a table laid out as the plants' (`geom.PlantTable`'s
`prim`, `kind`), so `render.tiles.exact` tests them with any kernel; each tile keeps the
`weed_keep` weeds its sweep enters first (`render.tiles.cull_weeds`, the plants' entry bound).

Limits: beyond the `weeds` nearest in view no weed is drawn (at 64 × 64 pixels a weed of 8 cm
is about one pixel wide 7 m away; with 2 weeds per m² the 64 nearest reach about 9 m ahead);
a tile whose rays meet more than `weed_keep` weeds before their hits can miss the farther ones.
"""

from __future__ import annotations

import jax
import jax.numpy as jnp
import numpy as np
from flax import struct

from mjxrow import field as mjxrow_field
from mjxrow.crops import prims as crops_prims
from mjxrow.render import geom
from mjxrow.render.config import Intrinsics

INF = jnp.inf
SHADOW_HEIGHTS = 3.0  # weed heights added to the selection radius: shadows of suns ≥ 18° high


@struct.dataclass
class WeedTable:
    """A frame's weeds prepared for ray casting (n of them; inactive slots have empty boxes)."""

    prim: jax.Array  # float32 [K, n, 12], as PlantTable.prim (K = 5 ellipsoids)
    box_t: jax.Array  # float32 [6, n] [m], axis-aligned boxes (x lo, x hi, y lo, ... z hi)
    base: jax.Array  # float32 [n, 3]: base z [m], height [m], phase [0, 1)
    index: jax.Array  # int32 [n], the weed's slot in the field (its colour and texture seed)
    kind: np.ndarray = struct.field(pytree_node=False)  # int [K], crops.prims.ELLIPSOID
    material: np.ndarray = struct.field(pytree_node=False)  # int [K], crops.prims.WEED


def radius(field: mjxrow_field.Field) -> jax.Array:
    """float32 [W]: a radius around each weed's base point holding all its primitives [m]
    (the leaves reach about half the diameter out and the height up; tested)."""
    return field.weed_size[:, 0] + field.weed_size[:, 1]


def _build(field: mjxrow_field.Field, idx: jax.Array, ok: jax.Array) -> WeedTable:
    """The table of weed slots idx int32 [n] (ok bool [n]: drawn)."""
    size = field.weed_size[idx]
    centre, rot, sz, kind, mat = crops_prims.weed_local(size[:, 0], size[:, 1],
                                                        field.weed_yaw[idx], field.weed_phase[idx])
    pr = crops_prims.Prims(centre=centre + field.weed_pos[idx][:, None, :], rot=rot, size=sz,
                           active=jnp.broadcast_to(ok[:, None], centre.shape[:-1]),
                           kind=np.asarray(kind), material=np.asarray(mat))
    prim, lo, hi = geom.prim_rows(pr)
    lo = jnp.where(ok[:, None], lo, 1e9)
    hi = jnp.where(ok[:, None], hi, -1e9)
    box = jnp.stack([lo[:, 0], hi[:, 0], lo[:, 1], hi[:, 1], lo[:, 2], hi[:, 2]])
    base = jnp.stack([field.weed_pos[idx, 2], size[:, 1], field.weed_phase[idx]], -1)
    return WeedTable(prim=prim, box_t=box, base=base, index=idx.astype(jnp.int32),
                     kind=np.asarray(kind), material=np.asarray(mat))


def table(field: mjxrow_field.Field, cam_pos: jax.Array, cam_rot: jax.Array, intr: Intrinsics,
          n: int) -> WeedTable:
    """The `n` active weeds nearest the camera (cam_pos [3], cam_rot [3, 3] as `render`'s)
    that can be seen or cast a shadow into the view (module doc). n ≤ W, static."""
    fwd = -cam_rot[:, 2]
    ty = np.tan(np.deg2rad(intr.fovy) / 2)
    half = float(np.arctan(np.hypot(ty, ty * intr.width / intr.height)))  # the view's corners
    rel = field.weed_pos - cam_pos
    dist = jnp.sqrt(jnp.sum(rel * rel, -1))
    rho = radius(field) + SHADOW_HEIGHTS * field.weed_size[:, 1]
    cos_a = jnp.sum(rel * fwd, -1) / jnp.maximum(dist, 1e-9)
    angle = jnp.arccos(jnp.clip(cos_a, -1.0, 1.0))
    seen = (dist <= rho) | (angle <= half + jnp.arcsin(jnp.minimum(rho / jnp.maximum(dist, 1e-9),
                                                                    1.0)))
    score = jnp.where(field.weed_active & seen, dist, INF)
    neg, idx = jax.lax.top_k(-score, n)
    return _build(field, idx, jnp.isfinite(neg))


def all_weeds(field: mjxrow_field.Field) -> WeedTable:
    """Every weed slot of the field (references and tests)."""
    W = field.weed_pos.shape[0]
    return _build(field, jnp.arange(W, dtype=jnp.int32), field.weed_active)
