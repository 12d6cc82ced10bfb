"""The synthetic segmentation dataset (the work of `python -m mjxrow.seg.synth`; its parser and
the dataset's layout: `mjxrow.seg.synth`): RGB images and binary plant masks rendered by
`render.py`, every sample a function of (crop, seed, i) only, so that a re-run resumes.

Camera poses: the robot's view down a lane mostly — a random lane (lanes the robot fits in
four times out of five), a lateral offset inside the lane's free width, anywhere along the row
from 3 m before its start to 1 m past its end, heading along ±x with a few degrees of yaw noise,
height 0.30-0.65 m and pitch about −10°; one sample in six looks from higher (0.65-1.5 m) and
steeper, one in ten turns to any heading.
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
from mjxrow.field import params as field_params
from mjxrow.seg import synth as synth_cli

COLUMNS = ("rgb", "mask", "crop", "condition", "x", "y", "z", "yaw", "pitch", "lateral", "split")

# field variation around the preset: factor ranges, then absolute ranges
_FACTORS = {"d_rr": (0.92, 1.12), "d_RR": (0.92, 1.15), "d_pp": (0.85, 1.2),
            "plant_length": (0.8, 1.2), "plant_width": (0.8, 1.15), "plant_height": (0.75, 1.25),
            "terrain_dh": (0.3, 1.5), "terrain_scale": (0.6, 1.6), "plant_jitter": (0.5, 2.0),
            "stone_density": (0.0, 2.0), "branch_density": (0.0, 2.0)}
_ABSOLUTE = {"p_missing": (0.0, 0.08), "plant_size_var": (0.04, 0.14),
             "slope_x": (-0.03, 0.03), "slope_y": (-0.03, 0.03)}
_MORE_WITH_LESS = ("d_rr", "d_RR", "d_pp")  # counts grow as these shrink


def dataset_shape(crop: str) -> mjxrow_field.FieldShape:
    """Static shape that holds every field the sampler can draw for `crop`."""
    pre = crops.get(crop).preset
    ext = {k: pre[k] * (lo if k in _MORE_WITH_LESS else hi) for k, (lo, hi) in _FACTORS.items()}
    return mjxrow_field.fit_shape(mjxrow_field.make_params(crop, **ext), crop)


def random_params(crop: str, key: jax.Array) -> mjxrow_field.FieldParams:
    """The crop's preset with geometry, terrain and obstacle numbers drawn around it."""
    pre = crops.get(crop).preset
    ks = jax.random.split(key, len(_FACTORS) + len(_ABSOLUTE))
    vals = {}
    for kk, (name, (lo, hi)) in zip(ks, _FACTORS.items(), strict=False):
        vals[name] = pre[name] * jax.random.uniform(kk, (), minval=lo, maxval=hi)
    for kk, (name, (lo, hi)) in zip(ks[len(_FACTORS):], _ABSOLUTE.items(), strict=True):
        vals[name] = jax.random.uniform(kk, (), minval=lo, maxval=hi)
    return mjxrow_field.make_params(crop, **vals)


def sample_pose(
    field: mjxrow_field.Field, key: jax.Array
) -> tuple[jax.Array, jax.Array, jax.Array]:
    """A camera pose in `field`: (cam_pos float32 [3], cam_rot float32 [3, 3],
    meta float32 [6] = x, y, z [m], yaw, pitch [rad], lateral offset from the lane centre [m])."""
    ks = jax.random.split(key, 10)
    q = field_params._scaled(field.params)
    free = field.lane_width - q["plant_width"]
    fits = field.lane_active & (free >= mjxrow_field.ROBOT_WIDTH + mjxrow_field.LANE_CLEARANCE)
    robot_lanes = jnp.any(fits)
    pick_fit = (jax.random.uniform(ks[0]) < 0.8) & robot_lanes
    pool = jnp.where(pick_fit, fits, field.lane_active)
    logits = jnp.where(pool, 0.0, -jnp.inf)
    lane = jax.random.categorical(ks[1], logits)
    half_free = 0.5 * jnp.maximum(free[lane], 0.05)
    lateral = jax.random.uniform(ks[2], (), minval=-0.6, maxval=0.6) * half_free
    y = field.lane_y[lane] + lateral
    x = jax.random.uniform(ks[3], (), minval=field.row_x[0] - 3.0, maxval=field.row_x[1] + 1.0)
    backward = jax.random.uniform(ks[4]) < 0.5
    yaw = jnp.where(backward, jnp.pi, 0.0) + jnp.deg2rad(6.0) * jax.random.normal(ks[5])
    any_heading = jax.random.uniform(ks[6]) < 0.1
    yaw = jnp.where(any_heading, jax.random.uniform(ks[7], (), maxval=2 * jnp.pi), yaw)
    high = jax.random.uniform(ks[8]) < 1.0 / 6.0
    kh, kp = jax.random.split(ks[9])
    h_low = jax.random.uniform(kh, (), minval=0.30, maxval=0.65)
    h_high = jax.random.uniform(kh, (), minval=0.65, maxval=1.5)
    height = jnp.where(high, h_high, h_low)
    p_low = jnp.deg2rad(jnp.clip(-10.0 + 5.0 * jax.random.normal(kp), -25.0, 3.0))
    p_high = jnp.deg2rad(jax.random.uniform(kp, (), minval=-35.0, maxval=-12.0))
    pitch = jnp.where(high, p_high, p_low)
    z = mjxrow_field.terrain_height(field.terrain, field.terrain_size, x, y) + height
    pos = jnp.stack([x, y, z]).astype(jnp.float32)
    meta = jnp.stack([x, y, z, jnp.mod(yaw + jnp.pi, 2 * jnp.pi) - jnp.pi, pitch, lateral])
    return pos, mjxrow_render.camera_rot(yaw, pitch), meta.astype(jnp.float32)


def sample(
    crop: str,
    shape: mjxrow_field.FieldShape,
    intr: mjxrow_render.Intrinsics,
    key: jax.Array,
    condition: jax.Array,
    augment: bool = True,
    cfg: mjxrow_render.RenderConfig = mjxrow_render.DEFAULT_CONFIG,
):
    """One sample (pure): its own field, pose and lighting from `key`; condition: int index
    into render.CONDITIONS. Returns (rgb uint8 [H, W, 3], mask bool [H, W], meta float32 [6])."""
    k_par, k_fld, k_pose, k_cond, k_img = jax.random.split(key, 5)
    field = mjxrow_field.generate(random_params(crop, k_par), shape, k_fld)
    pos, rot, meta = sample_pose(field, k_pose)
    cond = mjxrow_render.condition_by_index(condition, k_cond)
    frame = mjxrow_render.render(
        field, shape, pos, rot, intr, cond, k_img if augment else None, cfg
    )
    return frame.rgb, frame.mask, meta


def sample_meta(crop: str, shape: mjxrow_field.FieldShape, key: jax.Array) -> jax.Array:
    """The pose meta of `sample` without rendering (same key ⇒ same numbers)."""
    k_par, k_fld, k_pose, _, _ = jax.random.split(key, 5)
    field = mjxrow_field.generate(random_params(crop, k_par), shape, k_fld)
    return sample_pose(field, k_pose)[2]


def make_batch_fn(crop: str, intr: mjxrow_render.Intrinsics, augment: bool = True,
                  cfg: mjxrow_render.RenderConfig = mjxrow_render.DEFAULT_CONFIG):
    """On-the-fly training data: `fn(key, batch) -> (rgb uint8 [B, H, W, 3], mask bool [B, H, W])`
    with `batch` a static int; fields, poses and conditions (uniform over the four) drawn from
    `key`. Jittable (`jax.jit(fn, static_argnums=1)`); called as is, it runs one compiled
    renderer per (crop, intr, augment, cfg) that `write_dataset` shares."""
    core = _render_fn(crop, intr, augment, cfg)

    def fn(key: jax.Array, batch: int):
        k_s, k_c = jax.random.split(key)
        keys = jax.random.split(k_s, batch)
        conds = jax.random.randint(k_c, (batch,), 0, len(mjxrow_render.CONDITIONS))
        rgb, mask, _ = core(keys, conds)
        return rgb, mask

    return fn


@functools.lru_cache(maxsize=16)
def _render_fn(
    crop: str, intr: mjxrow_render.Intrinsics, augment: bool, cfg: mjxrow_render.RenderConfig
):
    """jit(vmap(sample)): (keys [B], conditions int [B]) -> (rgb, mask, meta), one compile per
    argument set (and batch size)."""
    shape = dataset_shape(crop)
    return jax.jit(jax.vmap(lambda k, c: sample(crop, shape, intr, k, c, augment, cfg)))


@functools.lru_cache(maxsize=16)
def _meta_fn(crop: str):
    shape = dataset_shape(crop)
    return jax.jit(jax.vmap(lambda k: sample_meta(crop, shape, k)))


def sample_keys(seed: int, index: jax.Array) -> jax.Array:
    """Key of sample `index` (int32 [B]) of a dataset with `seed`."""
    base = jax.random.key(seed)
    return jax.vmap(lambda i: jax.random.fold_in(base, i))(index)


# ---------------------------------------------------------------------------------------------
# Writing a dataset (host)


def rel_paths(crop: str, i: int) -> tuple[str, str]:
    cond = mjxrow_render.CONDITIONS[i % len(mjxrow_render.CONDITIONS)]
    return f"{cond}/rgb/{crop}_{i:06d}.png", f"{cond}/mask/{crop}_{i:06d}.png"


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


def remove_damaged(out: Path, paths: list[tuple[str, str]], size: int) -> list[str]:
    """Check every existing image of the dataset (`png_problem`); remove the damaged ones, so
    that they are rendered again. Returns their paths relative to `out`."""
    bad = []
    for pair in paths:
        for rel in pair:
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
) -> Path:
    """Render and write `n` samples of `crop` into `out` (resumable); returns the index path.
    test_frac: share of each condition in the test split (None: the crop's `test_frac`)."""
    out = Path(out)
    test_frac = crops.get(crop).test_frac if test_frac is None else test_frac
    for cond in mjxrow_render.CONDITIONS:
        (out / cond / "rgb").mkdir(parents=True, exist_ok=True)
        (out / cond / "mask").mkdir(parents=True, exist_ok=True)
    meta_fn = _meta_fn(crop)
    render_fn = _render_fn(
        crop, mjxrow_render.Intrinsics(size, size, mjxrow_render.Intrinsics().fovy), True, cfg
    )
    batch = min(batch, n)
    all_idx = np.arange(n)
    metas = []
    meta_batch = min(512, 1 << (n - 1).bit_length())
    for chunk, pad in tqdm(list(_batches(all_idx, meta_batch)), desc=f"{crop} poses",
                           unit="batch", disable=not progress or n <= 4 * meta_batch):
        metas.append(np.asarray(meta_fn(sample_keys(seed, jnp.asarray(pad))))[: len(chunk)])
    meta = np.concatenate(metas)

    paths = [rel_paths(crop, i) for i in range(n)]
    for folder in [out] + [out / c / k for c in mjxrow_render.CONDITIONS for k in ("rgb", "mask")]:
        for tmp in folder.glob(".tmp_*"):  # temp files of a killed run
            tmp.unlink(missing_ok=True)
    damaged = remove_damaged(out, paths, size)
    if damaged:
        print(f"{len(damaged)} damaged image(s) in {out} removed and rendered again: "
              + ", ".join(damaged[:5]) + (" ..." if len(damaged) > 5 else ""), file=sys.stderr)
    todo = np.array([i for i in range(n) if not ((out / paths[i][0]).exists()
                                                and (out / paths[i][1]).exists())], np.int64)
    bar = tqdm(total=n, initial=n - len(todo), desc=f"{crop} dataset", unit="img",
               disable=not progress, smoothing=0.1)
    with cf.ThreadPoolExecutor(max(1, workers)) as pool:
        pending: list[cf.Future] = []
        for chunk, pad in _batches(todo, batch) if len(todo) else ():
            conds = jnp.asarray(pad % len(mjxrow_render.CONDITIONS), jnp.int32)
            rgb, mask, _ = render_fn(sample_keys(seed, jnp.asarray(pad)), conds)
            rgb, mask = np.asarray(rgb), np.asarray(mask)
            for done in pending:
                done.result()
            pending = []
            for j, i in enumerate(chunk):  # only the missing file(s) of each pair
                rgb_p, mask_p = (out / p for p in paths[i])
                if not rgb_p.exists():
                    pending.append(pool.submit(_write_png, rgb_p, rgb[j]))
                if not mask_p.exists():
                    pending.append(pool.submit(_write_png, mask_p,
                                               mask[j].astype(np.uint8) * 255))
            bar.update(len(chunk))
        for done in pending:
            done.result()
    bar.close()

    table = pd.DataFrame(
        {
            "rgb": [p[0] for p in paths],
            "mask": [p[1] for p in paths],
            "crop": crop,
            "condition": [
                mjxrow_render.CONDITIONS[i % len(mjxrow_render.CONDITIONS)] for i in range(n)
            ],
            "x": meta[:, 0],
            "y": meta[:, 1],
            "z": meta[:, 2],
            "yaw": meta[:, 3],
            "pitch": meta[:, 4],
            "lateral": meta[:, 5],
            "split": splits(n, seed, test_frac),
        }
    )
    text = table.to_csv(index=False, float_format="%.4f", columns=list(COLUMNS))
    index = out / "index.csv"
    if not index.exists() or index.read_text() != text:
        fd, tmp = tempfile.mkstemp(dir=out, prefix=".tmp_", suffix=".csv")
        with os.fdopen(fd, "w") as f:
            f.write(text)
        os.replace(tmp, index)
    return index


def contact_sheet(crop: str, path: str | Path, per_condition: int = 3, size: int = 160,
                  seed: int = 0) -> Path:
    """A PNG with `per_condition` samples of each condition (rows), RGB beside mask."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    intr = mjxrow_render.Intrinsics(size, size, mjxrow_render.Intrinsics().fovy)
    nc = len(mjxrow_render.CONDITIONS)
    idx = np.array([c + nc * j for c in range(nc) for j in range(per_condition)], np.int32)
    fn = _render_fn(crop, intr, True, mjxrow_render.DEFAULT_CONFIG)
    rgb, mask, _ = fn(sample_keys(seed, jnp.asarray(idx)), jnp.asarray(idx % nc))
    rgb, mask = np.asarray(rgb), np.asarray(mask)
    fig, axes = plt.subplots(nc, 2 * per_condition, figsize=(2.0 * 2 * per_condition, 2.1 * nc))
    for r in range(nc):
        for j in range(per_condition):
            s = r * per_condition + j
            for col, (img, kw) in enumerate(((rgb[s], {}), (mask[s], {"cmap": "gray"}))):
                ax = axes[r, 2 * j + col]
                ax.imshow(img, vmin=0, vmax=1, **kw) if col else ax.imshow(img)
                ax.set_xticks([])
                ax.set_yticks([])
            if j == 0:
                axes[r, 0].set_ylabel(mjxrow_render.CONDITIONS[r].replace("_", " "), fontsize=11)
    fig.suptitle(f"{crop}: synthetic RGB and plant mask ({size}×{size})", fontsize=12)
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
                            seed=args.seed))
        return 0
    with interrupt.HardStop():  # Ctrl-C: exit 130; a re-run resumes (and cleans up)
        index = write_dataset(args.crop, args.n, args.out, args.seed, args.size,
                              args.test_frac, args.batch, args.workers)
    print(f"{args.n} samples of {args.crop} in {args.out}; index: {index}")
    return 0

