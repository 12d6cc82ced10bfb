"""Pear trees: a trunk under a canopy of three lobes, single rows; the paper's Table 1 field and
its Tables 2 and 3 rows (Table 3's pear MSE, 3.8349, cannot go with its MAE of 0.0058 in
metres: see experiments/table3_navigation.py)."""

import jax.numpy as jnp
import numpy as np

from mjxrow.crops import Crop, register
from mjxrow.crops.prims import (
    CANOPY,
    CAPSULE,
    ELLIPSOID,
    TRUNK,
    compose,
    rosette,
    upright,
    vertical_capsule,
)

# Martini et al., Table 1: terrain L × W, |ΔH|; plant L × W × H; d_rr, d_RR, d_pp [m]; rows
TABLE1 = dict(terrain_length=80.0, terrain_width=45.0, terrain_dh=0.3, plant_length=1.4,
              plant_width=2.2, plant_height=3.2, d_rr=5.0, d_RR=5.0, d_pp=2.2, rows_per_group=1)
TRUNK_RADIUS = 0.09  # m, also the collision footprint


def local(L, W, H, yaw, phase):
    """A trunk (capsule), a canopy and two lobes: K = 4."""
    trunk = vertical_capsule(H, TRUNK_RADIUS * jnp.ones_like(H), 0.0, 0.45)
    canopy = upright(L, W, H, (0.50, 0.50, 0.32, 0.66))
    lobes = rosette(L, W, H, yaw, phase, 2, 0.95, 0.30, 0.45, 0.18, 0.2, 0.72)
    return (*compose([trunk, canopy, lobes]), np.asarray([CAPSULE] + [ELLIPSOID] * 3),
            np.asarray([TRUNK, CANOPY, CANOPY, CANOPY]))


CROP = register(Crop(
    name="pear",
    preset=dict(TABLE1, row_length=70.0),  # rows stop 5 m short of the terrain's ends
    local=local,
    palette=((0.22, 0.42, 0.14), (0.40, 0.52, 0.22), (0.33, 0.25, 0.18), (0.21, 0.40, 0.13),
             (0.75, 0.72, 0.25)),
    trunk_radius=TRUNK_RADIUS,
    paper=dict(table1=TABLE1, table2=dict(accuracy=0.633, iou=145.7),
               table3=dict(cha=-0.0005, mae=0.0058, mse=3.8349, omega_std=0.0028)),
))
