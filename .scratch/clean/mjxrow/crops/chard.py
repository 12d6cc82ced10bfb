"""Chard: a few upright leaves on stems; the paper's Table 1 field (groups of 3 rows, the robot
drives between groups) and its Tables 2 and 3 rows."""

import numpy as np

from mjxrow.crops import Crop, register
from mjxrow.crops.prims import ELLIPSOID, LEAF, compose, rosette

# Martini et al., Table 1: terrain L × W, |ΔH|; plant L × W × H; d_rr, d_RR, d_pp [m]; rows
TABLE1 = dict(terrain_length=60.0, terrain_width=12.0, terrain_dh=0.25, plant_length=0.25,
              plant_width=0.4, plant_height=0.25, d_rr=0.7, d_RR=1.4, d_pp=0.3,
              rows_per_group=3)


def local(L, W, H, yaw, phase):
    """4 upright leaves: K = 4 ellipsoids."""
    parts = [rosette(L, W, H, yaw, phase, 4, 0.95, 0.50, 0.30, 0.12, 1.1, 0.5, upright=True)]
    return (*compose(parts), np.asarray([ELLIPSOID] * 4), np.asarray([LEAF] * 4))


CROP = register(Crop(
    name="chard",
    preset=dict(TABLE1, row_length=50.0),  # rows stop 5 m short of the terrain's ends
    local=local,
    palette=((0.14, 0.34, 0.11), (0.70, 0.22, 0.20), (0.36, 0.27, 0.18), (0.15, 0.35, 0.1),
             (0.85, 0.72, 0.20)),
    deep=(0.25, 24, 64, 192),  # many rows of small plants in front of a far ray's hit
    paper=dict(table1=TABLE1, table2=dict(accuracy=0.659, iou=6.13),
               table3=dict(cha=-0.0056, mae=0.0145, mse=0.0004, omega_std=0.0224)),
))
