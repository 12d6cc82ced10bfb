"""Vineyard: a trunk under a canopy wall elongated along the row, single rows 2.7 m apart. Not
in the paper's Tables 1 and 2 (typical values here); its Table 3 row."""

import jax.numpy as jnp
import numpy as np

from mjxrow.crops import Crop, register
from mjxrow.crops.prims import CANOPY, CAPSULE, ELLIPSOID, TRUNK, compose, upright, vertical_capsule

TRUNK_RADIUS = 0.045  # m, also the collision footprint


def local(L, W, H, yaw, phase):
    """A trunk (capsule), the canopy wall and a lower band of foliage: K = 3."""
    trunk = vertical_capsule(H, TRUNK_RADIUS * jnp.ones_like(H), 0.0, 0.55)
    wall = upright(L, W, H, (0.50, 0.50, 0.25, 0.72))
    low = upright(L, W, H, (0.40, 0.36, 0.14, 0.50))
    return (*compose([trunk, wall, low]), np.asarray([CAPSULE, ELLIPSOID, ELLIPSOID]),
            np.asarray([TRUNK, CANOPY, CANOPY]))


CROP = register(Crop(
    name="vineyard",
    preset=dict(terrain_length=60.0, terrain_width=30.0, terrain_dh=0.15, plant_length=1.2,
                plant_width=0.5, plant_height=1.9, d_rr=2.7, d_RR=2.7, d_pp=1.0,
                rows_per_group=1, row_length=50.0),
    local=local,
    palette=((0.27, 0.45, 0.15), (0.40, 0.52, 0.22), (0.40, 0.30, 0.21), (0.26, 0.44, 0.14),
             (0.30, 0.20, 0.35)),
    trunk_radius=TRUNK_RADIUS,
    paper=dict(table3=dict(cha=0.0053, mae=0.0330, mse=0.0014, omega_std=0.0255)),
))
