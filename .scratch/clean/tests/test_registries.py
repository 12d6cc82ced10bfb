"""A crop and a controller added from this file alone (one new definition plus one `register`
call each) run in a 2-episode sweep: the registries are the only places that name them."""

import dataclasses
from typing import ClassVar

import jax.numpy as jnp
import numpy as np
import pandas as pd
import pytest
from flax import struct

from mjxrow import control, crops
from mjxrow.crops import prims as PL
from mjxrow.sweep import config as C
from mjxrow.sweep import reference as SD
from mjxrow.sweep import run as S


def _one_ellipsoid(L, W, H, yaw, phase):
    parts = [PL.upright(L, W, H, (0.5, 0.5, 0.5, 0.5))]
    return (*PL.compose(parts), np.asarray([PL.ELLIPSOID]), np.asarray([PL.LEAF]))


BEANS = crops.Crop(
    name="beans",
    preset=dict(terrain_length=12.0, terrain_width=8.0, terrain_dh=0.0, plant_length=0.4,
                plant_width=0.4, plant_height=0.5, d_rr=1.5, d_RR=1.5, d_pp=0.5,
                rows_per_group=1, row_length=8.0, p_missing=0.0, stone_density=0.0,
                branch_density=0.0),
    local=_one_ellipsoid, palette=((0.3, 0.6, 0.2),) * 5, trunk_radius=0.05)


@struct.dataclass
class CreepParams:
    speed: jnp.ndarray  # m/s


@dataclasses.dataclass(frozen=True)
class CreepConfig:
    """Drive straight ahead at a constant speed (a toy)."""

    speed: float = 0.4  # m/s, forward speed

    TRACED: ClassVar[tuple[str, ...]] = ("speed",)


def _creep_act(params, state, obs):
    return state, jnp.stack([params.speed, jnp.float32(0.0)])


CREEP = control.Controller(
    "creep", CreepConfig, lambda cfg, image_hw: CreepParams(jnp.float32(cfg.speed)),
    lambda params: (), _creep_act)


@pytest.fixture
def registered():
    crops.register(BEANS)
    control.register(CREEP)
    try:
        yield
    finally:
        crops.CROPS.pop("beans", None)
        control.CONTROLLERS.pop("creep", None)


def test_toy_crop_and_controller_run_a_sweep(registered, tmp_path):
    raw = {"preset": "beans", "seeds": 2, "batch_size": 2, "field": {"terrain_dh": [0.0, 0.1]},
           "sim": {"path_length": 1.5}, "episode": {"max_time": 6.0},
           "controller": {"name": "creep", "speed": 0.5},
           "perception": {"source": "ground_truth"}, "camera": {"width": 16, "height": 16}}
    cfg = C.from_dict(raw)
    assert cfg.controller.name == "creep" and "controller.speed" in SD.reference_markdown()
    S.run(cfg, tmp_path, progress=False, figures=False)
    res = pd.read_csv(tmp_path / "results.csv")
    assert len(res) == 4 and set(res["preset"]) == {"beans"}
    assert set(res["controller.name"]) == {"creep"} and (res["controller.speed"] == 0.5).all()
    # straight along the lane centre at 0.5 m/s: 1.5 m reached in about 3 s (within 0.40 m)
    assert res["success"].all(), res["reason"]
    assert (res["v_mean"] > 0.4).all() and (res["mae"] < 0.05).all()


def test_unknown_names_are_config_errors(registered):
    with pytest.raises(C.ConfigError, match="controller.sped: unknown key; did you mean speed"):
        C.from_dict({"controller": {"name": "creep", "sped": 1.0}})
    with pytest.raises(C.ConfigError, match="preset: 'peas' is not one of"):
        C.from_dict({"preset": "peas"})
