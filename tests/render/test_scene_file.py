"""Scene-file settings are checked, with the key, the sequence and the file named, before anything is made."""

from __future__ import annotations

import hashlib
import json
import re
import struct

import pytest

from wdss.render.scene_file import check_scene, file_digest, scene_resources
from wdss.render.sequence import render_sequences


def glb(gltf: dict) -> bytes:
    """A glTF 2.0 binary holding ``gltf`` as its JSON chunk (and no binary chunk)."""
    text = json.dumps(gltf).encode()
    text += b" " * (-len(text) % 4)
    return struct.pack("<4sII", b"glTF", 2, 20 + len(text)) + struct.pack("<I4s", len(text), b"JSON") + text


def test_a_procedural_scene_takes_the_default_camera_and_lighting():
    assert check_scene(None, "auto", "auto", where="sequence 'a'") is None
    assert check_scene(None, "orbit", "hdri", where="sequence 'a'") is None


@pytest.mark.parametrize(
    ("scene", "camera", "lighting", "error", "message"),
    [
        ("model.obj", "auto", "auto", ValueError, r"render\.scene \(sequence 'a'\): model\.obj is not a scene file"),
        ("missing.glb", "auto", "auto", FileNotFoundError, r"render\.scene \(sequence 'a'\): missing\.glb does not"),
        ("scene.glb", "dolly", "auto", ValueError, r"render\.camera \(sequence 'a'\) must be one of auto, file, orb"),
        ("scene.glb", "auto", "neon", ValueError, r"render\.lighting \(sequence 'a'\) must be one of auto, file, hd"),
        (None, "fly", "auto", ValueError, r"render\.camera=fly \(sequence 'a'\) needs a scene file"),
        (None, "auto", "file", ValueError, r"render\.lighting=file \(sequence 'a'\) needs a scene file"),
    ],
)
def test_bad_settings_are_refused(tmp_path, monkeypatch, scene, camera, lighting, error, message):
    monkeypatch.chdir(tmp_path)
    (tmp_path / "scene.glb").write_bytes(glb({"asset": {"version": "2.0"}}))
    with pytest.raises(error, match=message):
        check_scene(scene, camera, lighting, where="sequence 'a'")


def test_every_sequence_is_checked_before_the_first_is_rendered(tmp_path):
    good = tmp_path / "scene.glb"
    good.write_bytes(glb({"asset": {"version": "2.0"}}))
    sequences = [{"name": "a", "seed": 0, "scene": str(good)}, {"name": "b", "seed": 1, "scene": "gone.blend"}]
    with pytest.raises(FileNotFoundError, match=r"render\.scene \(sequence 'b'\): gone\.blend does not exist"):
        render_sequences(tmp_path / "out", sequences, frames=1, resolution=(32, 16), scales=(2,))
    with pytest.raises(ValueError, match=r"render\.sequences\[0\] needs a name and a seed"):
        render_sequences(tmp_path / "out", [{"name": "a"}], frames=1)
    # A key no sequence takes (a typo, or a top-level-only key) is named before the first sequence renders.
    typo = [{"name": "a", "seed": 0}, {"name": "b", "seed": 1, "camra": "fly"}]
    with pytest.raises(ValueError, match=r"render\.sequences\[1\] \(sequence 'b'\): unknown key\(s\) camra"):
        render_sequences(tmp_path / "out", typo, frames=1, resolution=(32, 16), scales=(2,))
    with pytest.raises(ValueError, match=r"render: unknown setting\(s\) sampels"):
        render_sequences(tmp_path / "out", [{"name": "a", "seed": 0}], sampels=4)
    twice = [{"name": "a", "seed": 0}, {"name": "a", "seed": 1}]
    with pytest.raises(ValueError, match=r"render\.sequences\[1\]: sequence 'a' appears twice"):
        render_sequences(tmp_path / "out", twice, frames=1, resolution=(32, 16), scales=(2,))
    assert not (tmp_path / "out").exists()


def test_a_gltf_digest_covers_every_file_it_references(tmp_path):
    """A .gltf's buffers and images live beside it: a changed .bin or texture is another scene (no resume)."""
    (tmp_path / "tex").mkdir()
    (tmp_path / "mesh.bin").write_bytes(b"\0" * 8)
    (tmp_path / "tex" / "wall a.png").write_bytes(b"png")
    gltf = {
        "asset": {"version": "2.0"},
        "buffers": [{"uri": "mesh.bin", "byteLength": 8}, {"uri": "data:application/octet-stream;base64,AAAA"}],
        "images": [{"uri": "tex/wall%20a.png"}, {"bufferView": 0, "mimeType": "image/png"}],
    }
    path = tmp_path / "scene.gltf"
    path.write_text(json.dumps(gltf))
    assert [uri for uri, _ in scene_resources(path)] == ["mesh.bin", "tex/wall%20a.png"]
    assert scene_resources(path)[1][1] == tmp_path / "tex" / "wall a.png"
    digests = {file_digest(path)}
    (tmp_path / "mesh.bin").write_bytes(b"\1" * 8)
    digests.add(file_digest(path))
    (tmp_path / "tex" / "wall a.png").write_bytes(b"PNG")
    digests.add(file_digest(path))
    assert len(digests) == 3
    assert check_scene(path, "auto", "auto", where="sequence 'a'") == path.resolve()
    # A .glb with no external file keeps the digest of the file alone (as sidecars written before record it);
    # one with an external texture covers it too.
    inside = tmp_path / "inside.glb"
    inside.write_bytes(glb({"asset": {"version": "2.0"}, "images": [{"uri": "data:image/png;base64,AAAA"}]}))
    assert file_digest(inside) == hashlib.sha256(inside.read_bytes()).hexdigest()
    outside = tmp_path / "outside.glb"
    outside.write_bytes(glb({"asset": {"version": "2.0"}, "images": [{"uri": "tex/wall%20a.png"}]}))
    before = file_digest(outside)
    (tmp_path / "tex" / "wall a.png").write_bytes(b"png2")
    assert file_digest(outside) != before


def test_a_missing_or_unreadable_gltf_resource_is_named_before_anything_is_written(tmp_path):
    path = tmp_path / "scene.gltf"
    path.write_text(json.dumps({"asset": {"version": "2.0"}, "buffers": [{"uri": "gone.bin", "byteLength": 4}]}))
    sequences = [{"name": "a", "seed": 0}, {"name": "b", "seed": 1, "scene": str(path)}]
    message = r"render\.scene \(sequence 'b'\): .*scene\.gltf references 'gone\.bin', and .*gone\.bin does not exist"
    with pytest.raises(FileNotFoundError, match=message):
        render_sequences(tmp_path / "out", sequences, frames=1, resolution=(32, 16), scales=(2,))
    path.write_text("{not json")
    with pytest.raises(ValueError, match=r"render\.scene \(sequence 'b'\): .*scene\.gltf could not be read"):
        render_sequences(tmp_path / "out", sequences, frames=1, resolution=(32, 16), scales=(2,))
    assert not (tmp_path / "out").exists()


@pytest.mark.parametrize(
    "uri", ["../outside/scene.bin", "../../../../etc/passwd", "/etc/passwd", "tex/../../outside/x.bin", "%2E%2E/x.bin"]
)
def test_a_gltf_uri_outside_the_scene_folder_is_refused_naming_it_before_blender_reads_it(tmp_path, uri):
    scene = tmp_path / "scenes" / "a"
    scene.mkdir(parents=True)
    (tmp_path / "scenes" / "outside").mkdir()
    (tmp_path / "scenes" / "outside" / "scene.bin").write_bytes(b"\0" * 8)
    (tmp_path / "scenes" / "x.bin").write_bytes(b"\0" * 8)
    path = scene / "scene.gltf"
    path.write_text(json.dumps({"asset": {"version": "2.0"}, "buffers": [{"uri": uri, "byteLength": 8}]}))
    message = rf"render\.scene \(sequence 'a'\): .*scene\.gltf references '{re.escape(uri)}', which lies outside"
    with pytest.raises(ValueError, match=message):
        check_scene(path, "auto", "auto", where="sequence 'a'")
    with pytest.raises(ValueError, match=message):  # checked before the first sequence renders
        render_sequences(tmp_path / "out", [{"name": "a", "seed": 0, "scene": str(path)}], frames=1, scales=(2,))
    assert not (tmp_path / "out").exists()


def test_a_gltf_resource_linked_from_outside_its_folder_is_refused(tmp_path):
    (tmp_path / "a").mkdir()
    (tmp_path / "secret.bin").write_bytes(b"\0" * 8)
    (tmp_path / "a" / "mesh.bin").symlink_to(tmp_path / "secret.bin")
    path = tmp_path / "a" / "scene.gltf"
    path.write_text(json.dumps({"asset": {"version": "2.0"}, "buffers": [{"uri": "mesh.bin", "byteLength": 8}]}))
    with pytest.raises(ValueError, match=r"references 'mesh\.bin', which lies outside the scene file's folder"):
        scene_resources(path)
