"""The batch contract (wdss.data.batch): the data module's batches hold every key as its table defines it, the reader's
requirements and the engine-facing export description use its names, and check_batch names what breaks it."""

from __future__ import annotations

from pathlib import Path

import pytest
import torch

from wdss.data import SceneDataModule
from wdss.data.batch import ALWAYS, BATCH_KEYS, GBUFFER_STACK, KEYS, LR_GEOMETRY, LR_GUIDE, BatchError, check_batch
from wdss.data.buffers import BUFFERS
from wdss.data.dataset import Preprocessing, requirements

FIXTURES = Path(__file__).resolve().parents[1] / "fixtures" / "rendered"
SPLITS = {"train": ["fixture_000"], "val": ["fixture_000"], "test": ["fixture_000"]}


def _batch(n: int = 2, hr: tuple[int, int] = (8, 12), lr: tuple[int, int] = (4, 6)) -> dict:
    """A batch of every key, shaped as the table says."""
    grids = {"hr": hr, "lr": lr}
    batch: dict = {"scale": torch.full((n,), 2.0), "sequence": ["a"] * n, "frame": torch.arange(n)}
    for name in BATCH_KEYS:
        key = KEYS[name]
        batch[name] = torch.zeros(n, key.channels, *grids.get(key.grid, ()))
    return batch


@pytest.mark.parametrize("placement", ["loader", "device"])
def test_the_data_modules_batches_hold_every_key_as_defined(placement):
    dm = SceneDataModule(
        FIXTURES, SPLITS, BATCH_KEYS, patch_size=24, batch_size=2, scale=[2, 4], test_scales=[3.0],
        preprocess_on=placement,
    )  # fmt: skip
    dm.setup()
    for loader in (dm.train_dataloader(), dm.val_dataloader(), dm.test_dataloader()[0]):
        batch = dm.on_after_batch_transfer(next(iter(loader)), 0)
        check_batch(batch, BATCH_KEYS)
        assert set(batch) == set(BATCH_KEYS) | set(ALWAYS)
    steps = SceneDataModule(FIXTURES, SPLITS, ["lr", "history", "target"], patch_size=24, sequence_length=2)
    steps.setup("fit")
    batch = steps.on_after_batch_transfer(next(iter(steps.train_dataloader())), 0)
    assert len(batch["steps"]) == 2
    check_batch(batch, ["lr", "history", "target"])


def test_check_batch_names_the_key_that_breaks_the_contract():
    check_batch(_batch(), BATCH_KEYS)
    check_batch({k: v for k, v in _batch().items() if k != "emission"}, BATCH_KEYS)  # absent without separation
    cases = [
        ({"lr": None}, ["lr"], r"batch key 'lr' is torch.float32, got NoneType"),
        ({"gbuffer": torch.zeros(2, 7, 8, 12)}, [], r"'gbuffer' has shape \(N, 11, H, W\), got \[2, 7, 8, 12\]"),
        ({"target": torch.zeros(2, 3, 8, 10)}, [], r"'brdf' .*: W is 10 in 'target'"),
        ({"lr": torch.zeros(3, 3, 4, 6)}, [], r"'lr' .*: N is 2 in 'scale'"),
        ({"frame": torch.zeros(2)}, [], r"'frame' is torch.int64, got torch.float32"),
        ({"sequence": "ab"}, [], r"'sequence' is a list of str"),
        ({"lr_jitter": torch.zeros(2, 2, 1)}, [], r"'lr_jitter' has shape \(N, 2\)"),
        ({"albedo": torch.zeros(2)}, [], r"unknown keys \['albedo'\]"),
    ]
    for change, needs, message in cases:
        with pytest.raises(BatchError, match=message):
            check_batch(_batch() | change, needs)
    lacking = {k: v for k, v in _batch().items() if k not in ("history", "frame")}
    with pytest.raises(BatchError, match="the batch lacks frame, history"):
        check_batch(lacking, ["history"])
    with pytest.raises(BatchError, match=r"unknown batch keys \['albedo'\]"):
        check_batch(_batch(), ["albedo"])
    with pytest.raises(BatchError, match="lacks history"):
        check_batch({"steps": [_batch(), lacking | {"frame": torch.arange(2)}]}, ["history"])


def test_the_data_module_checks_the_first_batch_of_each_loader_only():
    dm = SceneDataModule(FIXTURES, SPLITS, ["lr", "target"])
    bad = {k: v for k, v in _batch().items() if k != "target"}
    with pytest.raises(BatchError, match="lacks target"):
        dm.on_after_batch_transfer(bad, 0)
    assert dm.on_after_batch_transfer(bad, 0) is bad  # later batches pass unchecked: no cost per step
    with pytest.raises(BatchError, match="lacks target"):
        dm.on_after_batch_transfer(bad, 1)


def test_the_stacks_and_their_channels():
    assert GBUFFER_STACK[: len(LR_GUIDE)] == LR_GUIDE
    for name, stack, channels in (("gbuffer", GBUFFER_STACK, 11), ("lr_guide", LR_GUIDE, 7)):
        assert KEYS[name].stack == stack and KEYS[name].channels == sum(BUFFERS[b] for b in stack) == channels
    assert KEYS["lr_gbuffer"].stack == KEYS["prev_lr_gbuffer"].stack == LR_GEOMETRY
    assert KEYS["lr_gbuffer"].channels == 4


def test_the_reader_reads_each_key_by_the_tables_names():
    prep = Preprocessing()
    assert requirements(["gbuffer"], prep)["hr"] == set(GBUFFER_STACK)
    assert requirements(["lr_guide"], prep)["lr"] == set(LR_GUIDE)
    assert requirements(["prev_lr_gbuffer"], prep)["prev_lr"] == set(LR_GEOMETRY)
    # Every key a model may ask for reads something (lr_jitter: the sidecar), and the keys of every batch nothing.
    for name in BATCH_KEYS:
        assert any(requirements([name], prep).values()) != (name == "lr_jitter"), name
    assert not any(requirements(ALWAYS, prep).values())


def test_the_export_description_agrees_with_the_table():
    from wdss.export import CHANNELS

    for name, (resolution, channels, _) in CHANNELS.items():
        assert KEYS[name].grid == {"high": "hr", "low": "lr"}[resolution], name
        assert len(channels) == KEYS[name].channels, name
