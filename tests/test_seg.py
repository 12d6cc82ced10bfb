"""Segmenter: architecture facts, losses, a training step, resume, checkpoints, ONNX, evaluation."""

from __future__ import annotations

import dataclasses
import itertools
import json
import math

import jax
import jax.numpy as jnp
import numpy as np
import pandas as pd
import pytest
from PIL import Image

from mjxrow import crops
from mjxrow import render as RD
from mjxrow.seg import checkpoint as C
from mjxrow.seg import convs as SC
from mjxrow.seg import data as D
from mjxrow.seg import evaluation as E
from mjxrow.seg import model as M
from mjxrow.seg import step as ST
from mjxrow.seg import training as T

H, W = 32, 48


def blobs(n: int, h: int = H, w: int = W, seed: int = 0) -> tuple[np.ndarray, np.ndarray]:
    """Green discs on brown soil: (rgb uint8 [n, h, w, 3], mask bool [n, h, w])."""
    rng = np.random.default_rng(seed)
    yy, xx = np.mgrid[:h, :w]
    rgb = np.empty((n, h, w, 3), np.uint8)
    mask = np.empty((n, h, w), bool)
    for i in range(n):
        cx, cy, r = rng.uniform(8, w - 8), rng.uniform(8, h - 8), rng.uniform(4, 9)
        mask[i] = (xx - cx) ** 2 + (yy - cy) ** 2 < r * r
        img = np.where(mask[i][..., None], [40, 160, 50], [120, 90, 60])
        rgb[i] = np.clip(img + rng.integers(-15, 16, img.shape), 0, 255)
    return rgb, mask


@pytest.fixture(scope="module")
def tiny():
    """Tiny net with perturbed BatchNorm statistics (so folding and running stats matter)."""
    module, variables = M.create("tiny", 1.0, jax.random.key(0), (H, W), dw_impl="conv")
    rng = np.random.default_rng(1)
    variables["batch_stats"] = jax.tree.map(
        lambda x: jnp.asarray(rng.uniform(0.5, 1.5, x.shape), jnp.float32),
        variables["batch_stats"])
    return module, variables


@pytest.fixture(scope="module")
def apply_fn(tiny):
    module, _ = tiny
    return jax.jit(lambda v, x: M.apply(module, v, x))


def test_output_shape_dtype_and_range(tiny, apply_fn):
    module, variables = tiny
    rgb, _ = blobs(2)
    logits = apply_fn(variables, rgb)
    assert logits.shape == (2, H, W) and logits.dtype == jnp.float32
    assert bool(jnp.all(jnp.isfinite(logits)))
    p = jax.nn.sigmoid(logits)
    assert float(p.min()) >= 0.0 and float(p.max()) <= 1.0
    mask = jax.jit(M.predict_mask, static_argnums=0)(module, variables, rgb, 0.7)
    assert mask.dtype == jnp.bool_ and mask.shape == (2, H, W)
    np.testing.assert_array_equal(mask, p > 0.7)
    with pytest.raises(ValueError, match="rgb"):
        M.apply(module, variables, rgb[..., :2])


def test_published_architecture_facts():
    # Backbone parameters (conv + BN affine, up to the last 1×1 conv, no classifier): the
    # published totals (Large 5.4 M, Small 2.5 M) minus the classifier (960·1280 + 1280 +
    # 1280·1000 + 1000; 576·1024 + 1024 + 1024·1000 + 1000) = 2,971,952 and 927,008.
    for arch, want in (("large", 5_483_032 - 2_511_080), ("small", 2_542_856 - 1_615_848)):
        v = M.abstract_variables(M.SegNet(arch=arch))
        assert M.param_count(v["params"]["backbone"]) == want, arch
    # Feature strides: 1/8 (40 channels) and, with the dilated last stage, 1/16 (960 channels).
    for os_, side in ((16, 14), (32, 7)):
        plan = M.plan("large", 1.0, output_stride=os_)
        net = M.MobileNetV3(plan)
        x = jax.ShapeDtypeStruct((1, 224, 224, 3), jnp.float32)
        shapes = jax.eval_shape(lambda x, net=net: net.init_with_output(
            jax.random.key(0), x, False)[0], x)
        assert shapes[0].shape == (1, 28, 28, 40) and shapes[1].shape == (1, side, side, 960)
    small = M.plan("small")
    assert (small.low_channels, small.last) == (24, 576)
    assert [ly.dilation for ly in small.layers[-3:]] == [2, 2, 2]
    # width multiplier rounding: 18 → 24 (16 would be >10 % below), 12 → 16, 20 → 24
    assert (M.make_divisible(18), M.make_divisible(12), M.make_divisible(20)) == (24, 16, 24)
    assert M.plan("small", 0.75).stem == 16 and M.plan("large", 0.5).last == 480
    with pytest.raises(ValueError, match="arch"):
        M.plan("medium")


def test_depthwise_shift_equals_grouped_conv():
    rng = np.random.default_rng(0)
    x = jnp.asarray(rng.standard_normal((2, 13, 16, 6)), jnp.float32)
    shift = jax.jit(SC.depthwise_shift, static_argnums=(2, 3))
    for k, s, d in ((5, 2, 1), (3, 1, 2)):
        kern = jnp.asarray(rng.standard_normal((k, k, 1, 6)), jnp.float32)
        p = (k - 1) // 2 * d
        ref = jax.lax.conv_general_dilated(x, kern, (s, s), ((p, p), (p, p)),
                                           rhs_dilation=(d, d),
                                           dimension_numbers=("NHWC", "HWIO", "NHWC"),
                                           feature_group_count=6)
        np.testing.assert_allclose(shift(x, kern, s, d), ref, atol=1e-5)


def test_dilated_conv_as_phases_equals_dilated_conv():
    rng = np.random.default_rng(2)
    for (h, w), k, d in (((14, 14), 5, 2), ((13, 10), 3, 2), ((7, 11), 3, 3)):
        x = jnp.asarray(rng.standard_normal((2, h, w, 4)), jnp.float32)
        kern = jnp.asarray(rng.standard_normal((k, k, 1, 4)), jnp.float32)

        def conv(x, d, k=k, kern=kern):
            p = (k - 1) // 2 * d
            return jax.lax.conv_general_dilated(x, kern, (1, 1), ((p, p), (p, p)),
                                                rhs_dilation=(d, d),
                                                dimension_numbers=("NHWC", "HWIO", "NHWC"),
                                                feature_group_count=4)

        got = SC.dilated_as_phases(x, d, lambda y: conv(y, 1))
        assert got.shape == (2, h, w, 4)
        np.testing.assert_allclose(got, conv(x, d), atol=1e-5)


def test_conv_implementations_agree_on_the_same_parameters():
    """Every depthwise x 1x1 implementation computes the same logits from the same variables
    (a checkpoint loads into any of them), dilated last stage included (output stride 8)."""
    module, variables = M.create("tiny", 1.0, jax.random.key(3), (H, W), output_stride=8)
    assert any(ly.dilation > 1 for ly in module.resolved().layers)
    rgb, _ = blobs(2)
    ref = M.apply(module.clone(dw_impl="conv", pw_impl="conv"), variables, rgb)
    for dw, pw in itertools.product(SC.DW_IMPLS, SC.PW_IMPLS):
        other = module.clone(dw_impl=dw, pw_impl=pw)
        shapes = jax.tree.map(lambda a: a.shape, M.abstract_variables(other, (H, W)))
        assert shapes == jax.tree.map(lambda a: a.shape, variables)
        np.testing.assert_allclose(M.apply(other, variables, rgb), ref, atol=1e-4,
                                   err_msg=f"{dw}:{pw}")
    with pytest.raises(ValueError, match="depthwise: unknown implementation 'fft'"):
        M.apply(module.clone(dw_impl="fft"), variables, rgb)
    from mjxrow.bench import closed_loop as CL

    assert CL.seg_impl("phases:dot") == {"dw_impl": "phases", "pw_impl": "dot"}
    for bad in ("phases", "phases:fft", "fft:dot"):
        with pytest.raises(ValueError, match=f"--seg-impl '{bad}'"):
            CL.seg_impl(bad)


def test_iou_and_bce_losses_hand_computed():
    # image 0: p = 0.5 everywhere, one plant pixel of 4: I = 0.5, U = 1 + 2 − 0.5 = 2.5
    # image 1: p = 0.75 everywhere, all plant: I = 3, U = 4 + 3 − 3 = 4
    logits = jnp.stack([jnp.zeros((2, 2)), jnp.full((2, 2), math.log(3.0))])
    mask = jnp.array([[[True, False], [False, False]], [[True, True], [True, True]]])
    per_image = (1 - 0.5 / 2.5 + 1 - 3 / 4) / 2  # 0.525 (pooled would be 1 − 3.5/6.5)
    assert float(ST.iou_loss(logits, mask, smooth=0.0)) == pytest.approx(per_image, abs=1e-6)
    smooth = (1 - 1.5 / 3.5 + 1 - 4 / 5) / 2
    assert float(ST.iou_loss(logits, mask)) == pytest.approx(smooth, abs=1e-6)
    assert float(ST.iou_loss(logits, mask, jnp.array([1.0, 0.0]), smooth=0.0)) == \
        pytest.approx(0.8, abs=1e-6)
    bce = (math.log(2.0) + math.log(4 / 3)) / 2
    assert float(ST.bce_loss(logits, mask)) == pytest.approx(bce, abs=1e-6)
    # hard metrics at 0.7: image 0 predicts nothing (0.5), image 1 everything (0.75)
    c = E.counts(logits, mask)
    assert {k: float(v) for k, v in c.items()} == {"inter": 4, "union": 5, "correct": 7,
                                                   "total": 8}
    assert E.scores(c) == {"iou": 0.8, "acc": 7 / 8}


def test_augment_flip_and_grey():
    rgb, mask = blobs(3)
    key = jax.random.key(0)
    r, m = D.augment(key, rgb, mask, flip=0.0, grey=0.0)
    np.testing.assert_array_equal(r, rgb)
    np.testing.assert_array_equal(m, mask)
    r, m = D.augment(key, rgb, mask, flip=1.0, grey=0.0)
    np.testing.assert_array_equal(r, rgb[:, :, ::-1])
    np.testing.assert_array_equal(m, mask[:, :, ::-1])
    r, m = D.augment(key, rgb, mask, flip=0.0, grey=1.0)
    np.testing.assert_array_equal(m, mask)
    assert np.all(r[..., 0] == r[..., 1]) and np.all(r[..., 1] == r[..., 2])
    # soil (120, 90, 60) → 0.299·120 + 0.587·90 + 0.114·60 = 95.5 ± the noise
    soil = np.asarray(r[..., 0])[~mask]
    assert 80 < soil.mean() < 110


CFG = T.TrainConfig(steps=4, lr=1e-2, warmup=0, flip=0.0, grey=0.0, eval_every=2, ckpt_every=2,
                    log_every=1, progress=False)


def _data(batches, val):
    return T.Data(val=val, describe="test", batches=lambda start: (
        batches[s % len(batches)] for s in itertools.count(start)))


def test_training_step_lowers_loss_on_a_fixed_batch(tiny, tmp_path):
    module, variables = tiny
    rgb, mask = blobs(4, seed=3)
    val = D.batches(rgb, mask, 4)
    res = T.fit(module, variables, _data([(rgb, mask)], val), CFG, tmp_path / "run")
    log = [json.loads(line) for line in (tmp_path / "run" / "train_log.jsonl").open()]
    losses = [r["loss"] for r in log if "loss" in r]
    assert len(losses) == 4 and losses[1] < losses[0] - 1e-3  # step 1 lowered the loss
    assert losses[3] < losses[0]
    assert res["step"] == 4 and 0.0 <= res["best_iou"] <= 1.0
    best = C.read_config(tmp_path / "run" / "best")
    assert best["meta"]["val_iou"] == pytest.approx(res["best_iou"], abs=1e-6)


def test_interrupted_run_resumes_to_the_same_weights(tiny, tmp_path):
    module, variables = tiny
    batches = [blobs(4, seed=10 + i) for i in range(4)]
    val = D.batches(*blobs(4, seed=99), 4)

    def interrupted(start):
        for s in itertools.count(start):
            if s == 3:
                raise KeyboardInterrupt("simulated interruption")
            yield batches[s]

    with pytest.raises(KeyboardInterrupt):
        T.fit(module, variables, T.Data(val=val, describe="test", batches=interrupted), CFG,
              tmp_path / "a")
    resumed = T.fit(module, variables, _data(batches, val), CFG, tmp_path / "a")
    straight = T.fit(module, variables, _data(batches, val), CFG, tmp_path / "b")
    assert resumed["step"] == straight["step"] == 4
    wa, wb = (C.load(tmp_path / r / "best")[1] for r in ("a", "b"))
    for x, y in zip(jax.tree.leaves(wa), jax.tree.leaves(wb), strict=True):
        np.testing.assert_array_equal(x, y)
    logs = [[json.loads(line) for line in (tmp_path / r / "train_log.jsonl").open()]
            for r in ("a", "b")]
    losses = [[(r["step"], r["loss"]) for r in log if "loss" in r] for log in logs]
    assert [s for s, _ in losses[0]] == [1, 2, 3, 4]  # step 3 of the first run was lost
    assert losses[0] == losses[1]


# -m slow (.ci/slow): 24 s of CPU compilation of the unfused training step
@pytest.mark.slow
def test_unfused_batch_function_trains_on_the_fused_steps_batches(tiny, tmp_path):
    """The CLI's on-the-fly data runs the batch function before the step (its renderers compiled
    once, shared with the validation set): the same keys, batches and weights as the fused step."""
    module, variables = tiny

    def batch_fn(key):  # jittable and callable as is: blobs placed by the key
        c = jax.random.uniform(key, (4, 2), minval=8.0, maxval=W - 8.0)
        yy, xx = jnp.mgrid[:H, :W]
        mask = (xx - c[:, :1, None]) ** 2 + (yy - c[:, 1:, None]) ** 2 < 36.0
        rgb = jnp.where(mask[..., None], jnp.array([40, 160, 50]), jnp.array([120, 90, 60]))
        return rgb.astype(jnp.uint8), mask

    val = D.batches(*blobs(4, seed=99), 4)
    cfg = dataclasses.replace(CFG, flip=0.5, grey=0.2)  # the augmentation's keys too
    runs = {fuse: T.fit(module, variables, T.Data(val=val, describe="test", batch_fn=batch_fn,
                                                  fuse=fuse), cfg, tmp_path / str(fuse))
            for fuse in (True, False)}
    assert runs[True]["step"] == runs[False]["step"] == 4
    logs = [[json.loads(line)["loss"] for line in (tmp_path / str(f) / "train_log.jsonl").open()
             if "loss" in line] for f in (True, False)]
    np.testing.assert_allclose(logs[0], logs[1], rtol=1e-4)
    wa, wb = (C.load(tmp_path / str(f) / "best")[1] for f in (True, False))
    for x, y in zip(jax.tree.leaves(wa), jax.tree.leaves(wb), strict=True):
        np.testing.assert_allclose(x, y, rtol=1e-3, atol=1e-5)


def test_checkpoint_roundtrip_exact(tiny, tmp_path, monkeypatch):
    module, variables = tiny
    C.save(tmp_path / "f32", module, variables, meta={"image_size": H})
    m2, v2 = C.load(tmp_path / "f32")
    assert m2 == module
    assert jax.tree.structure(v2) == jax.tree.structure(variables)
    for x, y in zip(jax.tree.leaves(v2), jax.tree.leaves(variables), strict=True):
        assert x.dtype == jnp.float32
        np.testing.assert_array_equal(x, y)
    C.save(tmp_path / "f16", module, variables, weights_dtype="float16")
    _, v3 = C.load(tmp_path / "f16")
    for x, y in zip(jax.tree.leaves(v3), jax.tree.leaves(variables), strict=True):
        np.testing.assert_allclose(x, y, rtol=1e-3, atol=1e-4)
    # crop names resolve to the shipped folder, falling back to the all-crop model
    monkeypatch.setattr(C, "CHECKPOINT_DIR", tmp_path / "shipped")
    with pytest.raises(ValueError, match="'lettuce'"):
        C.load("lettuce")
    C.save(tmp_path / "shipped" / "all", module, variables)
    assert C.resolve("lettuce") == tmp_path / "shipped" / "all"
    with pytest.raises(ValueError, match="nowhere"):
        C.load(str(tmp_path / "nowhere"))


def test_onnx_export_matches_flax(tiny, apply_fn, tmp_path):
    pytest.importorskip("onnx", reason="optional export dependency onnx not installed")
    pytest.importorskip("onnxruntime", reason="optional dependency onnxruntime not installed")
    from mjxrow.seg import onnx_export as X

    module, variables = tiny
    rgb, _ = blobs(2, seed=5)
    path = X.save_onnx(module, variables, tmp_path / "seg.onnx", (H, W), batch=None)
    got = X.run_onnx(path, rgb)
    ref = np.asarray(apply_fn(variables, rgb))
    assert got.shape == ref.shape == (2, H, W)
    assert np.abs(got - ref).max() < 1e-3


def _write_folder(root, n=8, classes=False):
    """A dataset folder of `blobs`; with `classes`, class images too, where images 4 and 5 hold
    a 3 × 4 weed in their top-left corner (drawn plant-green in the RGB)."""
    rgb, mask = blobs(n, seed=7)
    rows = []
    for i in range(n):
        crop, cond = ("zucchini", "lettuce")[i % 2], ("sunny", "cloudy")[i // 2 % 2]
        for sub in ("rgb", "mask", "class"):
            (root / cond / sub).mkdir(parents=True, exist_ok=True)
        cls = np.where(mask[i], RD.PLANT, RD.SOIL).astype(np.uint8)
        if classes and i in (4, 5):
            mask[i, :3, :4] = False
            cls[:3, :4] = RD.WEED
            rgb[i, :3, :4] = (40, 160, 50)
        Image.fromarray(rgb[i]).save(root / cond / "rgb" / f"{crop}_{i:06d}.png")
        Image.fromarray(mask[i].astype(np.uint8) * 255).save(
            root / cond / "mask" / f"{crop}_{i:06d}.png")
        Image.fromarray(cls).save(root / cond / "class" / f"{crop}_{i:06d}.png")
        rows.append(dict(rgb=f"{cond}/rgb/{crop}_{i:06d}.png",
                         mask=f"{cond}/mask/{crop}_{i:06d}.png", crop=crop, condition=cond,
                         x=0.0, y=0.0, z=0.4, yaw=0.0, pitch=-10.0, lateral=0.0,
                         split="test" if i >= 4 else "train")
                    | ({"classes": f"{cond}/class/{crop}_{i:06d}.png"} if classes else {}))
    pd.DataFrame(rows).to_csv(root / "index.csv", index=False)
    return rgb, mask


def test_dataset_folder_loading(tmp_path):
    rgb, mask = _write_folder(tmp_path)
    df = D.read_index(tmp_path)
    test = D.select(df, "lettuce", "test")
    assert list(test["rgb"]) == ["sunny/rgb/lettuce_000005.png", "cloudy/rgb/lettuce_000007.png"]
    r, m = D.load_arrays(tmp_path, test, progress=False)
    np.testing.assert_array_equal(r, rgb[[5, 7]])
    np.testing.assert_array_equal(m, mask[[5, 7]])
    r16, m16 = D.load_arrays(tmp_path, test, size=16, progress=False)
    assert r16.shape == (2, 16, 16, 3) and m16.dtype == bool
    train, val = D.train_val(df, 0.25, seed=0)
    assert len(train) == 3 and len(val) == 1 and set(val["split"]) == {"train"}
    loader = D.Loader(tmp_path, D.select(df, split="train"), 2, seed=0)
    assert sorted(np.concatenate([loader.indices(0), loader.indices(1)])) == [0, 1, 2, 3]
    np.testing.assert_array_equal(loader.indices(2), loader.indices(2))
    first = next(loader(1))
    np.testing.assert_array_equal(first[0], rgb[:4][loader.indices(1)])
    multi = D.Loader(tmp_path, D.select(df, split="train"), 2, size=(16, 32), seed=0)
    assert [next(multi(s))[0].shape[1] for s in (0, 1, 2)] == [16, 32, 16]
    with pytest.raises(ValueError, match="pear"):
        D.select(df, "pear")
    with pytest.raises(ValueError, match="index.csv"):
        D.read_index(tmp_path / "empty")


def test_train_cli_fine_tunes_from_a_checkpoint(tiny, tmp_path):
    _write_folder(tmp_path / "ds")
    module, variables = tiny
    C.save(tmp_path / "ck", module, variables, meta={"image_size": H})
    base = ["--crop", "all", "--data", str(tmp_path / "ds"), "--size", "32", "--batch", "2",
            "--steps", "1", "--warmup", "0", "--weight-decay", "0", "--val-frac", "0.25",
            "--eval-every", "1", "--workers", "1"]
    # lr 0: the run's weights are the checkpoint's, so the exported model equals it
    T.main(base + ["--init", str(tmp_path / "ck"), "--lr", "0", "--out", str(tmp_path / "run"),
                   "--export-to", str(tmp_path / "out")])
    got_module, got = C.load(tmp_path / "out")
    assert got_module.config() == module.config()
    for a, b in zip(jax.tree.leaves(got["params"]), jax.tree.leaves(variables["params"]),
                    strict=True):
        np.testing.assert_allclose(a, b, rtol=1e-3, atol=1e-6)  # float16 storage
    assert C.read_config(tmp_path / "out")["meta"]["init"] == str((tmp_path / "ck").resolve())
    with pytest.raises(ValueError, match="nowhere"):
        T.main(base + ["--init", str(tmp_path / "nowhere"), "--out", str(tmp_path / "r2")])


def test_eval_tables(tiny, tmp_path):
    # pooled metrics per group, by hand
    df = pd.DataFrame({"crop": ["a", "a", "b"], "condition": ["sunny", "cloudy", "sunny"],
                       "inter": [1.0, 3.0, 0.0], "union": [2.0, 4.0, 0.0],
                       "correct": [9.0, 8.0, 10.0], "total": [10.0, 10.0, 10.0]})
    t = E.summarise(df).set_index(["crop", "condition"])
    assert t.loc[("a", "all"), "iou"] == pytest.approx(4 / 6)
    assert t.loc[("a", "sunny"), "accuracy"] == pytest.approx(0.9)
    assert t.loc[("b", "sunny"), "iou"] == 1.0  # nothing predicted, nothing there
    assert t.loc[("all", "all"), "accuracy"] == pytest.approx(27 / 30)
    assert t.loc[("all", "all"), "images"] == 3
    # the CLI on a folder, with a checkpoint
    _write_folder(tmp_path / "ds")
    module, variables = tiny
    C.save(tmp_path / "ck", module, variables, meta={"image_size": H})
    table = E.main(["--crop", "zucchini", "--data", str(tmp_path / "ds"), "--ckpt",
                    str(tmp_path / "ck"), "--batch", "4"])
    assert set(table["crop"]) == {"zucchini", "all"}
    assert table["images"].iloc[-1] == 2
    assert ((table["iou"] >= 0) & (table["iou"] <= 1) & (table["accuracy"] <= 1)).all()
    assert (table["weedy_images"] == 0).all() and table["weed_as_crop"].isna().all()


def test_weed_share_hand_computed():
    """Weeds are not crop: the share of weed pixels predicted crop, and the IoU over the
    weedy images only."""
    # image 0 predicts crop everywhere (p = 0.75): 2 weed pixels, both called crop; image 1
    # predicts nothing: 1 weed pixel, not called crop; image 2 has no weeds
    logits = jnp.stack([jnp.full((2, 2), math.log(3.0)), jnp.zeros((2, 2)),
                        jnp.full((2, 2), math.log(3.0))])
    mask = jnp.array([[[True, False], [False, False]], [[True, True], [False, False]],
                      [[True, True], [True, True]]])
    weed = jnp.array([[[False, True], [True, False]], [[False, False], [True, False]],
                      [[False, False], [False, False]]])
    c = {k: np.asarray(v) for k, v in E.image_counts(logits, mask, weed=weed).items()}
    np.testing.assert_array_equal(c["weed"], [2, 1, 0])
    np.testing.assert_array_equal(c["weed_crop"], [2, 0, 0])
    df = pd.DataFrame({"crop": "a", "condition": ["sunny", "cloudy", "sunny"], **c})
    t = E.summarise(df).set_index(["crop", "condition"])
    total = t.loc[("all", "all")]
    assert total["weedy_images"] == 2
    assert total["weed_as_crop"] == pytest.approx(2 / 3)
    assert total["weedy_iou"] == pytest.approx(1 / 6)  # (1 + 0) / (4 + 2)
    assert total["iou"] == pytest.approx(5 / 10)  # (1 + 0 + 4) / (4 + 2 + 4)
    assert t.loc[("a", "sunny"), "weedy_images"] == 1
    assert t.loc[("a", "sunny"), "weed_as_crop"] == pytest.approx(1.0)
    assert np.isnan(E.summarise(df[df["weed"] == 0])["weed_as_crop"]).all()


def test_eval_and_table2_report_the_weeds(tiny, tmp_path):
    """A folder with class images: seg.eval and Table 2 report the weedy images, their IoU
    and the share of weed pixels called crop (per crop)."""
    from paper import table2

    _write_folder(tmp_path / "ds", classes=True)
    module, variables = tiny
    C.save(tmp_path / "ck" / "all", module, variables, meta={"image_size": H})
    rows = D.select(D.read_index(tmp_path / "ds"), None, "test")
    weed = D.load_weeds(tmp_path / "ds", rows)
    assert weed.shape == (4, H, W) and weed.sum(axis=(1, 2)).tolist() == [12, 12, 0, 0]
    df = E.evaluate_folder(module, variables, tmp_path / "ds", batch=4)
    np.testing.assert_array_equal(df["weed"], [12, 12, 0, 0])
    table = E.summarise(df).set_index(["crop", "condition"])
    assert table.loc[("zucchini", "all"), "weedy_images"] == 1
    share = df["weed_crop"].iloc[0] / 12
    assert table.loc[("zucchini", "all"), "weed_as_crop"] == pytest.approx(share)
    # Table 2 runs the model at its own size (H × H)
    df = E.evaluate_folder(module, variables, tmp_path / "ds", "zucchini", size=H, batch=4)
    share = df["weed_crop"].iloc[0] / df["weed"].iloc[0]
    page = tmp_path / "table2.md"
    t2, cross = table2.main(["--ckpt-root", str(tmp_path / "ck"), "--data-root",
                             str(tmp_path / "ds"), "--crops", "zucchini", "lettuce", "--batch",
                             "4", "--out", str(page)])
    assert list(t2["weedy images"]) == [1, 1]
    assert t2["weed → crop"].iloc[0] == f"{share:.3f}"
    assert cross["weed_as_crop"].iloc[0] == pytest.approx(share)
    text = page.read_text()
    assert "weed → crop" in text and "## IoU per sky condition" in text


SHIPPED = [c for c in crops.names() if any((C.CHECKPOINT_DIR / n / "config.json").is_file()
                                   for n in (c, "all"))]


# one crop in the default suite (a renderer compile per crop costs tens of seconds); all: -m slow
@pytest.mark.parametrize("crop", [pytest.param(c, marks=[pytest.mark.slow] if i else [])
                                  for i, c in enumerate(SHIPPED)] or ["none"])
def test_shipped_checkpoint_segments_a_rendered_frame(crop):
    if not SHIPPED:
        pytest.skip(f"no shipped checkpoints in {C.CHECKPOINT_DIR}")
    module, variables = C.load(crop)
    meta = C.read_config(crop)["meta"]
    size = meta.get("image_size", 224)  # the size the model is evaluated at (Table 2)
    # the dataset's fields (curved rows, gap runs and weeds in a share of them), which the
    # shipped model was fine-tuned on
    rgb, mask = D.fixed_set(D.onthefly(crop, size, 2), 1, 123)[0][:2]
    logits = jax.jit(M.apply, static_argnums=0)(module, variables, rgb)
    iou = E.scores(E.counts(logits, jnp.asarray(mask)))["iou"]
    assert iou >= 0.8, f"{crop}: IoU {iou:.3f} of the shipped model on 2 renders at {size} px"
