"""One frame-source interface (wdss.data.source.FrameSource) for EXR sequences and packed stores: both implement it
with the same signatures, and a frame read through either gives the same arrays."""

from __future__ import annotations

import inspect
from pathlib import Path

import numpy as np
import pytest

from wdss.data.buffers import BUFFERS
from wdss.data.cache import FrameCache
from wdss.data.layouts import SceneError, Sequence
from wdss.data.pack import pack_sequence
from wdss.data.packed import PackedSequence
from wdss.data.source import FrameSource

FIXTURE = Path(__file__).resolve().parents[1] / "fixtures" / "rendered" / "fixture_000"
METHODS = [name for name, value in vars(FrameSource).items() if inspect.isfunction(value) and not name.startswith("_")]


@pytest.fixture(scope="module", params=[("lz4", 16), ("none", 0)], ids=["lz4-tiles", "none-whole"])
def sources(request, tmp_path_factory) -> tuple[Sequence, PackedSequence]:
    codec, tile = request.param
    folder = tmp_path_factory.mktemp("packed") / FIXTURE.name
    packed = pack_sequence(Sequence(FIXTURE), folder, codec=codec, tile=tile, verify=0)
    return Sequence(FIXTURE), PackedSequence(packed.folder)


def test_the_protocol_declares_what_the_dataset_reads():
    assert {"has", "shape", "read", "read_window", "camera", "lr_jitter", "frames_at", "stale", "use_cache"} <= set(
        METHODS
    )


@pytest.mark.parametrize("kind", [Sequence, PackedSequence])
def test_both_kinds_implement_every_method_with_the_protocols_signature(kind):
    for name in METHODS:
        expected = inspect.signature(getattr(FrameSource, name)).parameters
        found = inspect.signature(getattr(kind, name)).parameters
        assert [(p.name, p.kind, p.default) for p in found.values()] == [
            (p.name, p.kind, p.default) for p in expected.values()
        ], f"{kind.__name__}.{name}"


def test_both_sources_are_frame_sources_with_the_same_facts(sources):
    exr, packed = sources
    assert isinstance(exr, FrameSource) and isinstance(packed, FrameSource)
    for attribute in ("name", "resolutions", "hr", "frames", "frame_rate"):
        assert getattr(packed, attribute) == getattr(exr, attribute), attribute
    for height in exr.resolutions:
        assert packed.shape(height) == exr.shape(height)
        assert packed.frames_at(height) == exr.frames_at(height)
        for buffer in BUFFERS:
            assert packed.has(buffer, height) == exr.has(buffer, height), (buffer, height)
            assert packed.has(buffer, height, exr.frames[1]) == exr.has(buffer, height, exr.frames[1])
    for frame in exr.frames:
        assert packed.lr_jitter(frame) == exr.lr_jitter(frame)
        camera = exr.camera(frame)
        assert (packed.camera(frame) is None) == (camera is None)
        if camera is not None:
            np.testing.assert_array_equal(packed.camera(frame).numpy(), camera.numpy())
    assert exr.stale() is None and packed.stale() is None


def test_a_frame_read_through_either_source_gives_the_same_arrays(sources):
    exr, packed = sources
    frame = exr.frames[1]
    for height in exr.resolutions:
        buffers = [b for b in BUFFERS if exr.has(b, height, frame)]
        whole = {kind: source.read(frame, height, buffers) for kind, source in (("exr", exr), ("packed", packed))}
        assert set(whole["exr"]) == set(whole["packed"]) == set(buffers)
        for buffer in buffers:
            assert whole["exr"][buffer].dtype == whole["packed"][buffer].dtype == np.float32
            np.testing.assert_array_equal(whole["packed"][buffer], whole["exr"][buffer], err_msg=buffer)
        h, w = exr.shape(height)
        window = (-3, w // 3, h // 2 + 3, w)  # over the top and the right edge: zeros beyond the frame
        options = {"depth_far": 100.0, "depth_range": True}
        cut_exr, range_exr = exr.read_window(frame, height, buffers, window, **options)
        cut_packed, range_packed = packed.read_window(frame, height, buffers, window, **options)
        assert range_packed == range_exr
        for buffer in buffers:
            assert cut_packed[buffer].shape == cut_exr[buffer].shape == (BUFFERS[buffer], h // 2 + 3, w)
            np.testing.assert_array_equal(cut_packed[buffer].astype(np.float32), cut_exr[buffer], err_msg=buffer)
            np.testing.assert_array_equal(cut_exr[buffer][:, :3], 0)


def test_a_frame_neither_source_holds_is_a_scene_error_naming_it(sources):
    for source in sources:
        with pytest.raises(SceneError, match=r"fixture_000.*frame 99"):
            source.read_window(99, source.hr, ["color"], None)


def test_only_the_exr_source_keeps_decoded_frames(sources):
    exr, packed = sources
    cache = FrameCache(2**20)
    exr.use_cache(cache)
    packed.use_cache(cache)
    assert exr.cache is cache and not hasattr(packed, "cache")
    exr.read(exr.frames[0], exr.hr, ["color"])
    packed.read(packed.frames[0], packed.hr, ["color"])
    assert cache.misses == 1
    exr.use_cache(None)
