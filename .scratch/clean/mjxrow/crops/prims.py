"""The geometry of the crops' plants, defined once for the renderer, the exports and the
collision check: every plant is a fixed number K of primitives (ellipsoids and capsules). The
builders here (`rosette`, `upright`, `vertical_capsule`, `compose`) are what the crop modules
compose their `Crop.local` from; `plant_prims`, `n_prims` and `footprint` look the crop up in
the registry (`mjxrow.crops.get`) when called.

A primitive is (type, material, centre, rotation, size):
- ellipsoid: `size` = its three semi-axes along the columns of `rot` [m];
- capsule: axis along `rot[:, 2]`, `size` = (radius, radius, half length of the segment) [m].
"""

from __future__ import annotations

from typing import TYPE_CHECKING

import jax
import jax.numpy as jnp
import numpy as np
from flax import struct

from mjxrow import crops

if TYPE_CHECKING:
    from mjxrow.field import Field, FieldShape

ELLIPSOID, CAPSULE = 0, 1
LEAF, STEM, TRUNK, CANOPY, FRUIT, WEED = 0, 1, 2, 3, 4, 5
MATERIAL_NAMES = ("leaf", "stem", "trunk", "canopy", "fruit", "weed")
# the weeds' own colours (every crop's weeds): dark and light leaf green, and a yellow-green
WEED_PALETTE = ((0.30, 0.50, 0.10), (0.48, 0.62, 0.18), (0.58, 0.66, 0.20))


@struct.dataclass
class Prims:
    """Primitives of all plants of a field. K = primitives per plant (static per crop)."""

    centre: jax.Array  # float32 [R, P, K, 3], world frame [m]
    rot: jax.Array  # float32 [R, P, K, 3, 3], columns = primitive axes in the world frame
    size: jax.Array  # float32 [R, P, K, 3], semi-axes or (r, r, half length) [m]
    active: jax.Array  # bool [R, P, K]
    kind: np.ndarray = struct.field(pytree_node=False)  # int [K], ELLIPSOID or CAPSULE
    material: np.ndarray = struct.field(pytree_node=False)  # int [K], LEAF ... FRUIT


def _rot(yaw, pitch):
    """Rz(yaw) @ Ry(-pitch): local x tilted up by `pitch`, then turned by `yaw`. [..., 3, 3]
    (written out element by element: no tiny matrix products)."""
    cy, sy, cp, sp = jnp.cos(yaw), jnp.sin(yaw), jnp.cos(pitch), jnp.sin(pitch)
    z = jnp.zeros_like(cy)
    return jnp.stack([jnp.stack([cy * cp, -sy, -cy * sp], -1),
                      jnp.stack([sy * cp, cy, -sy * sp], -1),
                      jnp.stack([sp, z, cp], -1)], -2)


def rosette(L, W, H, yaw, phase, n, reach, leaf_len, leaf_wid, leaf_thick, tilt, z_frac,
            upright=False):
    """n leaves around the plant axis, tips reaching `reach` of the half extents. The leaf
    semi-length is `leaf_len` of the half extent, or of the height for `upright` leaves.
    Local frame: [..., n, 3] centres, [..., n, 3, 3] rotations, [..., n, 3] sizes."""
    a = yaw[..., None] + (jnp.arange(n) + 0.3 * phase[..., None]) * (2 * jnp.pi / n)
    half = jnp.sqrt((0.5 * L[..., None] * jnp.cos(a)) ** 2 + (0.5 * W[..., None] * jnp.sin(a)) ** 2)
    lx = leaf_len * (jnp.broadcast_to(H[..., None], a.shape) if upright else half)
    r = reach * half - lx * jnp.cos(tilt)
    z = jnp.broadcast_to(z_frac * H[..., None], a.shape)
    centre = jnp.stack([r * jnp.cos(a), r * jnp.sin(a), z], -1)
    rot = _rot(a, jnp.full_like(a, tilt))
    size = jnp.stack([lx, leaf_wid * half, jnp.broadcast_to(leaf_thick * H[..., None], a.shape)],
                     -1)
    return centre, rot, size


def upright(L, W, H, n):
    """A centred, axis-aligned element (head, mound, canopy) with semi-axes n[:3] of (L, W, H)
    at height n[3]·H."""
    c = jnp.stack([jnp.zeros_like(L), jnp.zeros_like(L), n[3] * H], -1)
    s = jnp.stack([n[0] * L, n[1] * W, n[2] * H], -1)
    rot = jnp.broadcast_to(jnp.eye(3), L.shape + (3, 3))
    return c[..., None, :], rot[..., None, :, :], s[..., None, :]


def vertical_capsule(H, r, z0, z1):
    """A vertical capsule of radius r [m] (trunk) from height z0·H to z1·H."""
    c = jnp.stack([jnp.zeros_like(H), jnp.zeros_like(H), 0.5 * (z0 + z1) * H], -1)
    rot = jnp.broadcast_to(jnp.eye(3), H.shape + (3, 3))
    s = jnp.stack([r, r, jnp.maximum(0.5 * (z1 - z0) * H - r, 1e-3)], -1)
    return c[..., None, :], rot[..., None, :, :], s[..., None, :]


def compose(parts):
    """Concatenate the (centre, rot, size) of several parts along the primitive axis K."""
    return tuple(jnp.concatenate([p[i] for p in parts], axis=-2 if i != 1 else -3)
                 for i in range(3))


def turn(centre: jax.Array, rot: jax.Array, heading: jax.Array) -> tuple[jax.Array, jax.Array]:
    """Local primitives ([..., K, 3] centres, [..., K, 3, 3] rotations) turned about z by
    `heading` [...] [rad] (written out: at heading 0 the values are unchanged to the bit)."""
    c, s = jnp.cos(heading)[..., None], jnp.sin(heading)[..., None]
    centre = jnp.stack([c * centre[..., 0] - s * centre[..., 1],
                        s * centre[..., 0] + c * centre[..., 1], centre[..., 2]], -1)
    c, s = c[..., None], s[..., None]
    rot = jnp.stack([c * rot[..., 0, :] - s * rot[..., 1, :],
                     s * rot[..., 0, :] + c * rot[..., 1, :], rot[..., 2, :]], -2)
    return centre, rot


def plant_prims(field: Field, shape: FieldShape) -> Prims:
    """World-frame primitives of every plant of one field (pure; vmap for a batch). A plant's
    length axis follows its row (`Field.plant_heading`)."""
    L, W, H = (field.plant_size[..., i] for i in range(3))
    centre, rot, size, kind, mat = crops.get(shape.crop).local(L, W, H, field.plant_yaw,
                                                                field.plant_phase)
    centre, rot = turn(centre, rot, field.plant_heading)
    centre = centre + field.plant_pos[..., None, :]
    active = jnp.broadcast_to(field.plant_active[..., None], centre.shape[:-1])
    return Prims(centre=centre, rot=rot, size=size, active=active, kind=kind, material=mat)


def weed_local(D, Hw, yaw, phase):
    """A weed: 4 flat leaves spread low around the centre and a small upright one, K = 5
    ellipsoids of material WEED (diameter D, height Hw [m], [...] arrays)."""
    parts = [rosette(D, D, Hw, yaw, phase, 4, 0.95, 0.55, 0.30, 0.18, 0.35, 0.30),
             upright(D, D, Hw, (0.12, 0.12, 0.45, 0.45))]
    return (*compose(parts), np.asarray([ELLIPSOID] * 5), np.asarray([WEED] * 5))


def weed_prims(field: Field) -> Prims:
    """World-frame primitives of every weed of one field ([W, K] instead of [R, P, K]; W may be
    0). Weeds are the same for every crop: not crop pixels, not obstacles."""
    D, Hw = field.weed_size[..., 0], field.weed_size[..., 1]
    centre, rot, size, kind, mat = weed_local(D, Hw, field.weed_yaw, field.weed_phase)
    centre = centre + field.weed_pos[..., None, :]
    active = jnp.broadcast_to(field.weed_active[..., None], centre.shape[:-1])
    return Prims(centre=centre, rot=rot, size=size, active=active, kind=kind, material=mat)


def n_prims(crop: str) -> int:
    """K, the primitives per plant of `crop`."""
    one = jnp.ones((1,))
    return len(crops.get(crop).local(one, one, one, one * 0, one * 0)[3])


def footprint(crop: str, plant_size: jax.Array) -> jax.Array:
    """Collision footprint of each plant as an ellipse along its row: semi-axes (along the
    row, across it) [..., 2] in metres, from plant_size [..., 3] (turned by the plant's
    `plant_heading`; axis-aligned on straight rows). The trunk for crops with a `trunk_radius`
    (pear, vineyard), half the plant's length and width otherwise (the leaves of low crops)."""
    r = crops.get(crop).trunk_radius
    if r is not None:
        return jnp.full(plant_size.shape[:-1] + (2,), r)
    return 0.5 * plant_size[..., :2]
