"""Checkpoints of the layout before issue 39's move (``wdss.model.*``) still load: the allowlist's map of old dotted
paths to new ones (wdss.config.targets.MOVED) renames what they store, and nothing else is let through."""

from __future__ import annotations

import pytest
import torch

from tests.config.test_targets import UPSAMPLE, crafted_checkpoint
from tests.helpers import tiny_checkpoint
from wdss.checkpoint import CheckpointError, read_checkpoint
from wdss.config.targets import ALLOWED, MOVED, TargetRefused, moved, resolve
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
