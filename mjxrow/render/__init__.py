"""The batched camera: a JAX ray caster specialised to row crops (RGB, depth, crop-plant mask,
classes; four sky/lighting conditions). `render(field, shape, cam_pos, cam_rot, intr, cond,
key, cfg)` draws one frame of one world; vmap it for a batch.

Class ids of `Frame.classes`: SKY 0, SOIL 1, PLANT 2 (the crop: `Frame.mask`), OBSTACLE 3,
WEED 4 (weeds are never part of the crop mask).

Modules: `config` (camera intrinsics, the knobs and their defaults), `core` (rays, frame
assembly), `geom` (primitive hits, plant tables), `rows` (row segments: culling on straight and
curved rows), `tiles` (per-tile culling through the row structure), `weeds` (the frame's weeds
in view), `terrain` (heightfield march), `shade` (materials, sky, lighting conditions), `pallas`
(the GPU kernels of the per-ray tests)."""

from mjxrow.render.config import (
           DEFAULT_CONFIG,
           KERNELS,
           SETTLES,
           Intrinsics,
           RenderConfig,
           default_kernel,
           default_tile,
           resolve,
)
from mjxrow.render.core import (
           CONDITIONS,
           OBSTACLE,
           PLANT,
           SKY,
           SKY_DEPTH,
           SOIL,
           SUN_AZIMUTH_DEG,
           WEED,
           Conditions,
           Frame,
           PlantTable,
           camera_rot,
           condition_by_index,
           conditions,
           geometry,
           pixel_rays,
           plant_table,
           render,
)

__all__ = ["CONDITIONS", "DEFAULT_CONFIG", "KERNELS", "OBSTACLE", "PLANT", "SETTLES", "SKY",
           "SKY_DEPTH", "SOIL", "SUN_AZIMUTH_DEG", "WEED", "Conditions", "Frame", "Intrinsics",
           "PlantTable", "RenderConfig",
           "camera_rot", "condition_by_index", "conditions", "default_kernel", "default_tile",
           "geometry", "pixel_rays", "plant_table", "render", "resolve"]
