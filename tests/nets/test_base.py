"""Every network a model config builds keeps the contract of wdss.nets.base: the entry points read what it declares
(inputs, fixed scale, whether it needs training, its residual upsampler) instead of probing it."""

from __future__ import annotations

import pytest
from hydra import compose, initialize_config_dir

import wdss.paths  # noqa: F401  (registers the run_suffix resolver)
from wdss.config.targets import instantiate
from wdss.nets.base import SuperResolutionNet
from wdss.paths import CONF_DIR

VARIANTS = sorted(p.stem for p in (CONF_DIR / "variant").glob("*.yaml"))


@pytest.mark.parametrize("variant", VARIANTS)
def test_every_network_a_variant_builds_declares_the_contract(variant):
    with initialize_config_dir(config_dir=str(CONF_DIR), version_base="1.3"):
        cfg = compose("train", overrides=["experiment=cpu", f"variant={variant}"])
    net = instantiate(cfg.model.net, at="net")
    assert isinstance(net, SuperResolutionNet), type(net)
    assert net.inputs and all(isinstance(key, str) for key in net.inputs)
    assert not net.fixed_scale or net.scale is not None  # a network of one scale says which
    assert (net.upsampler is None) or net.residual != "none"  # a residual upsampler is named
    assert isinstance(net.needs_training, bool) and isinstance(net.loads_published_weights, bool)


def test_a_network_that_does_not_declare_its_inputs_says_so():
    class Undeclared(SuperResolutionNet):
        pass

    with pytest.raises(NotImplementedError, match="Undeclared does not declare its inputs"):
        _ = Undeclared().inputs


def test_only_a_baseline_that_can_load_published_weights_tags_them():
    from wdss.nets.comparison.rrdbnet import RRDBNet
    from wdss.nets.upsamplers.joint_bilateral import JointBilateralUpsample

    assert RRDBNet(num_feat=4, num_block=1, num_grow_ch=4).loads_published_weights
    assert RRDBNet(num_feat=4, num_block=1, num_grow_ch=4).needs_training  # no weights given: random
    assert not JointBilateralUpsample().loads_published_weights and not JointBilateralUpsample().needs_training


def test_the_residual_upsampler_a_network_registers_is_the_one_it_uses():
    """``upsampler`` is the registered submodule (its weights in the state dict), not a default that hides it."""
    from wdss.nets.upsamplers.learned_bilateral import LearnedBilateralUpsample
    from wdss.nets.wdss.network import WDSSNet

    net = WDSSNet(upsampler=LearnedBilateralUpsample())
    assert isinstance(net.upsampler, LearnedBilateralUpsample) and net.residual == "learned_bilateral"
    assert any(key.startswith("upsampler.") for key in net.state_dict())
    assert WDSSNet().upsampler is None
