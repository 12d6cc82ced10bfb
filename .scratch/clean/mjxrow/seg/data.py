"""Segmentation data: the dataset folder on disk (host side) and jittable batch augmentation.

A dataset folder (written by `python -m mjxrow.seg.synth`) holds `index.csv` with columns
`rgb,mask,classes,crop,condition,x,y,z,yaw,pitch,lateral,...,split` (image paths relative to the
folder), RGB PNGs, 8-bit crop masks (0 / 255) and 8-bit class images (`mjxrow.render`'s class
ids: weeds are their own class, not crop; folders written before them lack the column).
Splits: the `split` column (`train` / `test`, optionally `val`).
"""

from __future__ import annotations

import queue
import threading
from collections.abc import Iterator, Sequence
from concurrent.futures import ThreadPoolExecutor
from pathlib import Path

import jax
import jax.numpy as jnp
import numpy as np
import pandas as pd
from PIL import Image
from tqdm.auto import tqdm

from mjxrow import crops as mjxrow_crops
from mjxrow import render
from mjxrow.physics.robot import RobotConfig
from mjxrow.seg import synthesis

INDEX_COLUMNS = synthesis.COLUMNS
REQUIRED = ("rgb", "mask", "crop", "condition", "split")
LUMA = (0.299, 0.587, 0.114)  # ITU-R 601 greyscale weights


def read_index(root: str | Path) -> pd.DataFrame:
    """index.csv of a dataset folder; ValueError naming the folder or the missing column."""
    path = Path(root) / "index.csv"
    if not path.is_file():
        raise ValueError(f"dataset {str(root)!r}: no index.csv in {Path(root).resolve()}")
    df = pd.read_csv(path)
    missing = [c for c in REQUIRED if c not in df.columns]
    if missing:
        raise ValueError(f"dataset {str(root)!r}: index.csv lacks columns {missing}")
    inside = Path(root).resolve()
    for col in ("rgb", "mask", "classes"):
        for i, rel in enumerate(df[col] if col in df.columns else ()):
            if isinstance(rel, float) and col == "classes":
                continue  # a folder written before class images: NaN
            target = (inside / str(rel)).resolve()
            if Path(str(rel)).is_absolute() or not target.is_relative_to(inside):
                raise ValueError(f"dataset {str(root)!r}: index.csv row {i + 2}, column {col}: "
                                 f"{rel!r} lies outside the dataset folder")
    return df


def _image(root: Path, rel: str, mode: str) -> Image.Image:
    """The image `rel` of dataset `root`, decoded and converted to `mode`; ValueError naming
    the file when it is missing, truncated or not an image."""
    try:
        with Image.open(root / rel) as im:
            return im.convert(mode)
    except OSError as e:  # PIL's UnidentifiedImageError and truncated files are OSErrors
        raise ValueError(f"dataset {str(root)!r}: {rel}: unreadable image "
                         f"({type(e).__name__}: {str(e).splitlines()[0] if str(e) else ''})"
                         ) from None


def select(df: pd.DataFrame, crop: str | Sequence[str] | None = None,
           split: str | None = None) -> pd.DataFrame:
    """Rows of `crop` (a name, a list, or None / "all" for every crop) and `split`."""
    out = df
    if crop is not None and crop != "all":
        crops = [crop] if isinstance(crop, str) else list(crop)
        unknown = sorted(set(crops) - set(df["crop"]))
        if unknown:
            raise ValueError(f"crop: {unknown} not in the dataset (it has "
                             f"{sorted(set(df['crop']))})")
        out = out[out["crop"].isin(crops)]
    if split is not None:
        if split not in set(df["split"]):
            raise ValueError(f"split: {split!r} not in the dataset (it has "
                             f"{sorted(set(df['split']))})")
        out = out[out["split"] == split]
    return out.reset_index(drop=True)


def train_val(df: pd.DataFrame, val_frac: float = 0.1,
              seed: int = 0) -> tuple[pd.DataFrame, pd.DataFrame]:
    """(train, val) rows: the `val` split if the index has one, else a fixed random `val_frac`
    of the `train` split (the test split is never used for model selection)."""
    if "val" in set(df["split"]):
        return select(df, split="train"), select(df, split="val")
    train = select(df, split="train")
    if not 0.0 < val_frac < 1.0:
        raise ValueError(f"val_frac: must be in (0, 1), got {val_frac}")
    order = np.random.default_rng(seed).permutation(len(train))
    n_val = max(1, int(round(val_frac * len(train))))
    return (train.iloc[np.sort(order[n_val:])].reset_index(drop=True),
            train.iloc[np.sort(order[:n_val])].reset_index(drop=True))


def load_sample(root: str | Path, rgb_path: str, mask_path: str,
                size: int | None = None) -> tuple[np.ndarray, np.ndarray]:
    """One sample: (rgb uint8 [S, S, 3], mask bool [S, S]); resized to `size` if given
    (bilinear for RGB, nearest for the mask)."""
    root = Path(root)
    rgb = _image(root, rgb_path, "RGB")
    if size is not None and rgb.size != (size, size):
        rgb = rgb.resize((size, size), Image.BILINEAR)
    mask = _image(root, mask_path, "L")
    if size is not None and mask.size != (size, size):
        mask = mask.resize((size, size), Image.NEAREST)
    return np.asarray(rgb, np.uint8), np.asarray(mask) > 127


def load_weed(root: str | Path, classes_path: str, size: int | None = None) -> np.ndarray:
    """bool [S, S]: the weed pixels of a sample's class image (resized, nearest, to `size`)."""
    cls = _image(Path(root), classes_path, "L")
    if size is not None and cls.size != (size, size):
        cls = cls.resize((size, size), Image.NEAREST)
    return np.asarray(cls) == render.WEED


def load_weeds(root: str | Path, df: pd.DataFrame, size: int | None = None,
               workers: int = 4) -> np.ndarray | None:
    """bool [N, S, S]: the weed pixels of every row of `df`; None for a folder without class
    images (written before weeds had their own class)."""
    if "classes" not in df.columns or df["classes"].isna().any():
        return None
    with ThreadPoolExecutor(workers) as pool:
        return np.stack(list(pool.map(lambda p: load_weed(root, p, size), df["classes"])))


def load_arrays(root: str | Path, df: pd.DataFrame, size: int | None = None,
                workers: int = 4, progress: bool = True) -> tuple[np.ndarray, np.ndarray]:
    """Every row of `df`: (rgb uint8 [N, S, S, 3], mask bool [N, S, S])."""
    if len(df) == 0:
        raise ValueError(f"dataset {str(root)!r}: no rows selected")
    with ThreadPoolExecutor(workers) as pool:
        it = pool.map(lambda r: load_sample(root, r[0], r[1], size),
                      zip(df["rgb"], df["mask"], strict=True))
        samples = list(tqdm(it, total=len(df), desc="load images", disable=not progress,
                            leave=False))
    return np.stack([s[0] for s in samples]), np.stack([s[1] for s in samples])


class Loader:
    """Shuffled training batches from disk, decoded by a thread pool and prefetched.

    The batch of step s is a fixed function of (seed, s): epoch e = s // (N // batch) uses the
    permutation `default_rng(seed + e)`, so a resumed run sees the same batches. Drops the last
    partial batch of each epoch. `size`: side images are resized to; a sequence of sides is
    used in turn (step s: sizes[s % n]) for multi-resolution training."""

    def __init__(self, root: str | Path, df: pd.DataFrame, batch: int,
                 size: int | Sequence[int] | None = None, seed: int = 0, workers: int = 4,
                 prefetch: int = 4):
        if len(df) < batch:
            raise ValueError(f"batch: {batch} is larger than the {len(df)} training images")
        self.root, self.df, self.batch = Path(root), df, batch
        self.sizes = tuple(size) if isinstance(size, (list, tuple)) else (size,)
        self.seed, self.workers, self.prefetch = seed, workers, prefetch
        self.steps_per_epoch = len(df) // batch

    def indices(self, step: int) -> np.ndarray:
        """Row indices of the batch of `step` (int64 [batch])."""
        epoch, i = divmod(step, self.steps_per_epoch)
        perm = np.random.default_rng(self.seed + epoch).permutation(len(self.df))
        return perm[i * self.batch:(i + 1) * self.batch]

    def size_at(self, step: int) -> int | None:
        """Image side of the batch of `step` (None: as stored)."""
        return self.sizes[step % len(self.sizes)]

    def load(self, step: int, pool: ThreadPoolExecutor) -> tuple[np.ndarray, np.ndarray]:
        rows = self.df.iloc[self.indices(step)]
        size = self.size_at(step)
        samples = list(pool.map(lambda r: load_sample(self.root, r[0], r[1], size),
                                zip(rows["rgb"], rows["mask"], strict=True)))
        return np.stack([s[0] for s in samples]), np.stack([s[1] for s in samples])

    def __call__(self, start: int = 0) -> Iterator[tuple[np.ndarray, np.ndarray]]:
        """Endless batches from step `start` on: (rgb uint8 [B, S, S, 3], mask bool [B, S, S])."""
        q: queue.Queue = queue.Queue(self.prefetch)
        stop = threading.Event()

        def work():
            with ThreadPoolExecutor(self.workers) as pool:
                step = start
                while not stop.is_set():
                    try:
                        item = self.load(step, pool)
                    except Exception as e:  # handed to the consumer
                        item = e
                    while not stop.is_set():
                        try:
                            q.put(item, timeout=0.1)
                            break
                        except queue.Full:
                            continue
                    step += 1

        thread = threading.Thread(target=work, daemon=True)
        thread.start()
        try:
            while True:
                item = q.get()
                if isinstance(item, Exception):
                    raise item
                yield item
        finally:
            stop.set()


def batches(rgb: np.ndarray, mask: np.ndarray, batch: int,
            weed: np.ndarray | None = None) -> list[tuple[np.ndarray, ...]]:
    """Split arrays into consecutive batches; the last one is padded by repeating its last image
    and returned with a weight mask so padded images count zero: [(rgb, mask, weight bool [B])],
    or [(rgb, mask, weight, weed)] with the weed pixels `weed` bool [N, H, W]."""
    arrays = (rgb, mask) if weed is None else (rgb, mask, weed)
    out = []
    for i in range(0, len(rgb), batch):
        part = [a[i:i + batch] for a in arrays]
        w = np.ones(len(part[0]), bool)
        if len(w) < batch:
            pad = batch - len(w)
            part = [np.concatenate([a, np.repeat(a[-1:], pad, 0)]) for a in part]
            w = np.concatenate([w, np.zeros(pad, bool)])
        out.append((part[0], part[1], w, *part[2:]))
    return out


def greyscale(rgb: jax.Array) -> jax.Array:
    """float [..., 3] → float [..., 3] with every channel the luma."""
    y = rgb @ jnp.asarray(LUMA, rgb.dtype)
    return jnp.repeat(y[..., None], 3, axis=-1)


def augment(key: jax.Array, rgb: jax.Array, mask: jax.Array, *, flip: float = 0.5,
            grey: float = 0.2, jitter: float = 0.0) -> tuple[jax.Array, jax.Array]:
    """Random per-image augmentation of a batch (pure, jittable).

    rgb uint8 [B, H, W, 3], mask bool [B, H, W] → same. flip: probability of a horizontal flip
    (image and mask together); grey: probability of greyscale (as the paper); jitter: strength j of
    colour jitter (brightness, contrast and saturation factors uniform in [1 − j, 1 + j]; 0 = off).
    """
    b = rgb.shape[0]
    kf, kg, kb, kc, ks = jax.random.split(key, 5)
    x = rgb.astype(jnp.float32)
    do_flip = jax.random.uniform(kf, (b,)) < flip
    x = jnp.where(do_flip[:, None, None, None], x[:, :, ::-1], x)
    mask = jnp.where(do_flip[:, None, None], mask[:, :, ::-1], mask)
    if jitter > 0.0:
        f = lambda k: jax.random.uniform(k, (b, 1, 1, 1), minval=1 - jitter,  # noqa: E731
                                         maxval=1 + jitter)
        x = x * f(kb)
        mean = jnp.mean(greyscale(x), axis=(1, 2, 3), keepdims=True)
        x = mean + (x - mean) * f(kc)
        g = greyscale(x)
        x = g + (x - g) * f(ks)
    do_grey = jax.random.uniform(kg, (b,)) < grey
    x = jnp.where(do_grey[:, None, None, None], greyscale(x), x)
    return jnp.clip(jnp.round(x), 0, 255).astype(jnp.uint8), mask


def onthefly(crop: str, size: int, batch: int, fovy: float | None = None,
             variety: str = "fields", labels: bool = False):
    """Jittable `fn(key) -> (rgb uint8 [batch, size, size, 3], mask bool [batch, size, size])`
    rendered by `mjxrow.seg.synthesis.make_batch_fn`; crop "all" mixes every crop in equal parts
    (crop by crop, in `crops.names()` order). fovy: vertical field of view [deg], default the
    robot camera's; variety: the fields' ("fields": curved rows, gaps and weeds in a share of
    them; "none"); labels: also (classes uint8 [batch, size, size], condition int32 [batch])."""

    crops = mjxrow_crops.names() if crop == "all" else (crop,)
    if crop != "all" and crop not in mjxrow_crops.CROPS:
        raise ValueError(f"crop: unknown crop {crop!r}; expected one of {mjxrow_crops.names()} or "
                         "'all'")
    if batch % len(crops):
        raise ValueError(f"batch: {batch} must be a multiple of {len(crops)} with crop {crop!r}")
    if fovy is None:
        try:
            fovy = float(RobotConfig().cam_fovy)
        except ImportError:
            fovy = 42.0
    intr = render.Intrinsics(size, size, fovy)
    fns = [synthesis.make_batch_fn(c, intr, variety=variety, labels=labels) for c in crops]
    n = batch // len(crops)

    def fn(key: jax.Array) -> tuple[jax.Array, ...]:
        outs = [f(k, n) for f, k in zip(fns, jax.random.split(key, len(fns)), strict=True)]
        return tuple(jnp.concatenate(parts) for parts in zip(*outs, strict=True))

    # Called as is (not under jit), each crop's renderer is its own compiled program: `warm`
    # compiles them side by side, and a fixed set and the training batches share them.
    fn.parts = tuple((f, n) for f in fns)
    return fn


def warm(*batch_fns) -> None:
    """Compile the renderers of `onthefly` functions at once, one thread per (function, crop):
    XLA compiles separate programs in parallel where the machine has the cores (each renders one
    batch, which is dropped). Functions without renderers of their own are skipped."""
    parts = [p for fn in batch_fns for p in getattr(fn, "parts", ())]
    if len(parts) < 2:
        return
    with ThreadPoolExecutor(len(parts)) as pool:
        list(pool.map(lambda p: jax.block_until_ready(p[0](jax.random.key(0), p[1])), parts))


def fixed_set(batch_fn, n_batches: int, seed: int) -> list[tuple[np.ndarray, ...]]:
    """A fixed evaluation set from a jittable batch function: `n_batches` batches made with keys
    fold_in(key(seed), i), as [(rgb, mask, weight)] on the host ([(rgb, mask, weight, *rest)]
    when the function returns more than (rgb, mask)). An `onthefly` function runs as is, its
    crops' renderers compiled side by side (`warm`); any other is jitted."""
    if hasattr(batch_fn, "parts"):
        warm(batch_fn)
        fn = batch_fn
    else:
        fn = jax.jit(batch_fn)
    base = jax.random.key(seed)
    out = []
    for i in tqdm(range(n_batches), desc="render eval set", leave=False):
        rgb, mask, *rest = (np.asarray(a) for a in jax.device_get(fn(jax.random.fold_in(base, i))))
        out.append((rgb, mask, np.ones(len(rgb), bool), *rest))
    return out
