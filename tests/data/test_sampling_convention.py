"""Sampling conventions are data: where the LR frame and its guide come from, and scales drawn before the read."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
import torch

from wdss.data import Collate, FrameDataset, SceneError, Sequence, point_sample
from wdss.data.dataset import EpochSampler, draw_scale, parse_scale
from wdss.data.preprocess import clean
from wdss.data.synthetic import _write_unreal, synthetic_frame, write_sequence
from wdss.nets.upsamplers.joint_bilateral import joint_bilateral_upsample

HR = (24, 36)
KEYS = ["lr", "lr_guide", "gbuffer", "target"]


def _native_like(path: Path) -> Path:
    """A sequence whose 12P folder holds an LR frame of its own: G-buffer and colour rendered from a shifted scene
    (not the HR frame's point samples), as a native render's differ from them."""
    write_sequence(path, frames=(1, 2), size=HR, scales=(2,))
    for frame in (1, 2):
        other = synthetic_frame(frame, 12, 18, (1.0, -1.0), seed=5)
        del other["emission"]
        _write_unreal(path / "12P", frame, other, "zip", False)
    return path


def _batch(dataset: FrameDataset, scale: float) -> dict:
    return Collate(dataset.keys, dataset.prep, scale)([dataset[0]])


def test_without_a_native_folder_the_lr_guide_is_the_hr_guide_point_sampled_and_joint_bilateral_is_unchanged(
    tmp_path,
):
    seq = Sequence(write_sequence(tmp_path / "seq", frames=(1,), size=HR, scales=()))
    batch = _batch(FrameDataset([seq], KEYS, scale=3.0), 3.0)
    assert batch["lr_guide"].shape == (1, 7, 8, 12)
    torch.testing.assert_close(batch["lr_guide"], point_sample(batch["gbuffer"][:, :7], (8, 12)))
    torch.testing.assert_close(
        joint_bilateral_upsample(batch["lr"], batch["gbuffer"], lr_guide=batch["lr_guide"]),
        joint_bilateral_upsample(batch["lr"], batch["gbuffer"]),
    )


def test_a_native_folder_gives_its_own_guide_and_lr_source_chooses_the_convention(tmp_path):
    seq = Sequence(_native_like(tmp_path / "seq"))
    native = _batch(FrameDataset([seq], KEYS, scale=2.0, lr_source="native"), 2.0)
    auto = _batch(FrameDataset([seq], KEYS, scale=2.0), 2.0)
    point = _batch(FrameDataset([seq], KEYS, scale=2.0, lr_source="point"), 2.0)
    # The oracle: the native folder's own buffers, cleaned as the loader cleans (depth by its HR frame's range).
    raw = seq.read(1, 12, ["base_color", "depth", "normal"])
    hr_depth = seq.read(1, 24, ["depth"])["depth"]
    far = np.where(hr_depth > 100.0, 0.0, hr_depth)
    ranges = torch.tensor([[float(far.min()), float(far.max())]])
    cleaned = clean({k: torch.from_numpy(v)[None] for k, v in raw.items()}, FrameDataset([seq], KEYS).prep, ranges)
    expected = torch.cat([cleaned["base_color"], cleaned["depth"], cleaned["normal"]], 1)
    torch.testing.assert_close(native["lr_guide"], expected)
    torch.testing.assert_close(auto["lr_guide"], expected)  # auto reads the folder where one matches the scale
    torch.testing.assert_close(point["lr_guide"], point_sample(point["gbuffer"][:, :7], (12, 18)))
    assert not torch.allclose(native["lr_guide"], point["lr_guide"])
    assert not torch.allclose(native["lr"], point["lr"])
    torch.testing.assert_close(native["gbuffer"], point["gbuffer"])  # the HR side does not depend on it


def test_lr_source_native_names_the_sequence_and_scale_it_lacks(tmp_path):
    seq = Sequence(write_sequence(tmp_path / "seq", frames=(1,), size=HR, scales=(2,)))
    with pytest.raises(SceneError, match=r"sequence 'seq' has no native LR folder at scale 3 \(24P / 3; it has 12P\)"):
        FrameDataset([seq], KEYS, scale=3.0, lr_source="native")[0]
    with pytest.raises(ValueError, match="data.lr_source must be one of auto, native, point"):
        FrameDataset([seq], KEYS, lr_source="engine")


def test_scale_specs_parse_and_draw():
    assert parse_scale(2) == 2.0 and parse_scale([2, 4]) == (2.0, 4.0)
    assert parse_scale({"choices": [2, 3, 4]}) == {"choices": (2.0, 3.0, 4.0)}
    with pytest.raises(ValueError, match=r"data.scale is a number, \[low, high\] or \{choices"):
        parse_scale([2, 3, 4])
    with pytest.raises(ValueError, match=r"as a mapping is \{choices"):
        parse_scale({"values": [2]})
    drawn = {draw_scale({"choices": (2.0, 3.0, 4.0)}, seed) for seed in range(60)}
    assert drawn == {2.0, 3.0, 4.0}
    assert all(2.0 <= draw_scale((2.0, 4.0), seed) <= 4.0 for seed in range(20))


def test_the_sampler_draws_one_scale_per_batch_as_a_function_of_seed_and_epoch():
    spec = {"choices": [2.0, 3.0, 4.0]}
    sampler = EpochSampler(10, seed=3, repeats=2, scale=spec, batch_size=4)
    sampler.set_epoch(1)
    draws = list(sampler)
    assert len(draws) == 20 and all(len(d) == 3 for d in draws)
    per_batch = [{d[2] for d in draws[b : b + 4]} for b in range(0, 20, 4)]
    assert all(len(s) == 1 for s in per_batch)  # one scale per batch
    assert {s.pop() for s in per_batch} <= {2.0, 3.0, 4.0}
    again = EpochSampler(10, seed=3, repeats=2, scale=spec, batch_size=4)
    again.set_epoch(1)
    assert list(again) == draws  # a resumed run replays its scales
    fixed = EpochSampler(10, seed=3, scale=2.0, batch_size=4)
    assert all(len(d) == 2 for d in fixed)  # a fixed scale: the dataset knows it already


def test_a_batch_drawn_at_a_native_scale_reads_that_folder(tmp_path):
    """Training at scales drawn per batch reads native LR frames, which a scale drawn after the read could not."""
    seq = Sequence(_native_like(tmp_path / "seq"))
    dataset = FrameDataset([seq], KEYS, scale={"choices": [2.0]}, lr_source="auto")
    sampler = EpochSampler(len(dataset), seed=0, scale=dataset.scale, batch_size=2)
    items = list(sampler)
    batch = Collate(dataset.keys, dataset.prep, dataset.scale)([dataset[item] for item in items])
    assert batch["scale"].tolist() == [2.0, 2.0]
    fixed = FrameDataset([seq], KEYS, scale=2.0, lr_source="native")
    native = Collate(fixed.keys, fixed.prep, 2.0)([fixed[index] for index, _, _ in items])
    torch.testing.assert_close(batch["lr"], native["lr"])
    torch.testing.assert_close(batch["lr_guide"], native["lr_guide"])
    # Read without a scale (no sampler), a range's batch is point-sampled after the read, as before.
    unscaled = Collate(dataset.keys, dataset.prep, (2.0, 2.0))([dataset[index] for index, _, _ in items])
    point = FrameDataset([seq], KEYS, scale=2.0, lr_source="point")
    torch.testing.assert_close(
        unscaled["lr"], Collate(point.keys, point.prep, 2.0)([point[i] for i, _, _ in items])["lr"]
    )


def test_the_test_split_can_read_another_convention_than_training(tmp_path):
    from wdss.data import SceneDataModule

    _native_like(tmp_path / "scenes" / "seq")
    splits = {"train": ["seq"], "val": ["seq"], "test": ["seq"]}
    dm = SceneDataModule(
        tmp_path / "scenes", splits, KEYS, scale=2.0, patch_size=None, lr_source="native", test_lr_source="point"
    )
    dm.setup()
    assert dm.datasets["train"].lr_source == dm.datasets["val"].lr_source == "native"
    assert [d.lr_source for d in dm.datasets["test"]] == ["point"] * 3
    assert SceneDataModule(tmp_path / "scenes", splits, KEYS, lr_source="point").test_lr_source == "point"


def test_the_test_split_can_read_the_same_scenes_rendered_under_another_convention(tmp_path):
    from wdss.data import SceneDataModule

    write_sequence(tmp_path / "centred" / "seq", frames=(1, 2), size=HR, scales=(2,))
    _native_like(tmp_path / "other" / "seq")
    splits = {"train": ["seq"], "val": ["seq"], "test": ["seq"]}
    dm = SceneDataModule(tmp_path / "centred", splits, KEYS, scale=2.0, patch_size=None, test_root=tmp_path / "other")
    dm.setup()
    assert dm.datasets["train"].sequences[0].source.path == tmp_path / "centred" / "seq"
    test = dm.datasets["test"][0].sequences[0]
    assert test.source.path == tmp_path / "other" / "seq"
    with pytest.raises(SceneError, match="data.test_root .*missing is not a folder"):
        SceneDataModule(tmp_path / "centred", splits, KEYS, test_root=tmp_path / "missing").setup("test")
