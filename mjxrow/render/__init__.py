"""The batched camera: a JAX ray caster specialised to row crops (RGB, depth, plant mask,
classes; four sky/lighting conditions). `render(field, shape, cam_pos, cam_rot, intr, cond,
key, cfg)` draws one frame of one world; vmap it for a batch.

Modules: `core` (camera, frame assembly, config), `geom` (primitive hits, plant tables),
`tiles` (per-tile culling through the row structure), `terrain` (heightfield march), `shade`
(materials, sky, lighting conditions), `pallas` (the GPU kernels of the per-ray tests)."""

from mjxrow.render.core import (
    CONDITIONS,
    DEFAULT_CONFIG,
    KERNELS,
    OBSTACLE,
    PLANT,
    SETTLES,
    SKY,
    SKY_DEPTH,
    SOIL,
    Conditions,
    Frame,
    Intrinsics,
    PlantTable,
    RenderConfig,
    camera_rot,
    condition_by_index,
    conditions,
    default_kernel,
    default_tile,
    geometry,
    pixel_rays,
    plant_table,
    render,
    resolve,
)

__all__ = ["CONDITIONS", "DEFAULT_CONFIG", "KERNELS", "OBSTACLE", "PLANT", "SETTLES", "SKY",
           "SKY_DEPTH", "SOIL", "Conditions", "Frame", "Intrinsics", "PlantTable", "RenderConfig",
           "camera_rot", "condition_by_index", "conditions", "default_kernel", "default_tile",
           "geometry", "pixel_rays", "plant_table", "render", "resolve"]
