"""The size/ group sizes whichever learned model model= or variant= selects (experiment=cpu: small widths)."""

from __future__ import annotations

from pathlib import Path

import pytest
from hydra import compose, initialize_config_dir
from omegaconf import OmegaConf

CONF = Path(__file__).resolve().parents[2] / "conf"
# variant -> the size/ entry its model reads; None: plain WDSS (the default model).
LEARNED = {None: "wdss", "dfasr": "wdss", "nsrr": "nsrr", "fusesr": "fusesr", "real_esrgan": "real_esrgan"}


def model_of(*overrides: str) -> dict:
    with initialize_config_dir(config_dir=str(CONF), version_base="1.3"):
        cfg = compose("train", overrides=list(overrides))
    return OmegaConf.to_container(cfg.model, resolve=True)


def preset(size: str, entry: str) -> dict:
    return OmegaConf.to_container(OmegaConf.load(CONF / "size" / f"{size}.yaml")[entry])


def test_dfasr_under_the_cpu_preset_gets_cpu_widths_and_learning_rate():
    model = model_of("variant=dfasr", "experiment=cpu")
    assert model["net"]["lr_widths"] == [16, 24, 24, 32] and model["net"]["inr_width"] == 32
    assert model["net"]["lr_unshuffle"] is False  # still DFASR, not WDSS
    assert model["optimizer"]["lr"] == pytest.approx(1e-3)


def test_dfasr_alone_keeps_the_papers_widths_and_learning_rate():
    model = model_of("variant=dfasr")
    assert model["net"]["lr_widths"] == [32, 48, 48, 64] and model["net"]["mlp_depth"] == 3
    assert model["optimizer"]["lr"] == pytest.approx(1e-4)


@pytest.mark.parametrize("variant", list(LEARNED), ids=lambda v: v or "wdss")
@pytest.mark.parametrize("experiment, size", [("cpu", "small"), ("smoke", "small"), (None, "paper")])
def test_every_learned_model_reads_the_chosen_size(variant, experiment, size):
    overrides = [f"variant={variant}"] * (variant is not None) + [f"experiment={experiment}"] * (experiment is not None)
    model = model_of(*overrides)
    expected = preset(size, LEARNED[variant])
    lr = expected.pop("lr")
    assert {k: model["net"][k] for k in expected} == expected
    assert model["optimizer"]["lr"] == pytest.approx(lr)


def test_the_two_sizes_differ_for_every_learned_model():
    for entry in set(LEARNED.values()):
        assert preset("small", entry) != preset("paper", entry), entry


def test_what_benchmarks_build_outside_a_run_is_read_from_the_size_and_model_configs():
    """One source for widths and DFASR's settings: wdss.config.sizes reads conf/size and conf/model, which runs
    compose; the benchmarks keep no copy."""
    from wdss.bench.inference import inference_settings
    from wdss.bench.model import dfasr_settings
    from wdss.config.sizes import model_net_settings, size_widths

    for size in ("small", "paper"):
        for entry in set(LEARNED.values()):
            assert size_widths(size, entry) == {k: v for k, v in preset(size, entry).items() if k != "lr"}
    assert dfasr_settings() == inference_settings("DFASR") == model_net_settings("dfasr")
    assert dfasr_settings()["transform"] == "none" and dfasr_settings()["lr_unshuffle"] is False
    with pytest.raises(ValueError, match="no size 'huge'"):
        size_widths("huge")
