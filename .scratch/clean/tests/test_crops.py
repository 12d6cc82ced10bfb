"""The crop registry: the built-in crops in order, errors naming the crop, and a toy crop
registered from this file alone that every stage (FieldShape, generation, primitives,
footprint, exports, rendering, the dataset writer) takes by its name."""

import jax
import numpy as np
import pytest

from mjxrow import crops
from mjxrow import field as F
from mjxrow import render as RD
from mjxrow.crops import prims as PL
from mjxrow.seg import synthesis as DS
from mjxrow.worlds import export as WD

BUILT_IN = ("zucchini", "lettuce", "chard", "pear", "vineyard")


def toy_local(L, W, H, yaw, phase):
    """One ellipsoid per plant: semi-axes half the plant's extents, centre at half its height."""
    parts = [PL.upright(L, W, H, (0.5, 0.5, 0.5, 0.5))]
    return (*PL.compose(parts), np.asarray([PL.ELLIPSOID]), np.asarray([PL.LEAF]))


# single rows 1.5 m apart on an 8 m wide flat terrain: (8 - 2 · 1 m headland) / 1.5 + 1 = 5
# rows; 8 m rows with a plant every 0.5 m: 17 plants each, none missing
TOY = crops.Crop(
    name="toy",
    preset=dict(terrain_length=12.0, terrain_width=8.0, terrain_dh=0.0, plant_length=0.5,
                plant_width=0.4, plant_height=0.6, d_rr=1.5, d_RR=1.5, d_pp=0.5,
                rows_per_group=1, row_length=8.0, p_missing=0.0, stone_density=0.0,
                branch_density=0.0),
    local=toy_local,
    palette=((0.9, 0.1, 0.1),) * 5,  # red: a plant pixel shows the toy's own colour
    trunk_radius=0.05,
)


@pytest.fixture
def toy():
    crop = crops.register(TOY)
    try:
        yield crop
    finally:
        crops.CROPS.pop(crop.name, None)


def test_registry_lists_the_built_in_crops_in_order():
    assert crops.names() == BUILT_IN
    assert crops.names() == BUILT_IN
    zucchini = crops.get("zucchini")
    assert zucchini.preset["d_rr"] == 1.8 and zucchini.preset["rows_per_group"] == 7  # Table 1
    assert zucchini.preset["plant_jitter"] == crops.COMMON_PRESET["plant_jitter"]
    assert (zucchini.dataset_n, zucchini.test_frac, zucchini.silver_leaf) == (19456, 0.30, True)
    assert crops.get("pear").paper["table3"]["mse"] == 3.8349
    assert "table1" not in crops.get("vineyard").paper


def test_unknown_crop_errors_name_it():
    with pytest.raises(ValueError, match=r"^crop: unknown crop 'x'; expected one of \('zucchini'"):
        crops.get("x")
    with pytest.raises(ValueError, match="crop: unknown crop 'x'"):
        F.FieldShape(crop="x")
    with pytest.raises(ValueError, match="preset: unknown preset 'x'"):
        F.make_params("x")
    with pytest.raises(ValueError, match="crop: unknown crop 'x'"):
        PL.footprint("x", np.ones((2, 3)))
    with pytest.raises(ValueError, match="crop: 'pear' is already registered"):
        crops.register(crops.get("pear"))
    with pytest.raises(ValueError, match="palette: crop 'bad'"):
        crops.Crop(name="bad", preset={}, local=toy_local, palette=((0.0, 0.0, 0.0),))


def test_a_preset_missing_or_misnaming_a_parameter_names_it():
    gappy = {k: v for k, v in TOY.preset.items() if k != "d_pp"}
    for name, preset, message in [("gappy", gappy, "^d_pp: crop 'gappy'"),
                                  ("typo", dict(TOY.preset, d_ppp=0.5), "^d_ppp: unknown field "
                                   "parameter in crop 'typo'")]:
        crops.register(crops.Crop(name=name, preset=preset, local=toy_local,
                                  palette=TOY.palette))
        try:
            with pytest.raises(ValueError, match=message):
                F.make_params(name)
        finally:
            crops.CROPS.pop(name, None)


def test_a_toy_crop_registered_here_works_everywhere(toy):
    assert crops.names() == (*BUILT_IN, "toy")
    params = F.make_params("toy")
    assert float(params.plant_jitter) == pytest.approx(0.03)  # COMMON_PRESET's
    shape = F.fit_shape(params, "toy")
    assert shape.crop == "toy"
    F.validate(params, shape)
    fld = jax.tree.map(np.asarray, jax.jit(F.generate, static_argnums=1)(
        params, shape, jax.random.key(0)))
    assert bool(fld.valid) and int(fld.n_rows) == 5
    assert fld.plant_active.sum() == 5 * 17
    np.testing.assert_allclose(np.diff(fld.row_y[fld.row_active]), 1.5, atol=1e-5)

    prims = jax.tree.map(np.asarray, PL.plant_prims(fld, shape))
    assert PL.n_prims("toy") == 1 and prims.centre.shape[2] == 1
    assert list(prims.kind) == [PL.ELLIPSOID] and list(prims.material) == [PL.LEAF]
    np.testing.assert_array_equal(prims.size[:, :, 0], 0.5 * fld.plant_size)
    np.testing.assert_allclose(prims.centre[:, :, 0, 2],
                               fld.plant_pos[..., 2] + 0.5 * fld.plant_size[..., 2], atol=1e-6)
    np.testing.assert_array_equal(PL.footprint("toy", fld.plant_size), np.float32(0.05))

    xml, _ = WD.to_mjcf(fld, shape, "toy")
    assert xml.count('name="plant_r') == 5 * 17  # one primitive per plant
    assert DS.dataset_shape("toy").crop == "toy"

    lane = int(F.robot_lane(fld))
    pos = np.array([float(fld.row_x[0]) - 1.0, float(fld.lane_y[lane]), 0.5], np.float32)
    rot = RD.camera_rot(0.0, np.deg2rad(-10.0))
    intr = RD.Intrinsics(16, 16, 45.0)
    frame = jax.jit(lambda f, p, r: RD.render(f, shape, p, r, intr, RD.conditions("sunny")))(
        fld, pos, rot)
    mask, rgb = np.asarray(frame.mask), np.asarray(frame.rgb).astype(int)
    assert mask.sum() >= 10
    assert (rgb[mask][:, 0] > 2 * rgb[mask][:, 1]).all()  # the toy's red palette
