"""Blender passes -> Unreal-layout buffers, and the committed rendered fixture (no Blender needed)."""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import pytest
import torch

from tests.render.conventions import load_sidecar, reproject
from wdss.data import BATCH_KEYS, SceneDataModule, Sequence
from wdss.render.convert import background_motion, to_buffers
from wdss.render.spec import intrinsics, random_scene

FIXTURE = Path(__file__).resolve().parents[1] / "fixtures" / "rendered"


def yaw(angle: float) -> np.ndarray:
    pose = np.eye(4)
    pose[:3, :3] = [[math.cos(angle), 0, math.sin(angle)], [0, 1, 0], [-math.sin(angle), 0, math.cos(angle)]]
    return pose


def test_background_motion_of_a_pure_turn():
    """Turning the camera left by phi moves directions at infinity right: the centre by fx tan(phi)."""
    width, height, lens = 64, 32, 30.0
    fx = intrinsics(lens, width, height)[0]
    phi = math.radians(2.0)
    # A camera yawed by +phi about world y (its up axis) looks further left than the previous one.
    motion = background_motion(yaw(phi), yaw(0.0), lens, width, height)
    assert motion.shape == (2, height, width)
    centre = motion[:, height // 2, width // 2]
    assert centre[0] == pytest.approx(fx * math.tan(phi), rel=0.02)  # half a pixel off-centre: 2% slack
    assert abs(centre[1]) < 0.05 * abs(centre[0])
    assert np.all(motion[0] > 0)


def test_to_buffers_conventions():
    height, width = 4, 6
    depth = np.full((1, height, width), 5.0)
    depth[0, 0, :] = 1e10  # background row
    passes = {
        "Combined": np.random.rand(4, height, width),
        "Depth": depth,
        "Normal": np.tile(np.array([0.0, 0.0, 1.0]).reshape(3, 1, 1), (1, height, width)),
        "Vector": np.tile(np.array([1.5, -2.0, 0.0, 0.0]).reshape(4, 1, 1), (1, height, width)),
        "Position": np.zeros((3, height, width)),
        "basecolor": np.full((4, height, width), 0.4),
        "roughness": np.full((1, height, width), 0.3),
        "metallic": np.ones((1, height, width)),
        "Emission": np.full((4, height, width), 2.0),
    }
    camera = np.eye(4)
    camera[:3, 3] = [0, 0, 10]  # camera above the origin, looking down -z at the surface point (0, 0, 0)
    out = to_buffers(passes, camera=camera, previous_camera=None, lens=30.0, motion_scale=2.0)
    assert all(v.dtype == np.float32 for v in out.values())
    assert out["depth"][0, 0].tolist() == [0.0] * width and out["depth"][0, 1, 0] == 5.0
    assert out["specular"][0, 0].max() == 0 and out["specular"][0, 1:].min() == 0.5
    assert out["base_color"][:, 0].max() == 0 and out["normal"][:, 0].max() == 0
    np.testing.assert_allclose(out["motion"][:, 1:], np.tile(np.array([-3.0, 4.0]).reshape(2, 1, 1), (1, 3, width)))
    np.testing.assert_allclose(out["nov"][0, 1:], 1.0)
    assert out["emission"].shape == (3, height, width)  # RGB of the RGBA pass; none on the background (the sky)
    assert out["emission"][:, 0].max() == 0 and out["emission"][:, 1:].min() == 2.0


def test_fixture_is_small_and_complete():
    size = sum(p.stat().st_size for p in FIXTURE.rglob("*") if p.is_file())
    assert size < 2 * 2**20
    seq = Sequence(FIXTURE / "fixture_000")
    assert seq.resolutions == [48, 24, 16, 12] and seq.frames == [0, 1, 2, 3, 4]


def test_fixture_motion_vectors_agree_with_the_cameras():
    """Reprojecting planar depth with the sidecar cameras reproduces the stored motion (static geometry)."""
    folder = FIXTURE / "fixture_000"
    meta, cameras = load_sidecar(folder)
    seq = Sequence(folder)
    spec = random_scene(meta["seed"], min_objects=10, max_objects=14)
    assert meta["scene"] == spec.to_dict()  # the sidecar describes the scene of the seed
    for frame in (1, 2):
        buffers = seq.read(frame, 48, ["depth", "motion", "normal"])
        depth = buffers["depth"][0].astype(np.float64)
        surface = depth > 0
        _, expected = reproject(depth, cameras[frame], cameras[frame - 1], meta["intrinsics"]["fx_fy_cx_cy"])
        error = np.hypot(*(buffers["motion"] - expected))[surface]
        assert np.median(error) < 0.05, np.median(error)
        lengths = np.linalg.norm(buffers["normal"], axis=0)[surface]
        np.testing.assert_allclose(lengths, 1.0, atol=2e-3)


def test_the_data_module_reads_the_rendered_fixture():
    dm = SceneDataModule(
        FIXTURE,
        {"train": ["fixture_000"], "test": ["fixture_000"]},
        BATCH_KEYS,
        patch_size=24,
        batch_size=2,
        flips=True,
        test_scales=[2.0, 4.0],
    )
    dm.setup("fit")
    batch = next(iter(dm.train_dataloader()))
    assert batch["target"].shape == (2, 3, 24, 24)
    dm.setup("test")
    for loader, size in zip(dm.test_dataloader(), ((24, 48), (12, 24)), strict=True):
        batch = next(iter(loader))
        assert batch["lr"].shape[-2:] == size
        for key in BATCH_KEYS:
            assert torch.isfinite(batch[key]).all(), key


def test_render_sequences_lets_a_sequence_override_shared_settings(monkeypatch, tmp_path):
    import wdss.render.sequence as sequence

    calls = []
    monkeypatch.setattr(sequence, "render_sequence", lambda out, name, seed, **kw: calls.append((name, seed, kw)))
    sequence.render_sequences(tmp_path, [{"name": "a", "seed": 1}, {"name": "b", "seed": 2, "frames": 5}], frames=9)
    assert [(name, seed, kw["frames"]) for name, seed, kw in calls] == [("a", 1, 9), ("b", 2, 5)]


def test_rendering_without_bpy_says_which_command_installs_it(monkeypatch):
    import importlib
    import sys

    monkeypatch.setitem(sys.modules, "bpy", None)  # as if the render extra were not installed
    monkeypatch.delitem(sys.modules, "wdss.render.blender", raising=False)
    with pytest.raises(ImportError, match="make setup-render"):
        importlib.import_module("wdss.render.blender")
