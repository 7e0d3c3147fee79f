"""Checkpoints of the layout before issue 39's move (``wdss.model.*``) still load: the allowlist's map of old dotted
paths to new ones (wdss.config.targets.MOVED) renames what they store, and nothing else is let through. Checkpoints
of the WDSS network before it was composed (head and residual by name) load too: wdss.config.targets.composed_wdss_net
rewrites their network's config."""

from __future__ import annotations

import pytest
import torch

from tests.config.test_targets import UPSAMPLE, crafted_checkpoint
from tests.helpers import tiny_checkpoint
from wdss.checkpoint import CheckpointError, read_checkpoint
from wdss.config.targets import (
    ALLOWED,
    MOVED,
    OLD_HEADS,
    OLD_KERNEL_OPTIONS,
    OLD_RESIDUALS,
    TargetRefused,
    composed_wdss_net,
    instantiate,
    moved,
    resolve,
)
from wdss.nets.upsamplers.learned_bilateral import LearnedBilateralUpsample
from wdss.training.module import SuperResolutionModule

OLD = {new: old for old, new in MOVED.items()}


def _old_layout(node):
    """``node`` with every ``_target_`` written as the layout before the move named it."""
    if isinstance(node, dict):
        return {k: OLD.get(v, v) if k == "_target_" else _old_layout(v) for k, v in node.items()}
    if isinstance(node, list):
        return [_old_layout(v) for v in node]
    return node


def test_every_old_path_maps_to_an_allowlisted_callable_of_the_same_name():
    for old, new in MOVED.items():
        module, name = new.rsplit(".", 1)
        assert old.rsplit(".", 1)[1] == name and name in ALLOWED[module]
        assert resolve(old) is None and resolve(new) is not None  # nothing is left at the old path
    assert moved({"net": {"_target_": "wdss.model.nsrr.NSRR", "note": "wdss.model.nsrr.NSRR"}, "lr": [1, 2]}) == {
        "net": {"_target_": "wdss.nets.comparison.nsrr.NSRR", "note": "wdss.model.nsrr.NSRR"},
        "lr": [1, 2],
    }


@pytest.mark.parametrize("overrides", [(), ("model=joint_bilateral",), ("model=learned_bilateral",)], ids=str)
@pytest.mark.filterwarnings("ignore:The state dict in .* contains no parameters")
def test_a_checkpoint_of_the_old_layout_loads_and_builds_todays_classes(overrides, tmp_path):
    new = torch.load(tiny_checkpoint(tmp_path / "new.ckpt", *overrides), map_location="cpu", weights_only=True)
    checkpoint = {**new, "hyper_parameters": _old_layout(new["hyper_parameters"])}
    stored = checkpoint["hyper_parameters"]["net"]["_target_"]
    assert stored.startswith("wdss.model.")  # as a checkpoint written before the move stores it
    torch.save(checkpoint, tmp_path / "old.ckpt")

    read_checkpoint(tmp_path / "old.ckpt")  # accepted
    module = SuperResolutionModule.load_from_checkpoint(tmp_path / "old.ckpt", map_location="cpu", weights_only=True)
    assert type(module.net) is resolve(MOVED[stored])
    assert module.hparams["net"]["_target_"] == MOVED[stored]  # what it saves from now on
    assert all(torch.equal(value, new["state_dict"][key]) for key, value in module.state_dict().items())


def test_an_old_path_the_map_does_not_list_is_still_refused(tmp_path):
    ckpt = crafted_checkpoint(tmp_path, {"_target_": "wdss.model.blocks.RIRBlock", "width": 8})
    match = r"net\._target_=wdss\.model\.blocks\.RIRBlock is not on wdss's allowlist"
    with pytest.raises(CheckpointError, match=rf"hyper_parameters\.{match}"):
        read_checkpoint(ckpt)
    with pytest.raises(TargetRefused, match=rf"^{match}"):
        SuperResolutionModule.load_from_checkpoint(ckpt, map_location="cpu", weights_only=True)


def test_an_old_path_the_map_lists_is_refused_off_its_slot(tmp_path):
    wrong = {"_target_": "wdss.model.network.WDSSNet", "_partial_": True}
    ckpt = crafted_checkpoint(tmp_path, UPSAMPLE, optimizer=wrong)
    with pytest.raises(CheckpointError, match=r"hyper_parameters\.optimizer\._target_=\S+\.WDSSNet is not on"):
        read_checkpoint(ckpt)


# ------------------------------------------------------------------------------------------ composed WDSSNet

KERNEL = "wdss.nets.upsamplers.learned_bilateral.LearnedBilateralUpsample"


def test_an_old_shape_wdss_net_config_is_rewritten_into_todays():
    old = {
        "_target_": "wdss.nets.wdss.network.WDSSNet",
        "head": "fusion_ll",
        "temporal": True,
        "output_space": "log",
        "residual": "learned_bilateral",
        "exit_init": 0.0,
        "tap_brdf": True,
        "kernel_never_raise": False,
        "kernel_raise_within_albedo": True,
    }
    assert composed_wdss_net(old) == {
        "_target_": "wdss.nets.wdss.network.WDSSNet",
        "head": {"_target_": "wdss.nets.wdss.heads.FusionLL"},
        "temporal": True,
        "output_space": "log",
        "upsampler": {"_target_": KERNEL, "tap_brdf": True, "never_raise": False, "raise_within_albedo": True},
        "exit_init": 0.0,
    }
    # A kernel from before its options existed builds as it was trained (its defaults); the options of another
    # residual did nothing and are dropped; a fixed upsampler becomes its module.
    assert composed_wdss_net({"head": "shared_inr", "residual": "learned_bilateral"})["upsampler"] == {
        "_target_": KERNEL
    }
    assert composed_wdss_net({"residual": "joint_bilateral", "tap_brdf": True}) == {
        "upsampler": {"_target_": "wdss.nets.upsamplers.joint_bilateral.JointBilateralUpsample"}
    }
    assert composed_wdss_net({"residual": "bilinear"})["upsampler"] == {
        "_target_": "wdss.nets.upsamplers.baselines.Upsample",
        "mode": "bilinear",
        "demodulated": True,
    }
    assert composed_wdss_net({"residual": "none", "kernel_never_raise": False}) == {"upsampler": None}
    # Today's shape, and what moved() leaves alone: other networks' configs.
    today = {"_target_": "wdss.nets.wdss.network.WDSSNet", "head": {"_target_": "wdss.nets.wdss.heads.SharedINR"}}
    assert composed_wdss_net(today) == today
    nsrr = {"_target_": "wdss.model.nsrr.NSRR", "residual": "bilinear"}
    assert moved({"net": nsrr}) == {"net": {**nsrr, "_target_": "wdss.nets.comparison.nsrr.NSRR"}}
    # The old layout's path and the old shape together, as the oldest checkpoints store them.
    assert moved({"net": {"_target_": "wdss.model.network.WDSSNet", "head": "multi_inr"}}) == {
        "net": {"_target_": "wdss.nets.wdss.network.WDSSNet", "head": {"_target_": "wdss.nets.wdss.heads.MultiINR"}}
    }


def _old_shape(net: dict) -> dict:
    """A WDSSNet config of today written as the network took it before it was composed (head and residual by name,
    the learned kernel's options beside them)."""
    heads, old = {v: k for k, v in OLD_HEADS.items()}, dict(net)
    old["head"] = heads[old["head"]["_target_"]]
    upsampler = old.pop("upsampler")
    names = {None: "none", **{v["_target_"]: k for k, v in OLD_RESIDUALS.items() if v}}
    old["residual"] = names[upsampler["_target_"] if upsampler else None]
    for option, name in OLD_KERNEL_OPTIONS.items():
        old[option] = (upsampler or {}).get(name, False)
    return old


@pytest.mark.parametrize(
    "overrides",
    [("experiment=cpu",), ("experiment=cpu", "head=multi_inr", "residual=joint_bilateral"), ("variant=fusion_ll",)],
    ids=" ".join,
)
@pytest.mark.parametrize("layout", ["today", "before the move"])
def test_a_checkpoint_of_the_old_network_shape_loads_as_trained(overrides, layout, tmp_path):
    new = torch.load(tiny_checkpoint(tmp_path / "new.ckpt", *overrides), map_location="cpu", weights_only=True)
    hparams = {**new["hyper_parameters"], "net": _old_shape(new["hyper_parameters"]["net"])}
    if layout == "before the move":
        hparams = _old_layout(hparams)
    assert isinstance(hparams["net"]["head"], str) and "upsampler" not in hparams["net"]  # the old shape
    torch.save({**new, "hyper_parameters": hparams}, tmp_path / "old.ckpt")

    read_checkpoint(tmp_path / "old.ckpt")  # accepted
    module = SuperResolutionModule.load_from_checkpoint(tmp_path / "old.ckpt", map_location="cpu", weights_only=True)
    saved, today = module.hparams["net"], new["hyper_parameters"]["net"]
    # Today's shape, saved from now on (the kernel's other settings left at the defaults it was built with then).
    assert {k: v for k, v in saved.items() if k != "upsampler"} == {k: v for k, v in today.items() if k != "upsampler"}
    assert (saved["upsampler"] or {}).items() <= (today["upsampler"] or {}).items()
    assert list(module.state_dict()) == list(new["state_dict"])
    assert all(torch.equal(value, new["state_dict"][key]) for key, value in module.state_dict().items())
    built = instantiate(today, at="net")
    assert module.net.inputs == built.inputs and module.net.residual == built.residual
    if isinstance(built.upsampler, LearnedBilateralUpsample):
        flags = ("tap_brdf", "never_raise", "raise_within_albedo")
        assert [getattr(module.net.upsampler, f) for f in flags] == [getattr(built.upsampler, f) for f in flags]
