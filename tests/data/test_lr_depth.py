"""Native LR folders and point-sampled LR give the same LR depth and spatial mask when their pixels agree."""

from __future__ import annotations

from pathlib import Path

import pytest
import torch

from wdss.data import Collate, FrameDataset, Sequence
from wdss.data.synthetic import write_sequence

FIXTURE = Path(__file__).resolve().parents[1] / "fixtures" / "rendered" / "fixture_000"  # lr_mode=downsample
KEYS = ["spatial_mask", "lr_gbuffer", "prev_lr_gbuffer", "target"]


def batches(seq: Sequence, scale: float, keys=KEYS) -> tuple[dict, dict]:
    """The full-frame batches of every sample: from the native LR folder, and point-sampled from the HR frame."""
    native = FrameDataset([seq], keys, scale=scale)
    sampled = FrameDataset([seq], keys, scale=(scale, scale))  # a range: never a native folder
    assert native.native_lr(seq) is not None and sampled.native_lr(seq) is None
    out = []
    for dataset in (native, sampled):
        collate = Collate(dataset.keys, dataset.prep, dataset.scale)
        out.append(collate([dataset[i] for i in range(len(dataset))]))
    return out[0], out[1]


def assert_same(native: dict, sampled: dict) -> None:
    for key in ("lr_gbuffer", "prev_lr_gbuffer"):
        torch.testing.assert_close(native[key], sampled[key], rtol=0, atol=0, msg=key)
    assert torch.equal(native["spatial_mask"], sampled["spatial_mask"])


@pytest.mark.parametrize("scale", [2.0, 3.0, 4.0])
def test_the_rendered_fixture_gives_one_mask_whichever_lr_path(scale):
    native, sampled = batches(Sequence(FIXTURE), scale)
    assert 0 < float(sampled["spatial_mask"].mean()) < 1  # the mask marks something, not everything
    assert_same(native, sampled)


@pytest.mark.parametrize("scale", [3, 4])
def test_synthetic_native_lr_matches_point_samples(tmp_path, scale):
    """At 3x and 4x the point samples miss the last HR row and column, where the depth ramp peaks: only the HR
    frame's range normalises both paths alike."""
    path = write_sequence(tmp_path / "seq", frames=(1, 2, 3), size=(24, 36), scales=(scale,))
    native, sampled = batches(Sequence(path), float(scale))
    assert_same(native, sampled)


def test_the_lr_depth_alone_reads_the_hr_depth_plane_only(tmp_path):
    """An LR G-buffer without a spatial mask (NSRR, FuseSR) still normalises with the HR frame's range."""
    path = write_sequence(tmp_path / "seq", frames=(1, 2), size=(24, 36), scales=(3,))
    native, sampled = batches(Sequence(path), 3.0, keys=["lr_gbuffer", "prev_lr_gbuffer"])
    torch.testing.assert_close(native["lr_gbuffer"], sampled["lr_gbuffer"], rtol=0, atol=0)
    torch.testing.assert_close(native["prev_lr_gbuffer"], sampled["prev_lr_gbuffer"], rtol=0, atol=0)
    sample = FrameDataset([Sequence(path)], ["lr_gbuffer", "prev_lr_gbuffer"], scale=3.0)[0]
    assert sample["hr"] == {} and sample["prev"] == {}  # the HR depth served the range and was dropped
