"""Zucchini: broad leaves in a low dome around a central mound; the paper's Table 1 field
(groups of 7 rows), its largest dataset and its Tables 2 and 3 rows."""

import numpy as np

from mjxrow.crops import Crop, register
from mjxrow.crops.prims import ELLIPSOID, LEAF, STEM, compose, rosette, upright

# Martini et al., Table 1: terrain L × W, |ΔH|; plant L × W × H; d_rr, d_RR, d_pp [m]; rows
TABLE1 = dict(terrain_length=60.0, terrain_width=38.0, terrain_dh=0.2, plant_length=0.82,
              plant_width=0.9, plant_height=0.6, d_rr=1.8, d_RR=3.6, d_pp=0.7, rows_per_group=7)


def local(L, W, H, yaw, phase):
    """5 spreading leaves, 2 upright ones and a central mound (stem): K = 8 ellipsoids."""
    parts = [rosette(L, W, H, yaw, phase, 5, 0.98, 0.36, 0.34, 0.12, 0.25, 0.36),
             rosette(L, W, H, yaw + 0.6, phase, 2, 0.45, 0.40, 0.30, 0.10, 1.0, 0.56,
                     upright=True),
             upright(L, W, H, (0.25, 0.25, 0.30, 0.25))]
    return (*compose(parts), np.asarray([ELLIPSOID] * 8), np.asarray([LEAF] * 7 + [STEM]))


CROP = register(Crop(
    name="zucchini",
    preset=dict(TABLE1, row_length=50.0),  # rows stop 5 m short of the terrain's ends
    local=local,
    palette=((0.20, 0.42, 0.13), (0.42, 0.55, 0.22), (0.36, 0.27, 0.18), (0.2, 0.4, 0.13),
             (0.85, 0.72, 0.20)),
    silver_leaf=True,
    dataset_n=19456,
    test_frac=0.30,
    paper=dict(table1=TABLE1, table2=dict(accuracy=0.802, iou=197.8),
               table3=dict(cha=-0.0346, mae=0.1167, mse=0.0189, omega_std=0.0428)),
))
