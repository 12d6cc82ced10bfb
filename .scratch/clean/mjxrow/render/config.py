"""The renderer's static configuration: the pinhole camera (`Intrinsics`), the ray caster's
knobs (`RenderConfig`) and the defaults that `resolve` fills in from the crop, the image size
and the backend (tile side, deep tiles, kernels, what is kept in memory)."""

from __future__ import annotations

import dataclasses
import os
from typing import ClassVar

import jax
import numpy as np

from mjxrow import crops
from mjxrow.render import pallas

__all__ = ["DEEP_DEFAULT", "DEFAULT_CONFIG", "KERNELS", "SETTLES", "Intrinsics", "RenderConfig",
           "deep_share_scale", "default_kernel", "default_settle", "default_tile", "resolve"]

# how the per-ray tests run: "scan" (XLA loops over groups of candidates; fastest on CPU),
# "fused" (XLA, all candidates in one reduction), "pallas" (Triton kernels for the plant tests
# and the terrain march; on CPU they run in Pallas' interpreter, for tests only)
KERNELS = ("scan", "fused", "pallas")
SETTLES = ("none", "barrier", "loop")  # RenderConfig.settle (`default_settle`)


@dataclasses.dataclass(frozen=True)
class Intrinsics:
    """Pinhole camera (static). Defaults: the robot's camera (vertical fov 42°)."""

    width: int = 64  # px, image width
    height: int = 64  # px, image height
    fovy: float = 42.0  # deg, vertical field of view (the robot's camera; the horizontal one
    # follows from width / height)

    def __post_init__(self):
        if int(self.width) < 1 or int(self.height) < 1:
            raise ValueError(f"camera.width/height: must be positive, got "
                             f"{self.width}x{self.height}")
        if not 0.0 < float(self.fovy) < 180.0:
            raise ValueError(f"camera.fovy: must lie in (0, 180) degrees, got {self.fovy}")


@dataclasses.dataclass(frozen=True)
class RenderConfig:
    """Static knobs of the ray caster (speed against completeness; see render_tiles)."""

    tile: int | None = None  # tile side [px]: plants are culled once per tile of tile × tile
    # pixels (None: by resolution, `default_tile`)
    row_blocks: int = 8  # blocks of BLOCK plants per row whose boxes a tile tests
    block_keep: int = 16  # blocks per tile whose plants' boxes are tested
    keep: int = 16  # candidate plants per tile that every ray intersects exactly
    deep_share: float | None = None  # share of a frame's tiles that may be deep (None: by crop
    # and resolution, `deep_share_scale`)
    deep_row_blocks: int | None = None  # the same for the deep tiles (None: by crop)
    deep_block_keep: int | None = None  # blocks per deep tile whose plants' boxes are tested
    deep_keep: int | None = None  # candidate plants per deep (sub-)tile
    deep_split: int = 2  # deep tiles are culled again as split × split sub-tiles (1: whole)
    shadow_row_blocks: int = 2  # the same for the shadow rays of a tile
    shadow_block_keep: int = 4
    shadow_keep: int = 6
    terrain_steps: int = 16  # march samples over the ray's part in the terrain's height band
    terrain_refine: int = 7  # bisections of the first bracket before the exact triangle
    obstacles: int = 8  # nearest obstacles (ahead of the camera) tested per frame
    obstacle_keep: int = 2  # of those, the ones per tile that its rays test (entered first)
    weeds: int = 64  # nearest weeds in view kept per frame (`render.weeds`; fields with weeds)
    weed_keep: int = 4  # of those, the ones per tile that its rays (and shadow rays) test
    shadows: bool = True  # plants and obstacles cast sun shadows
    kernel: str | None = None  # how the per-ray tests run (KERNELS; None: `default_kernel`)
    settle: str | None = None  # what is kept in memory before its consumers read it: the
    # hit geometry and the shading's per-pixel terms (SETTLES; None: `default_settle`)
    near: float = 0.01  # m, nothing nearer the camera is drawn
    far: float = 150.0  # m, nothing further is drawn

    CHOICES: ClassVar[dict[str, tuple[str, ...]]] = {"kernel": KERNELS, "settle": SETTLES}

    def __post_init__(self):
        for name in ("tile", "row_blocks", "block_keep", "keep", "deep_row_blocks",
                     "deep_block_keep", "shadow_row_blocks", "shadow_block_keep", "shadow_keep",
                     "terrain_steps", "obstacles", "obstacle_keep", "weeds", "weed_keep"):
            v = getattr(self, name)
            if v is not None and int(v) < 1:
                raise ValueError(f"render.{name}: must be at least 1, got {v}")
        if int(self.deep_split) < 1 or int(self.deep_split) & (int(self.deep_split) - 1):
            raise ValueError(f"render.deep_split: must be a power of two, got "
                             f"{self.deep_split}")
        if self.deep_keep is not None and int(self.deep_keep) < 0:
            raise ValueError(f"render.deep_keep: must be at least 0, got {self.deep_keep}")
        if self.deep_share is not None and not 0.0 <= self.deep_share <= 1.0:
            raise ValueError(f"render.deep_share: must lie in [0, 1], got {self.deep_share}")
        if self.kernel is not None and self.kernel not in KERNELS:
            raise ValueError(f"render.kernel: one of {', '.join(KERNELS)} or None, got "
                             f"{self.kernel!r}")
        if self.settle is not None and self.settle not in SETTLES:
            raise ValueError(f"render.settle: one of {', '.join(SETTLES)} or None, got "
                             f"{self.settle!r}")
        if not 0.0 < self.near < self.far:
            raise ValueError(f"render.near/far: need 0 < near < far, got {self.near}, {self.far}")


DEFAULT_CONFIG = RenderConfig()

# deep tiles (share, row_blocks, block_keep, keep) of the crops without their own `Crop.deep`
# (small plants in many rows put more plants in front of a far ray's hit than large ones)
DEEP_DEFAULT = (0.25, 12, 16, 48)


def default_tile(intr: Intrinsics) -> int:
    """Tile side for an image: 8 px at 64 × 64, doubled whenever the resolution doubles, 4 px
    below 64 and at most 16 px (a power of two, so that a tile's cone never spans more than
    that of an 8-px tile at 64 px and the Pallas kernels take it)."""
    side = 8 * 2.0 ** np.floor(np.log2(min(intr.width, intr.height) / 64.0))
    return int(np.clip(side, 4, 16))


def deep_share_scale(intr: Intrinsics, tile: int) -> float:
    """Factor on a crop's deep share for `intr` cut in tiles of `tile` px: 1 up to 8 tiles
    across the shorter side (64 px in 8-px tiles, 128 px in 16-px tiles), 8 / n beyond, for
    n tiles across, never below 1/2. The plants that a tile's first candidates miss lie in a
    small region near the vanishing point; finer tiles cover it with fewer whole tiles beside
    it, so a smaller share of them holds it (at 224 px, 14 tiles across: 0.571 of the share;
    with half of it the minimum plant-mask IoU along the rows and in the headland stays
    ≥ 0.98 for every preset, docs/render.md)."""
    n = min(intr.width, intr.height) / max(int(tile), 1)
    return float(np.clip(8.0 / n, 0.5, 1.0))


def default_settle(intr: Intrinsics | None = None) -> str:
    """What the renderer computes into memory before its consumers read it. XLA fuses a
    producer into each consumer element, so left alone ("none") a pixel's primitive normal is
    computed again by every consumer of the hit geometry (shadow rays, shading), and its
    textures, occlusion and sky once per colour channel. "barrier" keeps the hit points,
    normals and primitive-frame points, then the shading's per-pixel terms, with
    `lax.optimization_barrier`; "loop" keeps the shading terms with a while loop
    (`geom.materialise`). CPUs: "loop" (5-12 % faster per closed-loop step). GPUs: "barrier"
    up to 64 × 64 pixels (7 % more frames/s at 64 px), "none" above (at 224 px the barrier
    costs 7 %) (docs/benchmarks-history.md, sixth and seventh rounds)."""
    if jax.default_backend() == "cpu":
        return "loop"
    small = intr is not None and intr.width * intr.height <= 64 * 64
    return "barrier" if small else "none"


def default_kernel(tile: int) -> str:
    """Pallas kernels on a GPU (for power-of-two pixels per tile), else the XLA reduction on
    accelerators and the scan on CPU. The environment variable MJXROW_RENDER_KERNEL (one of
    KERNELS) overrides this for every command, e.g. to compare or to sidestep a compiler."""
    env = os.environ.get("MJXROW_RENDER_KERNEL", "").strip()
    if env:
        if env not in KERNELS:
            raise ValueError(f"MJXROW_RENDER_KERNEL: one of {', '.join(KERNELS)}, got {env!r}")
        return env
    backend = jax.default_backend()
    if backend == "gpu" and pallas.supported(tile * tile):
        return "pallas"
    return "scan" if backend == "cpu" else "fused"


def resolve(cfg: RenderConfig, crop: str, intr: Intrinsics | None = None) -> RenderConfig:
    """`cfg` with the knobs left at None set: the tile side for `intr` (`default_tile`; 4
    without intr), the deep-tile ones of `crop` (its `Crop.deep`, else DEEP_DEFAULT; the share
    times `deep_share_scale`), the kernels (`default_kernel`) and what is kept in memory
    (`default_settle`)."""
    if cfg.tile is None:
        cfg = dataclasses.replace(cfg, tile=default_tile(intr) if intr is not None else 4)
    names = ("deep_share", "deep_row_blocks", "deep_block_keep", "deep_keep")
    by_crop = dict(zip(names, crops.get(crop).deep or DEEP_DEFAULT, strict=True))
    if intr is not None:
        by_crop["deep_share"] *= deep_share_scale(intr, cfg.tile)
    cfg = dataclasses.replace(cfg, **{k: v for k, v in by_crop.items()
                                      if getattr(cfg, k) is None})
    if cfg.kernel is None:
        cfg = dataclasses.replace(cfg, kernel=default_kernel(cfg.tile))
    if cfg.settle is None:
        cfg = dataclasses.replace(cfg, settle=default_settle(intr))
    return cfg
