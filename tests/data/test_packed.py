"""Packed stores: the same batches as the EXR files, in either preprocessing placement; corrupt, interrupted, stale and
non-finite stores give clear errors or resume."""

from __future__ import annotations

import json
import shutil
from pathlib import Path

import numpy as np
import pytest
import torch

from wdss.data import BATCH_KEYS, SceneDataModule, SceneError, Sequence
from wdss.data import pack as pack_module
from wdss.data.dataset import Collate, FrameDataset, Preprocessing, _mix
from wdss.data.exr import read_exr, write_exr
from wdss.data.pack import main as pack_main
from wdss.data.pack import pack, pack_sequence, verify_sequence
from wdss.data.packed import PackedSequence
from wdss.data.preprocess import RawBatch
from wdss.data.synthetic import write_sequence

FIXTURES = Path(__file__).resolve().parents[1] / "fixtures" / "rendered"
SPLITS = {"train": ["fixture_000"], "val": ["fixture_000"], "test": ["fixture_000"]}


@pytest.fixture(
    scope="module", params=[("lz4", 16), ("zstd", 16), ("none", 0)], ids=["lz4-tiles", "zstd-tiles", "none-whole"]
)
def store(request, tmp_path_factory) -> Path:
    codec, tile = request.param
    out = tmp_path_factory.mktemp("packed") / "rendered.packed"
    pack(FIXTURES, out, codec=codec, tile=tile, verify=None)  # every frame compared bit for bit with its EXR
    return out


def batches(store: Path | None, placement: str, **kwargs) -> tuple[dict, dict]:
    """The first training batch (patches, flips, a scale range) and the first test batch, read from the EXR files
    (``store`` None) or the packed store, preprocessed in the loader or on the device (the DataModule's hook)."""
    options = dict(patch_size=24, batch_size=2, scale=[2, 4], flips=True, test_scales=[2.0]) | kwargs
    dm = SceneDataModule(
        FIXTURES,
        SPLITS,
        BATCH_KEYS,
        format="exr" if store is None else "packed",
        packed_root=store,
        preprocess_on=placement,
        **options,
    )
    dm.setup()
    kind = Sequence if store is None else PackedSequence
    assert all(isinstance(s, kind) for s in dm.datasets["train"].sequences)
    out = []
    for loader in (dm.train_dataloader(), dm.test_dataloader()[0]):
        batch = next(iter(loader))
        assert isinstance(batch, RawBatch) == (placement == "device")
        out.append(dm.on_after_batch_transfer(batch, 0))
    return out[0], out[1]


def assert_same(batch: dict, expected: dict) -> None:
    assert set(batch) == set(expected)
    for key in BATCH_KEYS:
        assert batch[key].dtype == torch.float32, key
        torch.testing.assert_close(batch[key], expected[key], rtol=0, atol=1e-6, msg=key)
    assert batch["sequence"] == expected["sequence"] and torch.equal(batch["frame"], expected["frame"])
    assert torch.equal(batch["scale"], expected["scale"])


def test_packed_batches_are_the_exr_batches_in_either_placement(store):
    """Packed or EXR, preprocessed in the loader or on the device: one batch (patches, history, masks, scales)."""
    train, test = batches(None, "loader")
    assert float(train["history"].abs().sum()) > 0 and 0 < float(train["spatial_mask"].mean()) < 1
    for source, placement in ((None, "device"), (store, "loader"), (store, "device")):
        other_train, other_test = batches(source, placement)
        assert_same(other_train, train)
        assert_same(other_test, test)


def test_sequences_of_steps_are_built_on_the_device_alike(store):
    keys = ["lr", "history", "temporal_mask", "target", "brdf", "motion"]
    built = []
    for source, placement in ((None, "loader"), (store, "device")):
        dm = SceneDataModule(
            FIXTURES, SPLITS, keys, format="exr" if source is None else "packed", packed_root=source,
            preprocess_on=placement, patch_size=24, batch_size=1, sequence_length=2, scale=2.0,
        )  # fmt: skip
        dm.setup("fit")
        built.append(dm.on_after_batch_transfer(next(iter(dm.train_dataloader())), 0))
    for step, expected in zip(built[1]["steps"], built[0]["steps"], strict=True):
        for key in keys:
            torch.testing.assert_close(step[key], expected[key], rtol=0, atol=1e-6)


def test_a_patch_reads_only_its_tiles_and_history_from_outside_the_patch_is_kept(tmp_path):
    """The previous frame is read with the margin the motion needs: the warped history of a translating scene is
    the current irradiance up to the patch's border (zeros only where it came from outside the frame)."""
    path = write_sequence(tmp_path / "seq", frames=(1, 2), size=(40, 48), scales=(2,), motion=(3.0, -2.0))
    packed = pack_sequence(Sequence(path), tmp_path / "packed" / "seq", tile=8, verify=0)
    decoded = []
    original = packed._decode
    packed._decode = lambda data, size: decoded.append(size) or original(data, size)
    window, _ = packed.read_window(2, 40, ["color"], (8, 16, 8, 8))
    assert len(decoded) == 1  # one 8x8 tile: an aligned patch decodes nothing else
    np.testing.assert_array_equal(window["color"], Sequence(path).read(2, 40, ["color"])["color"][:, 8:16, 16:24])
    keys = ["history", "temporal_mask", "target", "brdf"]
    collate = Collate(keys, Preprocessing(), 2.0)
    full = collate([FrameDataset([packed], keys, scale=2.0)[0]])
    dataset = FrameDataset([packed], keys, scale=2.0, patch=16)
    for epoch in range(6):
        sample = dataset[(0, epoch)]
        assert sample["margins"]["prev"] == 4  # |motion| 3, plus one for the bilinear taps
        assert sample["prev"]["color"].shape[-2:] == (24, 24)
        (y, x, size, _), _ = dataset._window(packed, None, torch.Generator().manual_seed(_mix(0, epoch, 0)))
        patch = collate([sample])
        for key in ("history", "temporal_mask"):  # the whole frame's, cut: not zeros at the patch's border
            torch.testing.assert_close(patch[key], full[key][..., y : y + size, x : x + size], rtol=1e-4, atol=1e-5)


@pytest.mark.parametrize("codec", ["lz4", "zstd"])
def test_a_corrupt_store_names_the_file_and_the_sequence(tmp_path, codec):
    path = write_sequence(tmp_path / "seq", frames=(1, 2), size=(16, 24), scales=(2,))
    folder = tmp_path / "packed" / "seq"
    pack_sequence(Sequence(path), folder, codec=codec, tile=8, verify=0)
    hr = folder / "16P.bin"
    data = bytearray(hr.read_bytes())
    # A flipped byte inside a chunk: its checksum fails when that tile is read.
    index = json.loads((folder / "index.json").read_text())
    record = index["resolutions"]["16"]["packed"]["2"]
    data[record["offset"] + record["length"] - 8] ^= 0xFF
    hr.write_bytes(bytes(data))
    with pytest.raises(SceneError, match=rf"packed file {hr} of sequence 'seq' is corrupt: frame 2, buffer motion"):
        PackedSequence(folder).read_window(2, 16, ["motion"], None)
    # A truncated file: refused when the sequence is opened.
    hr.write_bytes(bytes(data[:-100]))
    with pytest.raises(SceneError, match=rf"packed file {hr} of sequence 'seq' \(16P\) is .* truncated or corrupt"):
        PackedSequence(folder)
    (folder / "index.json").write_text("{not json")
    with pytest.raises(SceneError, match=r"packed index .*index.json cannot be read"):
        PackedSequence(folder)
    with pytest.raises(SceneError, match=r"sequence 'other' is not packed in .*wdss.data.pack"):
        SceneDataModule(tmp_path, {"train": ["other"]}, ["target"], format="packed", packed_root=tmp_path).setup("fit")


def test_an_interrupted_pack_resumes_where_it_stopped(tmp_path, monkeypatch):
    path = write_sequence(tmp_path / "seq", frames=(1, 2, 3, 4), size=(16, 24), scales=(2,))
    folder = tmp_path / "packed" / "seq"
    encoded = []
    original = pack_module._encode

    def killed_at_the_third_frame(*args, **kwargs):
        if len(encoded) == 2:
            with open(folder / "16P.bin", "ab") as out:
                out.write(b"half a record")  # what a kill leaves behind
            raise KeyboardInterrupt
        encoded.append(1)
        return original(*args, **kwargs)

    monkeypatch.setattr(pack_module, "SAVE_EVERY_S", 0.0)
    monkeypatch.setattr(pack_module, "_encode", killed_at_the_third_frame)
    with pytest.raises(KeyboardInterrupt):
        pack_sequence(Sequence(path), folder, verify=0)
    with pytest.raises(
        SceneError, match=r"packed sequence 'seq' .* is incomplete .* run python -m wdss.data.pack again"
    ):
        PackedSequence(folder)
    monkeypatch.setattr(pack_module, "_encode", lambda *a, **k: encoded.append(1) or original(*a, **k))
    packed = pack_sequence(Sequence(path), folder, verify=None)  # every frame compared with its EXR
    assert len(encoded) == 2 + 6  # two HR frames kept; two more and four at 8P packed on resuming
    assert packed.frames == [1, 2, 3, 4] and verify_sequence(Sequence(path), packed, None) == 8
    with pytest.raises(SceneError, match="other settings"):
        pack_sequence(Sequence(path), folder, codec="none")


def test_a_stale_store_is_refused_when_packed_and_passed_over_when_auto(tmp_path, caplog):
    root = tmp_path / "scenes"
    path = write_sequence(root / "seq", frames=(1, 2), size=(16, 24), scales=(2,))
    pack(root, verify=0)
    keys = ["lr", "target", "brdf"]
    auto = SceneDataModule(root, {"train": ["seq"]}, keys, patch_size=8)
    auto.setup("fit")
    assert isinstance(auto.datasets["train"].sequences[0], PackedSequence)
    write_exr(path / "16P" / "PretonemapMetallic.0002.exr", {c: np.ones((16, 24), np.float32) for c in "RGBA"})
    with pytest.raises(SceneError, match=r"packed sequence 'seq' .* is out of date: .*PretonemapMetallic.0002.exr"):
        SceneDataModule(root, {"train": ["seq"]}, keys, patch_size=8, format="packed").setup("fit")
    auto = SceneDataModule(root, {"train": ["seq"]}, keys, patch_size=8)
    auto.setup("fit")
    assert isinstance(auto.datasets["train"].sequences[0], Sequence)
    assert "reading seq from EXR files, not its packed copy" in caplog.text


def test_non_finite_values_fail_unless_sanitized_and_inputs_pack_only_their_buffers(tmp_path):
    path = write_sequence(tmp_path / "scenes" / "seq", frames=(1, 2), size=(16, 24), scales=(2,))
    name = path / "16P" / "BaseColorDepth.0002.exr"
    planes = read_exr(name)
    planes["A"][3, 4] = np.nan
    write_exr(name, planes)
    pack_main([f"root={tmp_path / 'scenes'}", "inputs=lr,target", "verify=all"])
    packed = PackedSequence(tmp_path / "scenes.packed" / "seq")
    # A bare model with demodulation reads colour and the BRDF's buffers: no depth, normal or motion.
    assert sorted(packed._res[16]["buffers"]) == ["base_color", "color", "metallic", "specular"]
    shutil.rmtree(tmp_path / "scenes.packed")
    pack(tmp_path / "scenes", verify=0)
    packed = PackedSequence(tmp_path / "scenes.packed" / "seq")
    with pytest.raises(SceneError, match=r"sequence 'seq', frame 2, buffer depth .* 1 non-finite value") as err:
        packed.read_window(2, 16, ["depth"], (0, 0, 8, 8))
    # The switch as each command takes it: data.preprocessing.sanitize=true, and upscale/export's own spelling.
    assert "data.preprocessing.sanitize=true" in str(err.value) and "+preprocessing.sanitize=true" in str(err.value)
    window, _ = packed.read_window(2, 16, ["depth"], (0, 0, 8, 8), sanitize=True)
    assert np.isfinite(window["depth"]).all() and packed.sanitized == {"16P:2:depth": 1}


def test_lightning_builds_raw_batches_in_the_datamodules_hook(tmp_path):
    """preprocess_on=device: the loader yields raw batches, and Lightning's transfer hands the model built ones."""
    import lightning as L

    seen = []

    class Probe(L.LightningModule):
        def __init__(self) -> None:
            super().__init__()
            self.weight = torch.nn.Parameter(torch.zeros(()))

        def training_step(self, batch, batch_idx):
            seen.append(batch)
            return (batch["history"].mean() * self.weight).sum()

        def configure_optimizers(self):
            return torch.optim.SGD(self.parameters(), lr=0.1)

    dm = SceneDataModule(FIXTURES, {"train": ["fixture_000"]}, ["history", "target", "brdf"], patch_size=24,
                         batch_size=2, preprocess_on="device")  # fmt: skip
    trainer = L.Trainer(
        accelerator="cpu", fast_dev_run=1, logger=False, enable_checkpointing=False, enable_progress_bar=False,
        enable_model_summary=False, default_root_dir=tmp_path,
    )  # fmt: skip
    trainer.fit(Probe(), datamodule=dm)
    assert isinstance(next(iter(dm.train_dataloader())), RawBatch)
    assert len(seen) == 1 and seen[0]["history"].shape == (2, 3, 24, 24) and seen[0]["target"].dtype == torch.float32


def test_a_zipped_sequence_packs_like_its_folder(tmp_path):
    path = write_sequence(tmp_path / "scenes" / "seq", frames=(1, 2), size=(16, 24), scales=(2,), cameras=True)
    shutil.make_archive(str(tmp_path / "zipped" / "seq"), "zip", root_dir=tmp_path / "scenes", base_dir="seq")
    folder, zipped = (pack_sequence(Sequence(p), tmp_path / f"{p.name}.packed", verify=None)
                      for p in (path, tmp_path / "zipped" / "seq.zip"))  # fmt: skip
    assert zipped.index["zip_prefix"] == "seq/" and zipped.stale() is None and zipped.camera(1) is not None
    for frame in (1, 2):
        for height in (16, 8):
            a, b = (s.read(frame, height, ["color", "motion", "depth"]) for s in (folder, zipped))
            assert all(np.array_equal(a[k], b[k]) for k in a)


def test_a_source_frame_rerendered_at_the_same_byte_size_makes_the_store_stale(tmp_path):
    """Sizes and CRC-32 are compared (the README's promise), for a folder as for a zip."""
    root = tmp_path / "scenes"
    path = write_sequence(root / "seq", frames=(1, 2), size=(16, 24), scales=(2,))
    pack(root, verify=0)
    packed = PackedSequence(root.with_name("scenes.packed") / "seq")
    assert packed.stale() is None
    file = path / "16P" / "PretonemapMetallic.0002.exr"
    data = bytearray(file.read_bytes())
    data[-1] ^= 0xFF  # the same byte size, other content
    file.write_bytes(bytes(data))
    assert packed.stale() == f"{file} changed since it was packed (sizes and CRC-32 compared: its CRC-32 differs)"
    with pytest.raises(SceneError, match=r"out of date: .*PretonemapMetallic.0002.exr .*its CRC-32 differs"):
        SceneDataModule(root, {"train": ["seq"]}, ["target"], patch_size=8, format="packed").setup("fit")
    with pytest.raises(SceneError, match=r"cannot resume packing 'seq' .*: .*its CRC-32 differs"):
        pack(root, verify=0)


def test_a_store_without_checksums_says_it_is_unchecked(tmp_path, capsys):
    root = tmp_path / "scenes"
    write_sequence(root / "seq", frames=(1, 2), size=(16, 24), scales=())
    pack_main([f"root={root}", "codec=none", "verify=0"])
    assert "codec=none stores no checksum: a byte that changes in" in capsys.readouterr().out
    folder = root.with_name("scenes.packed") / "seq"
    packed = PackedSequence(folder)
    assert not packed.checksummed
    hr = folder / "16P.bin"
    buffers = list(packed.index["resolutions"]["16"]["buffers"])
    before = packed.read_window(2, 16, buffers, None)[0]
    data = bytearray(hr.read_bytes())
    record = packed.index["resolutions"]["16"]["packed"]["2"]
    data[record["offset"] + record["length"] - 2] ^= 0x40  # a bit of the last buffer's last value
    hr.write_bytes(bytes(data))
    after = PackedSequence(folder).read_window(2, 16, buffers, None)[0]
    # Served as it is, no error: what the packer's line and the errors say.
    assert [b for b in buffers if not np.array_equal(after[b], before[b], equal_nan=True)] == buffers[-1:]
    hr.write_bytes(bytes(data[:-100]))
    with pytest.raises(SceneError, match=r"is .* truncated or corrupt \(codec=none stores no checksum: bytes changed"):
        PackedSequence(folder)
    write_sequence(tmp_path / "lz4" / "seq", frames=(1,), size=(16, 24), scales=())
    assert PackedSequence(pack(tmp_path / "lz4", verify=0) / "seq").checksummed
