"""The LightningModule settings are written once (conf/module/): every model file takes them through its defaults
list and writes only what sets it apart (its network, learning rate, losses, temporal mode)."""

from __future__ import annotations

import pytest
from hydra import compose, initialize_config_dir
from omegaconf import OmegaConf

import wdss.paths  # noqa: F401  (registers the run_suffix resolver)
from wdss.paths import CONF_DIR

MODELS = sorted(p.stem for p in (CONF_DIR / "model").glob("*.yaml"))
SHARED = ("_target_", "_recursive_", "flip", "flip_in_validation", "tonemap_name", "image_every_n_epochs", "scheduler")


@pytest.mark.parametrize("name", MODELS)
def test_a_model_file_writes_no_module_setting_again(name):
    own = OmegaConf.to_container(OmegaConf.load(CONF_DIR / "model" / f"{name}.yaml"))
    assert not set(SHARED) & set(own), f"conf/model/{name}.yaml repeats {set(SHARED) & set(own)} of conf/module/"
    assert "_partial_" not in own.get("optimizer", {}) and "_target_" not in own.get("optimizer", {})


@pytest.mark.parametrize("name", MODELS)
def test_every_model_composes_into_a_superresolution_module(name):
    with initialize_config_dir(config_dir=str(CONF_DIR), version_base="1.3"):
        model = compose("train", overrides=[f"model={name}"]).model
    assert model._target_ == "wdss.training.module.SuperResolutionModule" and model._recursive_ is False
    assert model.flip is True and model.flip_in_validation is False
    assert ("optimizer" in model) == (model.get("trainable", True) is not False)
