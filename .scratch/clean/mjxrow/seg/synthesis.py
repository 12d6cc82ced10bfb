"""The synthetic segmentation dataset (the work of `python -m mjxrow.seg.synth`; its parser and
the dataset's layout: `mjxrow.seg.synth`): RGB images, binary crop masks and class images
rendered by `mjxrow.render`, every sample a function of (crop, seed, variety, i) only, so that
a re-run resumes. The fields and camera poses are `mjxrow.seg.scenes`'s.
"""

from __future__ import annotations

import concurrent.futures as cf
import functools
import io
import os
import sys
import tempfile
from pathlib import Path

import jax
import jax.numpy as jnp
import numpy as np
import pandas as pd
from PIL import Image
from tqdm.auto import tqdm

from mjxrow import crops, files, interrupt
from mjxrow import field as mjxrow_field
from mjxrow import render as mjxrow_render
from mjxrow.seg import scenes
from mjxrow.seg import synth as synth_cli
from mjxrow.seg.scenes import VARIETIES, dataset_shape, random_params, sample_pose

__all__ = ["COLUMNS", "META", "VARIETIES", "contact_sheet", "dataset_shape", "make_batch_fn",
           "random_params", "sample", "sample_keys", "sample_meta", "sample_pose", "scenes",
           "write_dataset"]

# index.csv: the image paths, then the sample's labels, pose and field (META), then its split
META = ("x", "y", "z", "yaw", "pitch", "lateral", "row_amplitude", "row_curvature", "gap_rate",
        "weed_density")
COLUMNS = ("rgb", "mask", "classes", "crop", "condition", *META, "split")
_FIELD_META = META[6:]  # the FieldParams of the sample's field written to the index


def _meta(field: mjxrow_field.Field, pose_meta: jax.Array) -> jax.Array:
    """float32 [len(META)]: the pose's meta and the field's curvature, gap and weed numbers."""
    more = jnp.stack([getattr(field.params, k) for k in _FIELD_META])
    return jnp.concatenate([pose_meta, more.astype(jnp.float32)])


def sample(
    crop: str,
    shape: mjxrow_field.FieldShape,
    intr: mjxrow_render.Intrinsics,
    key: jax.Array,
    condition: jax.Array,
    augment: bool = True,
    cfg: mjxrow_render.RenderConfig = mjxrow_render.DEFAULT_CONFIG,
    variety: str = "fields",
):
    """One sample (pure): its own field, pose and lighting from `key`; condition: int index
    into render.CONDITIONS. Returns (rgb uint8 [H, W, 3], mask bool [H, W] (crop plants),
    classes uint8 [H, W] (`render`'s class ids, weeds their own), meta float32 [len(META)])."""
    k_par, k_fld, k_pose, k_cond, k_img = jax.random.split(key, 5)
    field = mjxrow_field.generate(random_params(crop, k_par, variety), shape, k_fld)
    pos, rot, meta = sample_pose(field, k_pose)
    cond = mjxrow_render.condition_by_index(condition, k_cond)
    frame = mjxrow_render.render(
        field, shape, pos, rot, intr, cond, k_img if augment else None, cfg
    )
    return frame.rgb, frame.mask, frame.classes, _meta(field, meta)


def sample_meta(crop: str, shape: mjxrow_field.FieldShape, key: jax.Array,
                variety: str = "fields") -> jax.Array:
    """The meta of `sample` without rendering (same key ⇒ same numbers)."""
    k_par, k_fld, k_pose, _, _ = jax.random.split(key, 5)
    field = mjxrow_field.generate(random_params(crop, k_par, variety), shape, k_fld)
    return _meta(field, sample_pose(field, k_pose)[2])


def make_batch_fn(crop: str, intr: mjxrow_render.Intrinsics, augment: bool = True,
                  cfg: mjxrow_render.RenderConfig = mjxrow_render.DEFAULT_CONFIG,
                  variety: str = "fields", labels: bool = False):
    """On-the-fly training data: `fn(key, batch) -> (rgb uint8 [B, H, W, 3], mask bool [B, H, W])`
    with `batch` a static int; fields, poses and conditions (uniform over the four) drawn from
    `key`. labels: also the class images and the conditions, `(rgb, mask, classes uint8
    [B, H, W], condition int32 [B])` (for evaluation: weeds, per-condition scores). Jittable
    (`jax.jit(fn, static_argnums=1)`); called as is, it runs one compiled renderer per (crop,
    intr, augment, cfg, variety) that `write_dataset` shares."""
    core = _render_fn(crop, intr, augment, cfg, variety)

    def fn(key: jax.Array, batch: int):
        k_s, k_c = jax.random.split(key)
        keys = jax.random.split(k_s, batch)
        conds = jax.random.randint(k_c, (batch,), 0, len(mjxrow_render.CONDITIONS))
        rgb, mask, classes, _ = core(keys, conds)
        return (rgb, mask, classes, conds) if labels else (rgb, mask)

    return fn


@functools.lru_cache(maxsize=16)
def _render_fn(crop: str, intr: mjxrow_render.Intrinsics, augment: bool,
               cfg: mjxrow_render.RenderConfig, variety: str):
    """jit(vmap(sample)): (keys [B], conditions int [B]) -> (rgb, mask, classes, meta), one
    compile per argument set (and batch size)."""
    shape = dataset_shape(crop, variety)
    return jax.jit(jax.vmap(lambda k, c: sample(crop, shape, intr, k, c, augment, cfg, variety)))


@functools.lru_cache(maxsize=16)
def _meta_fn(crop: str, variety: str):
    shape = dataset_shape(crop, variety)
    return jax.jit(jax.vmap(lambda k: sample_meta(crop, shape, k, variety)))


def sample_keys(seed: int, index: jax.Array) -> jax.Array:
    """Key of sample `index` (int32 [B]) of a dataset with `seed`."""
    base = jax.random.key(seed)
    return jax.vmap(lambda i: jax.random.fold_in(base, i))(index)


# ---------------------------------------------------------------------------------------------
# Writing a dataset (host)


def rel_paths(crop: str, i: int) -> tuple[str, str, str]:
    """The (rgb, mask, classes) paths of sample i, relative to the dataset folder."""
    cond = mjxrow_render.CONDITIONS[i % len(mjxrow_render.CONDITIONS)]
    return tuple(f"{cond}/{kind}/{crop}_{i:06d}.png" for kind in ("rgb", "mask", "class"))


def splits(n: int, seed: int, test_frac: float) -> np.ndarray:
    """'train' / 'test' per sample: round(test_frac · n_c) test samples in each condition."""
    out = np.full(n, "train", dtype=object)
    rng = np.random.default_rng(seed)
    nc = len(mjxrow_render.CONDITIONS)
    for c in range(nc):
        idx = np.arange(c, n, nc)
        test = rng.permutation(idx)[: int(round(test_frac * len(idx)))]
        out[test] = "test"
    return out


def _write_png(path: Path, img: np.ndarray) -> None:
    fd, tmp = tempfile.mkstemp(dir=path.parent, prefix=".tmp_", suffix=".png")
    try:
        with os.fdopen(fd, "wb") as f:
            Image.fromarray(img).save(f, format="PNG")
        os.replace(tmp, path)
    except BaseException:
        Path(tmp).unlink(missing_ok=True)
        raise


def png_problem(path: Path, size: int) -> str | None:
    """Why an existing dataset PNG cannot be kept (None: it can): unreadable, damaged (PIL's
    verify, then a full decode: a file cut short fails there), or not size × size."""
    try:
        with Image.open(path) as im:
            im.verify()
        with Image.open(path) as im:
            im.load()
            if im.size != (size, size):
                return f"{im.size[0]}x{im.size[1]} instead of {size}x{size}"
    except (OSError, SyntaxError, ValueError) as e:
        return f"damaged ({str(e).splitlines()[0] if str(e) else type(e).__name__})"
    return None


def remove_damaged(out: Path, paths: list[tuple[str, ...]], size: int) -> list[str]:
    """Check every existing image of the dataset (`png_problem`); remove the damaged ones, so
    that they are rendered again. Returns their paths relative to `out`."""
    bad = []
    for group in paths:
        for rel in group:
            p = out / rel
            if p.exists() and png_problem(p, size) is not None:
                p.unlink()
                bad.append(rel)
    return bad


def _batches(indices: np.ndarray, batch: int):
    for s in range(0, len(indices), batch):
        chunk = indices[s:s + batch]
        pad = np.concatenate([chunk, np.full(batch - len(chunk), chunk[-1])])
        yield chunk, pad.astype(np.int32)


def check_same_samples(index: Path, table: pd.DataFrame) -> None:
    """OutputError (a ValueError) when an existing `index` lists other samples than `table`
    under the same image paths (another seed or variety: its images would be mixed with the
    new ones)."""
    if not index.is_file():
        return
    try:
        old = pd.read_csv(index)
    except (OSError, ValueError, pd.errors.ParserError):
        return  # a damaged index is rewritten
    n = min(len(old), len(table))
    cols = [c for c in ("rgb", "x", "y", "z", "yaw", "pitch") if c in old.columns]
    if n == 0 or "rgb" not in cols:
        return
    same = (old["rgb"].iloc[:n].to_numpy() == table["rgb"].iloc[:n].to_numpy()).all()
    for c in cols[1:]:
        same &= bool(np.allclose(old[c].iloc[:n].to_numpy(float),
                                 table[c].iloc[:n].to_numpy(float), atol=2e-3))
    if not same:
        raise files.OutputError(f"--out {index.parent}: holds samples of another --seed or "
                                "--variety (its index.csv lists other camera poses); give "
                                "another --out")


def write_dataset(
    crop: str,
    n: int,
    out: str | Path,
    seed: int = 0,
    size: int = 224,
    test_frac: float | None = None,
    batch: int = 64,
    workers: int = 4,
    cfg: mjxrow_render.RenderConfig = mjxrow_render.DEFAULT_CONFIG,
    progress: bool = True,
    variety: str = "fields",
) -> Path:
    """Render and write `n` samples of `crop` into `out` (resumable); returns the index path.
    test_frac: share of each condition in the test split (None: the crop's `test_frac`).
    variety: "fields" (curved rows, gaps and weeds in a share of the fields) or "none"."""
    out = Path(out)
    test_frac = crops.get(crop).test_frac if test_frac is None else test_frac
    dataset_shape(crop, variety)  # ValueError naming a bad variety, before any work
    meta_fn = _meta_fn(crop, variety)
    metas = []
    meta_batch = min(512, 1 << (n - 1).bit_length())
    for chunk, pad in tqdm(list(_batches(np.arange(n), meta_batch)), desc=f"{crop} poses",
                           unit="batch", disable=not progress or n <= 4 * meta_batch):
        metas.append(np.asarray(meta_fn(sample_keys(seed, jnp.asarray(pad))))[: len(chunk)])
    meta = np.concatenate(metas)
    paths = [rel_paths(crop, i) for i in range(n)]
    conds = mjxrow_render.CONDITIONS
    table = pd.DataFrame({
        "rgb": [p[0] for p in paths], "mask": [p[1] for p in paths],
        "classes": [p[2] for p in paths], "crop": crop,
        "condition": [conds[i % len(conds)] for i in range(n)],
        **{name: meta[:, j] for j, name in enumerate(META)},
        "split": splits(n, seed, test_frac),
    })
    index = out / "index.csv"
    check_same_samples(index, table)

    for cond in conds:
        for kind in ("rgb", "mask", "class"):
            (out / cond / kind).mkdir(parents=True, exist_ok=True)
    for folder in [out] + [out / c / k for c in conds for k in ("rgb", "mask", "class")]:
        for tmp in folder.glob(".tmp_*"):  # temp files of a killed run
            tmp.unlink(missing_ok=True)
    damaged = remove_damaged(out, paths, size)
    if damaged:
        print(f"{len(damaged)} damaged image(s) in {out} removed and rendered again: "
              + ", ".join(damaged[:5]) + (" ..." if len(damaged) > 5 else ""), file=sys.stderr)
    todo = np.array([i for i in range(n) if not all((out / p).exists() for p in paths[i])],
                    np.int64)
    render_fn = _render_fn(crop, mjxrow_render.Intrinsics(size, size,
                                                          mjxrow_render.Intrinsics().fovy),
                           True, cfg, variety)
    batch = min(batch, n)
    bar = tqdm(total=n, initial=n - len(todo), desc=f"{crop} dataset", unit="img",
               disable=not progress, smoothing=0.1)
    with cf.ThreadPoolExecutor(max(1, workers)) as pool:
        pending: list[cf.Future] = []
        for chunk, pad in _batches(todo, batch) if len(todo) else ():
            cond_idx = jnp.asarray(pad % len(conds), jnp.int32)
            rgb, mask, classes, _ = render_fn(sample_keys(seed, jnp.asarray(pad)), cond_idx)
            images = (np.asarray(rgb), np.asarray(mask).astype(np.uint8) * 255,
                      np.asarray(classes))
            for done in pending:
                done.result()
            pending = []
            for j, i in enumerate(chunk):  # only the missing file(s) of each sample
                for rel, img in zip(paths[i], images, strict=True):
                    if not (out / rel).exists():
                        pending.append(pool.submit(_write_png, out / rel, img[j]))
            bar.update(len(chunk))
        for done in pending:
            done.result()
    bar.close()

    text = table.to_csv(index=False, float_format="%.4f", columns=list(COLUMNS))
    if not index.exists() or index.read_text() != text:
        fd, tmp = tempfile.mkstemp(dir=out, prefix=".tmp_", suffix=".csv")
        with os.fdopen(fd, "w") as f:
            f.write(text)
        os.replace(tmp, index)
    return index


def label_image(mask: np.ndarray, classes: np.ndarray) -> np.ndarray:
    """uint8 [H, W, 3] for a look: crop plants white, weeds magenta, the rest black."""
    out = np.zeros((*mask.shape, 3), np.uint8)
    out[classes == mjxrow_render.WEED] = (230, 40, 200)
    out[mask] = 255
    return out


def contact_sheet(crop: str, path: str | Path, per_condition: int = 3, size: int = 160,
                  seed: int = 0, variety: str = "fields") -> Path:
    """A PNG with `per_condition` samples of each condition (rows), RGB beside the labels
    (crop white, weeds magenta)."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    intr = mjxrow_render.Intrinsics(size, size, mjxrow_render.Intrinsics().fovy)
    nc = len(mjxrow_render.CONDITIONS)
    idx = np.array([c + nc * j for c in range(nc) for j in range(per_condition)], np.int32)
    fn = _render_fn(crop, intr, True, mjxrow_render.DEFAULT_CONFIG, variety)
    rgb, mask, classes, _ = jax.device_get(fn(sample_keys(seed, jnp.asarray(idx)),
                                              jnp.asarray(idx % nc)))
    fig, axes = plt.subplots(nc, 2 * per_condition, figsize=(2.0 * 2 * per_condition, 2.1 * nc))
    for r in range(nc):
        for j in range(per_condition):
            s = r * per_condition + j
            for col, img in enumerate((rgb[s], label_image(mask[s], classes[s]))):
                ax = axes[r, 2 * j + col]
                ax.imshow(img)
                ax.set_xticks([])
                ax.set_yticks([])
            if j == 0:
                axes[r, 0].set_ylabel(mjxrow_render.CONDITIONS[r].replace("_", " "), fontsize=11)
    fig.suptitle(f"{crop}: synthetic RGB and labels, crop white, weeds magenta ({size}×{size})",
                 fontsize=12)
    fig.tight_layout()
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    buf = io.BytesIO()
    fig.savefig(buf, dpi=80, format="png")
    plt.close(fig)
    # a 256-colour palette keeps the sheet small enough for the repository
    Image.open(buf).convert("RGB").quantize(256).save(path, optimize=True)
    return path


def __getattr__(name: str):
    """`PAPER_N` (crop → samples of the paper's dataset), read from the registry when asked;
    kept for the modules that still use it (new code reads `crops.get(name).dataset_n`)."""
    if name == "PAPER_N":
        return {n: c.dataset_n for n, c in crops.CROPS.items()}
    raise AttributeError(f"module {__name__!r} has no attribute {name!r}")


def main(argv: list[str] | None = None) -> int:
    """`python -m mjxrow.seg.synth ARGS` (`mjxrow.seg.synth.main` hands over here)."""
    args = synth_cli.parse(argv)
    try:  # an unknown crop or an unwritable folder: one line, before any work
        crops.get(args.crop)
        if not args.contact_sheet:
            files.check_out_dir(args.out, "--out")
    except ValueError as e:
        print(f"error: {e}", file=sys.stderr)
        return 2
    if args.contact_sheet:
        print(contact_sheet(args.crop, args.contact_sheet, args.per_condition,
                            seed=args.seed, variety=args.variety))
        return 0
    try:
        with interrupt.HardStop():  # Ctrl-C: exit 130; a re-run resumes (and cleans up)
            index = write_dataset(args.crop, args.n, args.out, args.seed, args.size,
                                  args.test_frac, args.batch, args.workers,
                                  variety=args.variety)
    except files.OutputError as e:  # a folder of another seed or variety
        print(f"error: {e}", file=sys.stderr)
        return 2
    print(f"{args.n} samples of {args.crop} in {args.out}; index: {index}")
    return 0

