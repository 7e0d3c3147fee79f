"""Every network a model config builds keeps the contract of wdss.nets.base: the entry points read what it declares
(inputs, fixed scale, whether it needs training, its residual upsampler) instead of probing it."""

from __future__ import annotations

import functools
import inspect

import pytest
import torch
from hydra import compose, initialize_config_dir

import wdss.paths  # noqa: F401  (registers the run_suffix resolver)
from wdss.config.targets import instantiate
from wdss.data.batch import KEYS, check_batch
from wdss.nets.base import SuperResolutionNet
from wdss.nets.profile import dummy_inputs
from wdss.paths import CONF_DIR

VARIANTS = sorted(p.stem for p in (CONF_DIR / "variant").glob("*.yaml"))


@functools.cache
def network(variant: str) -> SuperResolutionNet:
    """The network a variant's model config builds (the CPU experiment's settings)."""
    with initialize_config_dir(config_dir=str(CONF_DIR), version_base="1.3"):
        cfg = compose("train", overrides=["experiment=cpu", f"variant={variant}"])
    return instantiate(cfg.model.net, at="net")


@pytest.mark.parametrize("variant", VARIANTS)
def test_every_network_a_variant_builds_declares_the_contract(variant):
    net = network(variant)
    assert isinstance(net, SuperResolutionNet), type(net)
    assert net.inputs and all(isinstance(key, str) for key in net.inputs)
    assert not net.fixed_scale or net.scale is not None  # a network of one scale says which
    assert (net.upsampler is None) or net.residual != "none"  # a residual upsampler is named
    assert isinstance(net.needs_training, bool) and isinstance(net.loads_published_weights, bool)


@pytest.mark.parametrize("variant", VARIANTS)
def test_every_network_reads_only_keys_of_the_batch_module(variant):
    """``inputs`` and the arguments ``forward(**batch)`` names are keys wdss.data.batch defines, and the dummy inputs
    that benchmarks and export feed a network are shaped as that module says."""
    net = network(variant)
    assert set(net.inputs) <= set(KEYS), sorted(set(net.inputs) - set(KEYS))
    named = [p.name for p in inspect.signature(net.forward).parameters.values() if p.kind is not p.VAR_KEYWORD]
    assert set(named) - {"subbands"} <= set(KEYS), named
    inputs = dummy_inputs(net, 24, 36, 2.0)
    always = {"scale": torch.full((1,), 2.0), "sequence": ["dummy"], "frame": torch.zeros(1, dtype=torch.int64)}
    check_batch(always | inputs)


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


def test_the_networks_gbuffer_width_is_the_batch_modules():
    from wdss.nets.upsamplers import learned_bilateral
    from wdss.nets.wdss import network

    assert network.GBUFFER_CHANNELS == learned_bilateral.GBUFFER_CHANNELS == KEYS["gbuffer"].channels
