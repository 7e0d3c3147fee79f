"""Scene-file settings are checked, with the key, the sequence and the file named, before anything is made."""

from __future__ import annotations

import pytest

from wdss.render.scene_file import check_scene
from wdss.render.sequence import render_sequences


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
    (tmp_path / "scene.glb").write_bytes(b"glTF")
    with pytest.raises(error, match=message):
        check_scene(scene, camera, lighting, where="sequence 'a'")


def test_every_sequence_is_checked_before_the_first_is_rendered(tmp_path):
    good = tmp_path / "scene.glb"
    good.write_bytes(b"glTF")
    sequences = [{"name": "a", "seed": 0, "scene": str(good)}, {"name": "b", "seed": 1, "scene": "gone.blend"}]
    with pytest.raises(FileNotFoundError, match=r"render\.scene \(sequence 'b'\): gone\.blend does not exist"):
        render_sequences(tmp_path / "out", sequences, frames=1, resolution=(32, 16), scales=(2,))
    with pytest.raises(ValueError, match=r"render\.sequences\[0\] needs a name and a seed"):
        render_sequences(tmp_path / "out", [{"name": "a"}], frames=1)
    assert not (tmp_path / "out").exists()
