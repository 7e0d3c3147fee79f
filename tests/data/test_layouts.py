"""Reading scenes: both layouts, folders and zips, need-driven opens, and clear errors."""

from __future__ import annotations

import json
import re
import shutil
import zipfile
from pathlib import Path

import numpy as np
import pytest
import torch

from wdss.data import BUFFERS, ExrError, SceneError, Sequence, discover_sequences, read_exr, write_exr
from wdss.data.layouts import DEFAULT_FRAME_RATE
from wdss.data.synthetic import synthetic_frame, write_sequence
from wdss.ops.sampling import point_sample

HR = (24, 36)
FIXTURE = Path(__file__).resolve().parents[1] / "fixtures" / "rendered" / "fixture_000"  # 24P is 48x24


@pytest.fixture(scope="module", params=["unreal", "dfasr"])
def scene(request, tmp_path_factory) -> Path:
    root = tmp_path_factory.mktemp(f"scene_{request.param}")
    write_sequence(root / "seq", layout=request.param, frames=(1, 2, 3), size=HR, scales=(2, 3), emission=True)
    return root / "seq"


def test_every_channel_round_trips_at_every_resolution(scene):
    seq = Sequence(scene)
    assert seq.resolutions == [24, 12, 8] and seq.frames == [1, 2, 3]
    for frame in seq.frames:
        expected = synthetic_frame(frame, *HR)
        for height in seq.resolutions:
            got = seq.read(frame, height, BUFFERS)
            for name, value in got.items():
                want = expected[name]
                if height != HR[0]:
                    size = (height, round(HR[1] * height / HR[0]))
                    want = point_sample(torch.from_numpy(want)[None], size)[0].numpy()
                assert value.dtype == np.float32 and value.shape == want.shape, name
                np.testing.assert_array_equal(value, want, err_msg=f"{name} at {height}P frame {frame}")


def test_a_zipped_sequence_reads_like_its_folder(scene, tmp_path):
    archive = tmp_path / "seq.zip"
    with zipfile.ZipFile(archive, "w") as zf:
        for file in scene.rglob("*"):
            zf.write(file, Path("seq") / file.relative_to(scene))  # zipped with its top folder
    folder, zipped = Sequence(scene), Sequence(archive)
    assert zipped.name == "seq" and zipped.resolutions == folder.resolutions and zipped.frames == folder.frames
    for name, value in zipped.read(2, 12, ["color", "normal"]).items():
        np.testing.assert_array_equal(value, folder.read(2, 12, [name])[name])


def test_reads_open_only_the_files_that_hold_requested_buffers(scene):
    seq = Sequence(scene)
    seq.read(1, 24, ["color"])
    assert seq.source.opens == 1
    unreal = seq.layout.name == "unreal"
    seq.read(1, 24, ["base_color", "depth"])  # one packed file in the unreal layout, two in dfasr
    assert seq.source.opens == (2 if unreal else 3)
    seq.read(1, 24, ["motion", "roughness", "nov", "metallic"])  # unreal: MV_Roughness_NOV + PretonemapMetallic
    assert seq.source.opens == (4 if unreal else 5)


def test_discovery_finds_folders_and_zips_and_names_missing_ones(scene):
    root = scene.parent
    assert [s.name for s in discover_sequences(root)] == ["seq"]
    with pytest.raises(SceneError, match=r"sequence 'nope' not found under .* \(it holds \['seq'\]\)"):
        discover_sequences(root, ["nope"])


def test_layout_is_detected_or_refused(tmp_path):
    (tmp_path / "odd").mkdir()
    write_exr(tmp_path / "odd" / "frames" / "Color.0001.exr", {"R": np.zeros((2, 2))})
    with pytest.raises(SceneError, match="cannot tell its layout"):
        Sequence(tmp_path / "odd")
    (tmp_path / "empty").mkdir()
    with pytest.raises(SceneError, match="holds no EXR files"):
        Sequence(tmp_path / "empty")
    with pytest.raises(SceneError, match="unknown scene layout 'ue5'"):
        Sequence(write_sequence(tmp_path / "s", frames=(1,), size=(4, 4), scales=()), layout="ue5")


def test_missing_file_names_sequence_frame_file_and_channels(tmp_path):
    seq_dir = write_sequence(tmp_path / "seq", frames=(1, 2), size=(8, 8), scales=())
    (seq_dir / "8P" / "NormalSpecular.0002.exr").unlink()
    seq = Sequence(seq_dir)
    seq.read(2, 8, ["color"])  # what is there still reads
    with pytest.raises(
        SceneError,
        match=r"'seq', frame 2: buffer 'normal' is missing at 8P \(expected "
        r"8P/NormalSpecular.0002.exr, channels R,G,B\)",
    ):
        seq.read(2, 8, ["normal"])


def test_missing_channel_names_file_and_channel(tmp_path):
    seq_dir = write_sequence(tmp_path / "seq", frames=(1,), size=(8, 8), scales=())
    planes = read_exr(seq_dir / "8P" / "MV_Roughness_NOV.0001.exr")
    del planes["A"]
    write_exr(seq_dir / "8P" / "MV_Roughness_NOV.0001.exr", planes)
    with pytest.raises(ExrError, match=r"MV_Roughness_NOV.0001.exr has no channel A \(it has B, G, R\)"):
        Sequence(seq_dir).read(1, 8, ["nov"])


def test_mismatched_sizes_name_both_files(tmp_path):
    seq_dir = write_sequence(tmp_path / "seq", frames=(1,), size=(8, 8), scales=())
    write_exr(seq_dir / "8P" / "BaseColorDepth.0001.exr", {c: np.zeros((8, 6)) for c in "RGBA"})
    with pytest.raises(
        SceneError,
        match=r"buffers differ in size at 8P: .*PretonemapMetallic.0001.exr 8x8, .*BaseColorDepth.0001.exr 6x8",
    ):
        Sequence(seq_dir).read(1, 8, ["color", "depth"])


def test_truncated_exr_is_a_clear_error(tmp_path):
    seq_dir = write_sequence(tmp_path / "seq", frames=(1,), size=(8, 8), scales=())
    target = seq_dir / "8P" / "PretonemapMetallic.0001.exr"
    target.write_bytes(target.read_bytes()[:100])
    with pytest.raises(ExrError, match=r"cannot read EXR .*PretonemapMetallic.0001.exr \(corrupt, truncated"):
        Sequence(seq_dir).read(1, 8, ["color"])


def test_half_channels_read_as_float32(tmp_path):
    seq_dir = write_sequence(tmp_path / "seq", frames=(1,), size=(8, 8), scales=(), half=True)
    color = Sequence(seq_dir).read(1, 8, ["color"])["color"]
    assert color.dtype == np.float32
    np.testing.assert_allclose(color, synthetic_frame(1, 8, 8)["color"], rtol=1e-3)


def test_non_finite_values_fail_by_default_and_sanitize_counts(tmp_path):
    seq_dir = write_sequence(tmp_path / "seq", frames=(1,), size=(8, 8), scales=())
    path = seq_dir / "8P" / "PretonemapMetallic.0001.exr"
    planes = read_exr(path)
    planes["G"][0, :3] = np.nan
    planes["G"][1, 0] = np.inf
    write_exr(path, planes)
    with pytest.raises(
        SceneError, match=r"frame 1, file .*PretonemapMetallic.0001.exr, channel G: 4 non-finite"
    ) as err:
        Sequence(seq_dir).read(1, 8, ["color"])
    # the switch by the name each command takes: training's key, and upscale's and export's override
    assert "data.preprocessing.sanitize=true" in str(err.value) and "+preprocessing.sanitize=true" in str(err.value)
    seq = Sequence(seq_dir)
    color = seq.read(1, 8, ["color"], sanitize=True)["color"]
    assert np.isfinite(color).all() and color[1, 0, :3].tolist() == [0, 0, 0]
    assert seq.sanitized == {"8P/PretonemapMetallic.0001.exr:G": 4}


def test_unknown_buffer_is_refused(scene):
    with pytest.raises(SceneError, match="unknown buffer 'albedo'"):
        Sequence(scene).read(1, 24, ["albedo"])


def test_copy_without_low_resolution_folders_still_reads_hr(tmp_path, scene):
    copy = tmp_path / "hr_only"
    shutil.copytree(scene, copy)
    for folder in copy.iterdir():
        if folder.is_dir() and not folder.name.endswith("24P"):
            shutil.rmtree(folder)
    seq = Sequence(copy)
    assert seq.resolutions == [24]
    assert seq.read(3, 24, ["color"])["color"].shape == (3, 24, 36)


# Bad scene data, built from the committed fixture: each error names the file (zip and member), frame or key.


def _fixture_copy(tmp_path: Path) -> Path:
    return Path(shutil.copytree(FIXTURE, tmp_path / "fixture_000"))


def _zip_of(folder: Path, archive: Path) -> Path:
    archive.parent.mkdir(parents=True, exist_ok=True)
    with zipfile.ZipFile(archive, "w", zipfile.ZIP_STORED) as zf:  # stored: member bytes appear verbatim
        for file in sorted(folder.rglob("*")):
            zf.write(file, Path(folder.name) / file.relative_to(folder))
    return archive


@pytest.mark.parametrize("zipped", [False, True])
@pytest.mark.parametrize("read_first_frame_first", [False, True])
def test_a_frame_of_another_size_names_the_file_and_both_sizes(tmp_path, zipped, read_first_frame_first):
    seq_dir = _fixture_copy(tmp_path / "src")
    for file in (seq_dir / "24P").glob("*.0003.exr"):  # frame 3 rendered at 40x24 instead of 48x24
        write_exr(file, {c: plane[:, :40] for c, plane in read_exr(file).items()})
    seq = Sequence(_zip_of(seq_dir, tmp_path / "fixture_000.zip") if zipped else seq_dir)
    if read_first_frame_first:
        seq.read(1, 24, ["color"])
    seq.read(2, 24, ["color", "depth"])  # frames of the first frame's size still read
    with pytest.raises(
        SceneError,
        match=r"'fixture_000', frame 3: .*fixture_000.*24P/PretonemapMetallic.0003.exr is 40x24, but the "
        r"sequence's first frame at 24P is 48x24 \(.*24P/PretonemapMetallic.0000.exr\)",
    ):
        seq.read(3, 24, ["color"])


def test_an_exr_truncated_after_its_header_is_a_clear_error(tmp_path):
    seq_dir = _fixture_copy(tmp_path)
    target = seq_dir / "24P" / "PretonemapMetallic.0001.exr"
    target.write_bytes(target.read_bytes()[: target.stat().st_size // 2])
    seq = Sequence(seq_dir)
    with pytest.raises(ExrError, match=r"cannot read EXR .*24P/PretonemapMetallic.0001.exr \(corrupt or truncated"):
        seq.read(1, 24, ["color"])


def test_a_zip_member_with_a_bad_crc_names_the_zip_and_the_member(tmp_path):
    archive = _zip_of(FIXTURE, tmp_path / "fixture_000.zip")
    data = bytearray(archive.read_bytes())
    member = (FIXTURE / "24P" / "PretonemapMetallic.0001.exr").read_bytes()
    data[data.index(member) + len(member) // 2] ^= 0xFF
    archive.write_bytes(bytes(data))
    seq = Sequence(archive)  # the central directory is intact: the damage shows when the member is read
    seq.read(1, 24, ["depth"])
    with pytest.raises(
        SceneError,
        match=r"cannot read member fixture_000/24P/PretonemapMetallic.0001.exr of zip .*fixture_000.zip: Bad CRC",
    ):
        seq.read(1, 24, ["color"])


def test_a_truncated_zip_fails_at_discovery_naming_the_zip(tmp_path):
    archive = _zip_of(FIXTURE, tmp_path / "root" / "fixture_000.zip")
    archive.write_bytes(archive.read_bytes()[: archive.stat().st_size // 2])
    with pytest.raises(SceneError, match=r"sequence .*fixture_000.zip is not a readable zip file .*truncated"):
        discover_sequences(tmp_path / "root")


@pytest.mark.parametrize(
    "text, message",
    [
        ("{ bad", r"sequence.json is not valid JSON: Expecting property name .* line 1 column 3"),
        ('{"frames": [{"frame": 1}]}', r"sequence.json: malformed 'frames' \(KeyError: 'camera_to_world'\)"),
        (
            '{"frames": [{"frame": 1, "camera_to_world": [1, 2]}]}',
            r"sequence.json: malformed .*camera_to_world of frame 1 has shape \[2\]",
        ),
        ('{"fps": "fast"}', r"sequence.json: 'fps' must be a number of frames per second, got 'fast'"),
    ],
)
def test_a_malformed_sequence_json_fails_at_discovery_naming_the_file(tmp_path, text, message):
    seq_dir = _fixture_copy(tmp_path)
    (seq_dir / "sequence.json").write_text(text)
    with pytest.raises(SceneError, match=rf"{re.escape(str(seq_dir))}/{message}"):
        discover_sequences(tmp_path, ["fixture_000"])


def test_the_frame_rate_comes_from_sequence_json_else_the_default(tmp_path):
    seq_dir = _fixture_copy(tmp_path)
    assert Sequence(seq_dir).frame_rate == DEFAULT_FRAME_RATE == 30.0  # the fixture's sidecar says nothing
    meta = json.loads((seq_dir / "sequence.json").read_text())
    (seq_dir / "sequence.json").write_text(json.dumps({**meta, "fps": 59.94}))
    assert Sequence(seq_dir).frame_rate == 59.94


def _claim_size(path: Path, height: int, width: int) -> None:
    """Rewrite an EXR's header to claim ``height`` x ``width`` pixels (its pixel data stays what it was)."""
    data = bytearray(path.read_bytes())
    at = data.index(b"dataWindow\0box2i\0") + len(b"dataWindow\0box2i\0") + 4
    data[at : at + 16] = np.array([0, 0, width - 1, height - 1], "<i4").tobytes()
    path.write_bytes(bytes(data))


@pytest.mark.parametrize("zipped", [False, True])
def test_a_header_claiming_another_size_is_refused_before_its_pixels_are_decoded(tmp_path, monkeypatch, zipped):
    """A 23 KB file claiming 60000x60000 would have the decoder allocate ~27 GB: its header is compared first."""
    from wdss.data import exr

    seq_dir = _fixture_copy(tmp_path / "src")
    _claim_size(seq_dir / "24P" / "PretonemapMetallic.0003.exr", 60000, 60000)
    seq = Sequence(_zip_of(seq_dir, tmp_path / "fixture_000.zip") if zipped else seq_dir)
    decoded = []
    original = exr._open
    monkeypatch.setattr(
        exr, "_open", lambda *a, header_only: decoded.append(header_only) or original(*a, header_only=header_only)
    )
    with pytest.raises(
        SceneError,
        match=r"'fixture_000', frame 3: .*24P/PretonemapMetallic.0003.exr is 60000x60000, but the sequence's first "
        r"frame at 24P is 48x24",
    ):
        seq.read(3, 24, ["color"])
    assert decoded and all(decoded)  # headers only: no pixel of the file was decoded


def test_a_first_frame_whose_header_is_not_as_high_as_its_folder_is_refused(tmp_path):
    seq_dir = _fixture_copy(tmp_path)
    _claim_size(seq_dir / "24P" / "PretonemapMetallic.0000.exr", 60000, 60000)
    message = r"'fixture_000': .*24P/PretonemapMetallic.0000.exr is 60000x60000 by its header, but its folder is 24P"
    with pytest.raises(SceneError, match=message):
        Sequence(seq_dir).read(2, 24, ["color"])
    with pytest.raises(SceneError, match=message):
        Sequence(seq_dir).shape(24)
