"""Curved rows: the field frame and lane centre lines.

A field is laid out in field coordinates (s, u): s along the rows [m] (the x of a straight
field; plant i of a row sits at s = row_x[0] + i·d_pp), u across them [m] (the y of a straight
field; a row's u is its `row_y`, a lane's its `lane_y`). Every row follows one common centre
line, in two steps:

1. the sinusoid v = u + A·sin(2πs/λ + φ) (`row_amplitude` A, `row_wavelength` λ, the field's
   own phase φ = `Field.row_phase`): every row is the same curve shifted across, so the
   distance between rows measured across them (along y) stays d_rr / d_RR;
2. the bend into concentric arcs of curvature κ (`row_curvature`; centre of curvature at
   (0, 1/κ): κ > 0 bends the rows towards +y): (s, v) ↦ the point at arc length s along the
   arc through the origin, v to the left of it. Rows stay exactly d_rr apart along the radius.

With A = 0 and κ = 0 both steps are the identity, exactly (x = s, y = u), so a straight field
is today's field to the bit. `Lane` is one lane's centre line (its u) with the s of its end
(the goal); `project` gives a point's position along a lane, its signed offset from the
centre line and the line's direction there, which the oracle, the metrics, the goal and the
rewards use.
"""

from __future__ import annotations

import jax
import jax.numpy as jnp
from flax import struct

from mjxrow.field.params import Field, _scaled


@struct.dataclass
class Bend:
    """The common centre line of a field's rows (scalars, or [B] for a batch)."""

    curvature: jax.Array  # κ [1/m], 0: straight
    amplitude: jax.Array  # A [m] of the sinusoid, 0: straight
    wavelength: jax.Array  # λ [m] of the sinusoid (> 0)
    phase: jax.Array  # φ [rad] of the sinusoid at s = 0


@struct.dataclass
class Lane:
    """One lane's centre line: the curve u = `u` of its field's bend, driven towards +s; the
    goal is its point at s = `s_end` (the end of the rows)."""

    u: jax.Array  # lateral field coordinate of the centre line [m] (a straight field's y)
    s_end: jax.Array  # s of the lane's end, the goal [m]
    bend: Bend


def straight() -> Bend:
    """The bend of a straight field (the identity)."""
    z = jnp.zeros((), jnp.float32)
    return Bend(curvature=z, amplitude=z, wavelength=jnp.ones((), jnp.float32), phase=z)


def straight_lane(u, s_end) -> Lane:
    """The lane of a straight field: the line y = u, ending at x = s_end."""
    return Lane(u=jnp.asarray(u, jnp.float32), s_end=jnp.asarray(s_end, jnp.float32),
                bend=straight())


def field_bend(field: Field) -> Bend:
    """The bend of `field` (one field, or a batch)."""
    q = _scaled(field.params)
    return Bend(curvature=q["row_curvature"], amplitude=q["row_amplitude"],
                wavelength=q["row_wavelength"],
                phase=field.row_phase)


def lane(field: Field, index: jax.Array) -> Lane:
    """Lane `index` (int32 []) of one field, ending at the end of the rows."""
    return Lane(u=field.lane_y[index], s_end=field.row_x[1], bend=field_bend(field))


def wave(b: Bend, s: jax.Array) -> tuple[jax.Array, jax.Array]:
    """(A·sin(2πs/λ + φ), its derivative d/ds) at s."""
    k = 2.0 * jnp.pi / b.wavelength
    arg = k * s + b.phase
    return b.amplitude * jnp.sin(arg), b.amplitude * k * jnp.cos(arg)


def _sinc(a: jax.Array) -> jax.Array:
    """sin(a) / a (1 at 0)."""
    return jnp.sinc(a / jnp.pi)


def to_world(b: Bend, s: jax.Array, u: jax.Array) -> tuple[jax.Array, jax.Array]:
    """World (x, y) [m] of field coordinates (s, u) (any broadcastable shapes)."""
    v = u + wave(b, s)[0]
    k = b.curvature
    a = k * s
    x = (1.0 - k * v) * s * _sinc(a)
    y = s * jnp.sin(0.5 * a) * _sinc(0.5 * a) + v * jnp.cos(a)
    return x, y


def to_field(b: Bend, x: jax.Array, y: jax.Array) -> tuple[jax.Array, jax.Array]:
    """Field coordinates (s, u) [m] of world (x, y): the inverse of `to_world` (exact on the
    arcs; on the sinusoid u is read at the point's own s)."""
    k = b.curvature
    a, c = k * x, 1.0 - k * y
    safe = jnp.where(k == 0, 1.0, k)
    s = jnp.where(k == 0, x, jnp.arctan2(a, c) / safe)
    h = jnp.sqrt(a * a + c * c)
    v = (2.0 * y - k * (x * x + y * y)) / (1.0 + h)  # (1 − h) / κ without the cancellation
    return s, v - wave(b, s)[0]


def heading(b: Bend, s: jax.Array, u: jax.Array) -> jax.Array:
    """Direction [rad] of the curve u = const at (s, u), driven towards +s (0 on a straight
    field)."""
    w, dw = wave(b, s)
    k = b.curvature
    return k * s + jnp.arctan2(dw, 1.0 - k * (u + w))


def point(ln: Lane, s: jax.Array) -> jax.Array:
    """World (x, y) [..., 2] of the lane's centre line at s."""
    return jnp.stack(to_world(ln.bend, s, ln.u), -1)


def goal(ln: Lane) -> jax.Array:
    """float32 [2] (x, y) [m]: the lane's end, where the episode's goal is."""
    return point(ln, ln.s_end).astype(jnp.float32)


def project(ln: Lane, xy: jax.Array) -> tuple[jax.Array, jax.Array, jax.Array]:
    """A world point xy [..., 2] against the lane: (s along the lane [m], signed offset from
    the centre line [m] (positive: left of it, towards +u), direction of the centre line
    there [rad]). The offset is perpendicular to the line (exact on arcs; on the sinusoid the
    across-row difference times the cosine of the line's angle to the rows)."""
    b = ln.bend
    s, u = to_field(b, xy[..., 0], xy[..., 1])
    w, dw = wave(b, s)
    squeeze = 1.0 - b.curvature * (ln.u + w)
    tilt = jnp.arctan2(dw, squeeze)
    offset = (u - ln.u) * jnp.cos(tilt)
    return s, offset, b.curvature * s + tilt


def polyline(ln: Lane, s0: jax.Array, s1: jax.Array, n: int) -> jax.Array:
    """[n, 2] world points of the centre line from s0 to s1 (n static)."""
    s = s0 + (s1 - s0) * jnp.linspace(0.0, 1.0, n)
    return point(ln, s)
