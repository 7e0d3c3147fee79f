"""The decoded-frame cache: LRU within its budget, invisible in the batches, each file decoded once per process."""

from __future__ import annotations

import pickle
from pathlib import Path

import numpy as np
import pytest
import torch

from wdss.data import BATCH_KEYS, SceneDataModule, Sequence
from wdss.data.cache import FrameCache
from wdss.data.synthetic import write_sequence


@pytest.fixture(scope="module")
def root(tmp_path_factory) -> Path:
    root = tmp_path_factory.mktemp("scenes")
    write_sequence(root / "seq_a", layout="unreal", frames=(1, 2, 3, 4, 5), size=(24, 36), scales=(2,), cameras=True)
    return root


def planes(nbytes: int) -> dict[str, np.ndarray]:
    return {"x": np.zeros(nbytes // 4, np.float32)}


def test_least_recently_used_entries_go_first_and_the_budget_holds():
    cache = FrameCache(300)
    cache.put("a", planes(100))
    cache.put("b", planes(100))
    cache.put("c", planes(100))
    assert cache.get("a") is not None  # a is now the most recent: b goes first
    cache.put("d", planes(100))
    assert cache.get("b") is None and all(cache.get(k) is not None for k in "acd")
    assert cache.bytes == 300 and len(cache) == 3
    cache.put("a", planes(200))  # replacing an entry counts its new size only
    assert cache.bytes <= 300 and cache.get("a") is not None
    assert cache.put("huge", planes(400))["x"].nbytes == 400 and cache.get("huge") is None  # over the whole budget
    assert FrameCache(0).put("a", planes(4)) and len(FrameCache(0)) == 0
    with pytest.raises(ValueError, match="max_bytes"):
        FrameCache(-1)


def test_entries_are_read_only_and_a_pickled_cache_starts_empty():
    cache = FrameCache(1000)
    entry = cache.put("a", planes(40))
    with pytest.raises(ValueError, match="read-only"):
        entry["x"][0] = 1.0
    copy = pickle.loads(pickle.dumps(cache))
    assert len(copy) == 0 and copy.max_bytes == 1000


def test_a_sequence_read_is_the_callers_to_modify(root):
    seq = Sequence(root / "seq_a")
    seq.cache = FrameCache(2**20)
    first = seq.read(2, seq.hr, ["color", "depth"])
    expected = {k: v.copy() for k, v in first.items()}
    first["color"][:] = -1.0  # a caller writing into what it was given...
    again = seq.read(2, seq.hr, ["color", "depth"])
    for key in expected:  # ...changes nothing the next reader sees
        np.testing.assert_array_equal(again[key], expected[key])
    window, _ = seq.read_window(2, seq.hr, ["color"], (0, 0, 8, 8))
    window["color"][:] = -1.0
    np.testing.assert_array_equal(seq.read(2, seq.hr, ["color"])["color"], expected["color"])
    assert (seq.cache.hits, seq.cache.misses) == (2, 2)  # a frame is cached per set of buffers asked for


def loader(root: Path, cache_mb: int):
    dm = SceneDataModule(
        root,
        {"train": ["seq_a"]},
        BATCH_KEYS,
        patch_size=12,
        batch_size=2,
        patches_per_frame=3,
        flips=True,
        cache_mb=cache_mb,
        seed=3,
    )
    dm.setup("fit")
    return dm.train_dataloader()


def epoch(batches, number: int) -> list[dict]:
    batches.sampler.set_epoch(number)
    return list(batches)


def test_cached_batches_equal_decoded_ones_and_each_file_is_decoded_once(root, opened):
    # Mirroring and the preprocessing write into their tensors: none of it may reach a cached frame.
    plain = loader(root, cache_mb=0)
    uncached = [epoch(plain, n) for n in range(3)]
    names = opened
    names.clear()
    cached_loader = loader(root, cache_mb=64)
    cached = [epoch(cached_loader, 0)]
    decoded = len(names)
    assert decoded > 0
    cached += [epoch(cached_loader, n) for n in (1, 2)]
    assert len(names) == decoded  # the later epochs decode nothing
    for a_epoch, b_epoch in zip(uncached, cached, strict=True):
        assert len(a_epoch) == len(b_epoch) > 0
        for a, b in zip(a_epoch, b_epoch, strict=True):
            assert a["frame"].tolist() == b["frame"].tolist()
            for key in BATCH_KEYS:
                torch.testing.assert_close(a[key], b[key], rtol=0, atol=0, msg=key)


def test_cache_mb_is_checked(root):
    with pytest.raises(ValueError, match="data.cache_mb"):
        SceneDataModule(root, {"train": ["seq_a"]}, ["target"], cache_mb=-1)
