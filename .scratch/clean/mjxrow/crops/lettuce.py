"""Lettuce: a compact head in a ring of flattened leaves; the paper's Table 1 field (groups of
3 rows, the robot drives between groups) and its Tables 2 and 3 rows."""

import numpy as np

from mjxrow.crops import Crop, register
from mjxrow.crops.prims import ELLIPSOID, LEAF, compose, rosette, upright

# Martini et al., Table 1: terrain L × W, |ΔH|; plant L × W × H; d_rr, d_RR, d_pp [m]; rows
TABLE1 = dict(terrain_length=60.0, terrain_width=25.0, terrain_dh=0.25, plant_length=0.38,
              plant_width=0.34, plant_height=0.22, d_rr=0.7, d_RR=1.4, d_pp=0.4,
              rows_per_group=3)


def local(L, W, H, yaw, phase):
    """4 flattened leaves around a head: K = 5 ellipsoids."""
    parts = [rosette(L, W, H, yaw, phase, 4, 0.98, 0.30, 0.34, 0.18, 0.25, 0.38),
             upright(L, W, H, (0.32, 0.32, 0.50, 0.50))]
    return (*compose(parts), np.asarray([ELLIPSOID] * 5), np.asarray([LEAF] * 5))


CROP = register(Crop(
    name="lettuce",
    preset=dict(TABLE1, row_length=50.0),  # rows stop 5 m short of the terrain's ends
    local=local,
    palette=((0.45, 0.66, 0.22), (0.62, 0.78, 0.36), (0.36, 0.27, 0.18), (0.4, 0.6, 0.2),
             (0.85, 0.72, 0.20)),
    deep=(0.25, 24, 64, 192),  # many rows of small plants in front of a far ray's hit
    paper=dict(table1=TABLE1, table2=dict(accuracy=0.678, iou=93.0),
               table3=dict(cha=0.0474, mae=0.1209, mse=0.0204, omega_std=0.0224)),
))
