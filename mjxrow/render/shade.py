"""Lighting conditions, procedural colour and sky for `render.py` (pure jnp, no jit).

Colours are linear RGB; `render.py` applies exposure and the sRGB-like gamma at the end.
"""

from __future__ import annotations

import jax
import jax.numpy as jnp
import numpy as np
from flax import struct

from mjxrow import crops
from mjxrow.crops import prims as crops_prims

CONDITIONS = ("sunny", "cloudy", "crepuscular", "long_shadows")


@struct.dataclass
class Conditions:
    """Sky and lighting of one frame (add a leading [B] axis for a batch). Linear RGB."""

    sun_dir: jax.Array  # float32 [3], unit vector toward the sun (world frame)
    sun_rgb: jax.Array  # float32 [3], direct sun irradiance on a surface facing it
    ambient: jax.Array  # float32 [3], sky light on an unoccluded surface
    sky_zenith: jax.Array  # float32 [3], sky radiance straight up
    sky_horizon: jax.Array  # float32 [3], sky radiance at the horizon (also the haze colour)
    cloud: jax.Array  # float32 [], cloud cover of the sky texture, 0 (clear) .. 1 (overcast)
    haze: jax.Array  # float32 [], distance at which 63 % of a surface's colour is haze [m]
    soil_tint: jax.Array  # float32 [3], factor on the soil albedo
    leaf_tint: jax.Array  # float32 [3], factor on the plant albedo
    exposure: jax.Array  # float32 [], factor on the radiance before the gamma
    noise: jax.Array  # float32 [], sensor noise std in 8-bit units / 255 (used with a key)
    shadow: jax.Array  # float32 [], strength of the cast shadows: 1 full, 0 none (training's
    # randomisation: `env.randomize.shadow_strength`)


# name: (sun elevation range [deg], sun rgb, ambient, zenith, horizon, cloud, haze [m], noise)
_TABLE = {
    "sunny": ((35.0, 70.0), (1.00, 0.96, 0.88), (0.30, 0.34, 0.42), (0.16, 0.33, 0.75),
              (0.62, 0.74, 0.90), 0.15, 220.0, 0.010),
    "cloudy": ((25.0, 70.0), (0.10, 0.10, 0.10), (0.72, 0.74, 0.78), (0.45, 0.48, 0.53),
               (0.70, 0.72, 0.75), 0.90, 90.0, 0.012),
    "crepuscular": ((2.0, 9.0), (1.25, 0.55, 0.22), (0.16, 0.14, 0.20), (0.10, 0.13, 0.30),
                    (0.95, 0.48, 0.22), 0.30, 120.0, 0.020),
    "long_shadows": ((9.0, 20.0), (1.20, 1.05, 0.85), (0.24, 0.28, 0.38), (0.15, 0.30, 0.68),
                     (0.70, 0.72, 0.78), 0.10, 180.0, 0.012),
}
SUN_AZIMUTH_DEG = 35.0  # nominal sun azimuth (from +x toward +y)


def _vec(x) -> jax.Array:
    return jnp.asarray(x, jnp.float32)


def conditions(name: str, key: jax.Array | None = None,
               azimuth_deg: float = SUN_AZIMUTH_DEG) -> Conditions:
    """Nominal conditions of `name` (one of CONDITIONS) with the sun at `azimuth_deg` (degrees
    from +x, the rows' direction, toward +y), or, with a key, a random variant of them: sun
    azimuth anywhere, elevation inside the condition's range, colours, haze, soil and leaf tints
    and exposure jittered. Jittable (name is static)."""
    if name not in _TABLE:
        raise ValueError(f"condition: unknown condition {name!r}; expected one of {CONDITIONS}")
    (e_lo, e_hi), sun, amb, zen, hor, cloud, haze, noise = _TABLE[name]
    if key is None:  # host values (numpy float32): no device program per operation
        az, el = np.deg2rad(azimuth_deg), np.deg2rad(0.5 * (e_lo + e_hi))
        h = lambda x: np.asarray(x, np.float32)  # noqa: E731
        return Conditions(
            sun_dir=h([np.cos(el) * np.cos(az), np.cos(el) * np.sin(az), np.sin(el)]),
            sun_rgb=h(sun), ambient=h(amb), sky_zenith=h(zen), sky_horizon=h(hor),
            cloud=h(cloud), haze=h(haze), soil_tint=h(np.ones(3)), leaf_tint=h(np.ones(3)),
            exposure=h(1.0), noise=h(noise), shadow=h(1.0))
    ks = jax.random.split(key, 9)
    az = jax.random.uniform(ks[0], (), maxval=2 * jnp.pi)
    el = jnp.deg2rad(jax.random.uniform(ks[1], (), minval=e_lo, maxval=e_hi))
    it = iter(jax.random.split(ks[2], 3))
    j3 = lambda: 1.0 + 0.05 * jax.random.normal(next(it), (3,))  # noqa: E731
    jitter = jnp.exp(0.25 * jax.random.normal(ks[3], ()))
    # soil: darker/wetter .. lighter/drier, redder .. greyer; leaves: yellower .. bluer
    soil = jnp.exp(0.22 * jax.random.normal(ks[4], ())) * (
        1.0 + jnp.array([0.08, 0.0, -0.08]) * jax.random.normal(ks[5], ()))
    leaf = jnp.exp(0.12 * jax.random.normal(ks[6], ())) * (
        1.0 + jnp.array([0.15, 0.02, -0.10]) * jax.random.normal(ks[7], ()))
    exposure = jnp.exp(0.10 * jax.random.normal(ks[8], ()))
    sun_dir = jnp.stack([jnp.cos(el) * jnp.cos(az), jnp.cos(el) * jnp.sin(az), jnp.sin(el)])
    sky_j = j3()  # one tint for the whole sky keeps its hue plausible
    return Conditions(
        sun_dir=sun_dir.astype(jnp.float32), sun_rgb=_vec(sun) * j3(), ambient=_vec(amb) * j3(),
        sky_zenith=_vec(zen) * sky_j, sky_horizon=_vec(hor) * sky_j, cloud=_vec(cloud),
        haze=_vec(haze) * jitter, soil_tint=_vec(soil), leaf_tint=_vec(leaf),
        exposure=_vec(exposure), noise=_vec(noise), shadow=_vec(1.0))


def turn_sun(c: Conditions, azimuth_deg: jax.Array) -> Conditions:
    """`c` with its sun turned to `azimuth_deg` (degrees from +x toward +y) at the same
    elevation; a NaN azimuth leaves `c` as it is. Traced (one world's conditions)."""
    az = jnp.deg2rad(jnp.asarray(azimuth_deg, jnp.float32))
    h = jnp.hypot(c.sun_dir[0], c.sun_dir[1])
    turned = jnp.stack([h * jnp.cos(az), h * jnp.sin(az), c.sun_dir[2]])
    return c.replace(sun_dir=jnp.where(jnp.isnan(az), c.sun_dir, turned).astype(jnp.float32))


def condition_by_index(index: jax.Array, key: jax.Array | None = None) -> Conditions:
    """`conditions(CONDITIONS[index], key)` for a traced int index (vmappable)."""
    all_c = [conditions(n, key) for n in CONDITIONS]
    return jax.tree.map(lambda *xs: jnp.stack(xs)[index], *all_c)


# ---------------------------------------------------------------------------------------------
# Value noise (integer hash; identical on CPU and GPU)


def _hash(*ints: jax.Array, seed: int | jax.Array = 0) -> jax.Array:
    if isinstance(seed, int):
        h = jnp.uint32((0x9E3779B9 + 0x632BE5AB * seed) & 0xFFFFFFFF)
    else:  # a seed per element: the same start state, modulo 2**32
        h = jnp.uint32(0x9E3779B9) + jnp.uint32(0x632BE5AB) * jnp.asarray(seed).astype(jnp.uint32)
    for i, x in enumerate(ints):
        x = (x + (1 << 22)).astype(jnp.uint32)
        h = (h ^ (x * jnp.uint32((0x85EBCA77, 0xC2B2AE3D, 0x27D4EB2F)[i]))) * jnp.uint32(0x165667B1)
        h = h ^ (h >> 15)
    h = (h ^ (h >> 16)) * jnp.uint32(0x7FEB352D)
    h = (h ^ (h >> 15)) * jnp.uint32(0x846CA68B)
    h = h ^ (h >> 16)
    return (h >> 8).astype(jnp.float32) * (1.0 / (1 << 24))


def hash01(*ints: jax.Array, seed: int = 0) -> jax.Array:
    """Uniform [0, 1) from integer arrays (same shapes)."""
    return _hash(*(jnp.asarray(x, jnp.int32) for x in ints), seed=seed)


def value_noise2(x: jax.Array, y: jax.Array, seed: int | jax.Array = 0) -> jax.Array:
    """Smooth value noise in [0, 1) with unit lattice spacing (seed: an int, or an int array
    of x's shape, a seed per element)."""
    fx, fy = jnp.floor(x), jnp.floor(y)
    ix, iy = fx.astype(jnp.int32), fy.astype(jnp.int32)
    u, v = x - fx, y - fy
    u, v = u * u * (3 - 2 * u), v * v * (3 - 2 * v)
    a, b = _hash(ix, iy, seed=seed), _hash(ix + 1, iy, seed=seed)
    c, d = _hash(ix, iy + 1, seed=seed), _hash(ix + 1, iy + 1, seed=seed)
    return a + (b - a) * u + (c - a) * v + (a - b - c + d) * u * v


# ---------------------------------------------------------------------------------------------
# Colours (sRGB albedo, converted to linear)

_SOIL = (0.43, 0.32, 0.22)
_STONE, _BRANCH = (0.55, 0.53, 0.50), (0.42, 0.31, 0.20)


def _lin(rgb) -> jax.Array:
    return jnp.asarray(rgb, jnp.float32) ** 2.2


# pixel classes (`Frame.classes`): the crop's plants are PLANT (the mask controllers and the
# segmenter's ground truth use); weeds are their own class WEED, never part of that mask
SKY, SOIL, PLANT, OBSTACLE, WEED = 0, 1, 2, 3, 4

# Every pixel's textures come from NOISE_SLOTS value noises, evaluated once per pixel at the
# lattice coordinates and seeds its class asks for: a plant its material's one or two (mottle
# or bark; pale patches or the canopy's clumps, whose second octave takes a third slot) and
# three for its bumped normal (a weed: mottle and three), soil five, sky four (clouds),
# obstacles one. Evaluating every
# class's textures and then picking one would take 18 noises (72 hashes) a pixel, and XLA
# would compute them once per colour channel; this takes 6 (24 hashes), which `surfaces`'
# `keep` (the renderer's `settle`) can put in memory before any colour is formed.
NOISE_SLOTS = 6


def _octaves(values) -> jax.Array:
    """fBm of the octave noises `values` (gain 0.5), normalised to [0, 1)."""
    total, amp, norm = 0.0, 1.0, 0.0
    for v in values:
        total = total + amp * v
        norm += amp
        amp *= 0.5
    return total / norm


def _octave_inputs(x, y, octaves: int, seed: int) -> list:
    """(x, y, seed) of each of `octaves` value-noise octaves (lacunarity 2.03) from (x, y)."""
    out = []
    for o in range(octaves):
        out.append((x, y, seed + 17 * o))
        x, y = 2.03 * x + 5.1, 2.03 * y - 3.7
    return out


def _noise_inputs(crop: str, cls, material, p, d):
    """Lattice coordinates and seeds of the NOISE_SLOTS noises of each pixel: three int/float
    arrays [NOISE_SLOTS, N] (x, y, seed)."""
    x, y, z = p[:, 0], p[:, 1], p[:, 2]
    zero = jnp.zeros_like(x)
    pad = (zero, zero, 0)

    def pick(c, a, b):
        return tuple(jnp.where(c, u, v) for u, v in zip(a, b, strict=True))

    h = jnp.maximum(d[:, 2], 0.03)  # clouds on a plane 1 unit above: coordinates d_xy / d_z
    sky = _octave_inputs(1.7 * (d[:, 0] / h), 1.7 * (d[:, 1] / h), 4, 11)
    soil = _octave_inputs(x * 0.45, y * 0.45, 3, 1) + [(x * 9.0, y * 9.0, 2),
                                                       (x * 40.0, y * 40.0, 3)]
    obstacle = [(25 * x + 3 * z, 25 * y, 8)]
    mottle = (14.0 * (x + z), 14.0 * (y - 0.7 * z), 6)
    bark = (40.0 * (x + y), 3.0 * z, 10)
    silver = (30 * x, 30 * y, 7) if crops.get(crop).silver_leaf else pad
    clumps = _octave_inputs(9.0 * (x + 0.5 * z), 9.0 * (y - 0.5 * z), 2, 9)
    s = 12.0
    bumps = [(s * (x + z), s * y, 12), (s * (y + z), s * x, 13), (s * (x - y), s * z, 14)]
    canopy = material == crops_prims.CANOPY
    plant = [pick(material == crops_prims.TRUNK, bark, mottle), pick(canopy, clumps[0], silver),
             pick(canopy, clumps[1], pad)] + bumps
    weed = [mottle, pad, pad] + bumps
    by_class = {SKY: sky, SOIL: soil, PLANT: plant, OBSTACLE: obstacle, WEED: weed}
    slots = []
    for i in range(NOISE_SLOTS):
        out = pad
        for c, inputs in by_class.items():
            if i < len(inputs):
                out = pick(cls == c, inputs[i], out)
        slots.append(tuple(jnp.broadcast_to(jnp.asarray(u), x.shape) for u in out))
    return tuple(jnp.stack(u) for u in zip(*slots, strict=True))


def surfaces(crop: str, cls: jax.Array, material: jax.Array, p: jax.Array, local: jax.Array,
             phase: jax.Array, plant: jax.Array, k: jax.Array, is_branch: jax.Array,
             normal: jax.Array, d: jax.Array, cond: Conditions, keep=lambda x: x):
    """Albedo (linear) [N, 3], shading normal [N, 3] and sky radiance [N, 3] of the pixels.

    cls [N]: their class; p [N, 3] the hit points; for plant and weed pixels material, plant,
    k [N] ints (the primitive's material, the plant's index or another number per weed, and
    primitive index), local [N, 3] the point in the primitive's frame, phase [N] the plant's
    or weed's phase; is_branch [N] for obstacle pixels; normal
    [N, 3] the geometric normals; d [N, 3] the unit view directions. `keep(tree)` is applied to
    the per-pixel noises before they reach the colour channels (`render.core._settle`).

    - soil: large damp/dry patches, clods, grit;
    - plants: the crop's material colour (`Crop.palette`), varied per plant (phase) and per
      primitive, leaf veins (a pale midrib along the leaf's long axis and lateral veins), pale
      patches on the blades of crops with `Crop.silver_leaf`, clumps of foliage on canopies,
      bark streaks on trunks; normals perturbed by value noise (stronger on canopies);
    - weeds: leaves of one of `crops.prims.WEED_PALETTE`'s colours, the third of the palette
      its phase falls in (as the exports' `worlds.mjcf.weed_rgb`), varied within it, with
      the leaves' mottle, veins and bumps;
    - obstacles: stone or branch colour with a streaky noise;
    - sky: zenith-horizon gradient, sun disk and glow, a cloud layer textured with value noise.
    """
    nx, ny, seed = _noise_inputs(crop, cls, material, p, d)
    v = value_noise2(nx, ny, seed=seed)  # [NOISE_SLOTS, N]
    per_prim = 0.85 + 0.30 * hash01(plant, k, seed=5)
    v, per_prim = keep((v, per_prim))

    # soil
    patches, clods, grit = _octaves(v[0:3]), v[3], v[4]
    f = (0.62 + 0.75 * patches) * (0.82 + 0.36 * clods) * (0.9 + 0.2 * grit)
    warm = 1.0 + 0.10 * (patches - 0.5)[:, None] * jnp.array([1.0, 0.2, -0.8])
    a_soil = _lin(_SOIL) * cond.soil_tint * f[:, None] * warm

    # plants
    spec = crops.get(crop)
    pal = _lin(spec.palette)  # [5, 3]
    base = pal[jnp.minimum(material, pal.shape[0] - 1)]
    per_plant = 0.80 + 0.40 * phase
    yellow = 1.0 + 0.18 * (phase - 0.5)[:, None] * jnp.array([1.0, 0.3, -1.0])
    mottle = bark = v[0]
    leaf = material == crops_prims.LEAF
    u0, u1 = local[:, 0], local[:, 1]
    midrib = jnp.exp(-((u1 / 0.07) ** 2)) * (u0 > -0.9)
    lateral = jnp.clip((jnp.cos(2 * jnp.pi * (3.5 * u0 - 2.2 * jnp.abs(u1))) - 0.8) * 5, 0, 1)
    veins = jnp.clip(midrib + 0.6 * lateral * (jnp.abs(u1) < 0.8), 0, 1)
    rim = jnp.clip((u0 * u0 + u1 * u1 - 0.55) * 2.5, 0, 1)  # darker towards the blade's edge
    f_leaf = (0.8 + 0.4 * mottle) * (1.0 + 0.45 * veins) * (1.0 - 0.25 * rim)
    if spec.silver_leaf:  # pale mottled patches on the blades
        f_leaf = f_leaf + 0.6 * jnp.clip((v[1] - 0.62) * 4, 0, 1)
    f_canopy = 0.55 + 0.9 * _octaves(v[1:3]) * (0.8 + 0.4 * mottle)
    f_trunk = 0.7 + 0.6 * bark
    fine = jnp.where(leaf, f_leaf, jnp.where(material == crops_prims.CANOPY, f_canopy,
                                             jnp.where(material == crops_prims.TRUNK, f_trunk,
                                                       0.8 + 0.4 * mottle)))
    a_plant = base * cond.leaf_tint * yellow * (per_plant * per_prim * fine)[:, None]
    # weeds: a palette colour by the third of the phase, the phase within it varying it
    n_w = len(crops_prims.WEED_PALETTE)
    colour = jnp.minimum(jnp.floor(phase * n_w), n_w - 1)
    within = phase * n_w - colour
    f_weed = (0.8 + 0.4 * mottle) * (1.0 + 0.45 * veins) * (1.0 - 0.25 * rim)
    a_weed = (_lin(crops_prims.WEED_PALETTE)[colour.astype(jnp.int32)] * cond.leaf_tint
              * (1.0 + 0.18 * (within - 0.5)[:, None] * jnp.array([1.0, 0.3, -1.0]))
              * ((0.80 + 0.40 * within) * per_prim * f_weed)[:, None])
    bump = jnp.stack([v[3], v[4], v[5]], -1) - 0.5
    amp = jnp.where(material == crops_prims.CANOPY, 1.1, 0.35)[:, None]
    m = normal + amp * bump
    bumped = m / jnp.maximum(jnp.linalg.norm(m, axis=-1, keepdims=True), 1e-6)

    # obstacles
    n = 0.8 + 0.4 * v[0]
    a_obst = jnp.where(is_branch[:, None], _lin(_BRANCH), _lin(_STONE)) * n[:, None]

    is_plant = (cls == PLANT)[:, None]
    is_weed = (cls == WEED)[:, None]
    albedo = jnp.where(is_plant, a_plant,
                       jnp.where((cls == OBSTACLE)[:, None], a_obst, a_soil))
    albedo = jnp.where(is_weed, a_weed, albedo)
    return (albedo, jnp.where(is_plant | is_weed, bumped, normal),
            _sky(d, cond, _octaves(v[0:4])))


def _sky(d: jax.Array, cond: Conditions, c: jax.Array) -> jax.Array:
    """Sky radiance (linear) for unit view directions d [N, 3] with cloud noise c [N]."""
    up = jnp.clip(d[:, 2], 0.0, 1.0)
    grad = cond.sky_horizon + (cond.sky_zenith - cond.sky_horizon) * (up ** 0.45)[:, None]
    cos_sun = jnp.clip(jnp.sum(d * cond.sun_dir, -1), 0.0, 1.0)
    glow = (0.9 * cos_sun ** 900 + 0.12 * cos_sun ** 10)[:, None] * cond.sun_rgb
    cover = jnp.clip((c - (1.0 - cond.cloud)) * 3.0 + cond.cloud ** 3, 0.0, 1.0)
    cover = cover * jnp.clip(d[:, 2] * 6.0, 0.0, 1.0)
    cloud_rgb = (0.65 * cond.sky_horizon + 0.35 * cond.sun_rgb + 0.4 * cond.ambient) * (
        0.75 + 0.35 * c)[:, None]
    out = grad * (1.0 - cover[:, None]) + cloud_rgb * cover[:, None]
    below = d[:, 2] < 0  # under the horizon with nothing hit: haze
    out = jnp.where(below[:, None], cond.sky_horizon * 0.85, out)
    return out + glow * (1.0 - cover[:, None])
