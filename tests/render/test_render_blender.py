"""Rendering with Blender for real (slow): pass conventions, AOVs, resume and determinism."""

from __future__ import annotations

import json

import numpy as np
import pytest
import torch

from tests.render.conventions import check_conventions
from wdss.data import Sequence

pytest.importorskip("bpy", reason="needs the render extra: make setup-render")
pytestmark = pytest.mark.slow

from wdss.render.sequence import render_sequence  # noqa: E402
from wdss.render.spec import CameraPath, Material, SceneSpec, Thing  # noqa: E402

SIZE = (64, 32)


def controlled_scene() -> SceneSpec:
    """A rough dielectric ground and a smooth metal sphere with constant inputs, a turning camera."""

    def material(roughness: float, metallic: float, color: list[float]) -> Material:
        return Material("checker", color, color, 4.0, [roughness, roughness], metallic, 0.2)

    sphere = Thing("uv_sphere", [0.0, 0.0, 1.0], [0.0, 0.0, 0.0], 1.0, material(0.7, 1.0, [0.9, 0.6, 0.2]))
    camera = CameraPath(6.0, 2.0, 0.3, 0.03, 0.5, 20.0, [0.0, 0.0, 0.8], 0.5, 30.0)
    return SceneSpec(7, material(0.3, 0.0, [0.5, 0.5, 0.5]), [sphere], "forest", 1.0, 0.0, [0.8, 0.0, 0.5], 3.0, camera)


@pytest.fixture(scope="module")
def rendered(tmp_path_factory):
    out = tmp_path_factory.mktemp("render")
    kwargs = dict(frames=2, resolution=SIZE, scales=(2, 4), samples=2, denoise=False, spec=controlled_scene())
    folder = render_sequence(out, "seq", 7, **kwargs)
    return folder, kwargs


def test_motion_vectors_reproject_with_the_sidecar_cameras(rendered):
    folder, _ = rendered
    seq = Sequence(folder)
    assert seq.frames == [0, 1, 2] and seq.resolutions == [32, 16, 8]
    for frame, buffers in check_conventions(folder).items():
        surface, world = buffers["surface"], buffers["world"]
        # The sky's vectors come from the camera rotation: they are not zero although Blender writes zeros.
        assert (~surface).any() and np.abs(buffers["motion"][:, ~surface]).max() > 0.01
        # Depth is planar: the ground (roughness 0.3) reconstructs onto z = 0. (Roughness is stored as half.)
        ground = surface & np.isclose(buffers["roughness"][0], 0.3, atol=1e-3)
        sphere = surface & np.isclose(buffers["roughness"][0], 0.7, atol=1e-3)
        assert ground.sum() > 100 and sphere.sum() > 20, frame
        assert np.median(np.abs(world[..., 2][ground])) < 0.02
        # AOVs carry the material inputs.
        assert (ground | sphere).sum() == surface.sum()
        assert np.all(buffers["metallic"][0][sphere] == 1.0) and np.all(buffers["metallic"][0][ground] == 0.0)
        np.testing.assert_allclose(buffers["base_color"][:, sphere].mean(1), [0.9, 0.6, 0.2], atol=1e-3)


def test_a_finished_render_is_not_rendered_again_and_a_killed_one_resumes(rendered):
    folder, kwargs = rendered
    files = sorted(folder.rglob("*.exr"))
    stamps = {p: p.stat().st_mtime_ns for p in files}
    render_sequence(folder.parent, "seq", 7, **kwargs)
    assert {p: p.stat().st_mtime_ns for p in files} == stamps
    victim = folder / "16P" / "NormalSpecular.0001.exr"  # as if the render died while writing frame 1
    victim.unlink()
    render_sequence(folder.parent, "seq", 7, **kwargs)
    changed = {p for p in files if p.stat().st_mtime_ns != stamps[p]}
    assert victim.exists() and changed and all(".0001." in p.name for p in changed)
    assert not list(folder.rglob("*.tmp"))


def test_the_same_seed_renders_the_same_frames(rendered, tmp_path):
    folder, kwargs = rendered
    again = render_sequence(tmp_path, "seq", 7, **{**kwargs, "frames": 1})
    names = ["color", "motion", "depth", "normal", "base_color", "roughness"]
    a, b = Sequence(folder).read(1, 32, names), Sequence(again).read(1, 32, names)
    for name in names[1:]:  # geometry and materials: equal up to float rounding of per-sample averages
        np.testing.assert_allclose(a[name], b[name], rtol=1e-5, atol=1e-6, err_msg=name)
    # Path-traced colour: the same samples, summed by threads in a varying order; rounding can send a rare
    # path elsewhere. Nearly every value agrees to 1e-3 and none differs by more than 2%.
    # The exposure comes from probes along each sequence's own camera path (here 1 frame against the fixture's
    # longer one): compare the radiance before it.
    exposure_a, exposure_b = (json.loads((f / "sequence.json").read_text())["exposure"] for f in (folder, again))
    ca, cb = a["color"] / np.float32(exposure_a), b["color"] / np.float32(exposure_b)
    relative = np.abs(ca - cb) / np.maximum(np.abs(cb), 1e-3)
    assert (relative < 1e-3).mean() > 0.99 and relative.max() < 0.02
    assert json.loads((folder / "sequence.json").read_text())["scene"] == controlled_scene().to_dict()


def test_other_settings_in_an_existing_folder_are_refused(rendered):
    folder, kwargs = rendered
    with pytest.raises(ValueError, match="rendered with other settings"):
        render_sequence(folder.parent, "seq", 7, **{**kwargs, "samples": 3})


def test_a_killed_render_resumes_without_redoing_frames(tmp_path):
    import json
    import os
    import signal
    import subprocess
    import sys
    import time

    from wdss.paths import PROJECT_ROOT

    script = (
        "from wdss.render.sequence import render_sequence\n"
        f"render_sequence({str(tmp_path)!r}, 'seq', 3, frames=5, resolution=(32, 16), scales=(2,), samples=1, "
        "denoise=False, objects=(10, 10))\n"
    )
    process = subprocess.Popen(
        [sys.executable, "-c", script], cwd=PROJECT_ROOT, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL
    )
    # Frame 1 is complete once the sidecar records its time (written, atomically, after all its files).
    sidecar = tmp_path / "seq" / "sequence.json"

    def frame_one_done() -> bool:
        return sidecar.exists() and "1" in json.loads(sidecar.read_text()).get("render_seconds", {})

    deadline = time.time() + 300
    while not frame_one_done():
        assert process.poll() is None and time.time() < deadline
        time.sleep(0.01)
    os.kill(process.pid, signal.SIGKILL)
    process.wait()
    done = {
        p: p.stat().st_mtime_ns for p in (tmp_path / "seq").rglob("*.exr") if ".0000." in p.name or ".0001." in p.name
    }
    assert len(done) == 20  # frames 0 and 1: 5 files (the emission too) at 2 resolutions
    render_sequence(
        tmp_path, "seq", 3, frames=5, resolution=(32, 16), scales=(2,), samples=1, denoise=False, objects=(10, 10)
    )
    assert all(p.stat().st_mtime_ns == stamp for p, stamp in done.items())  # finished frames were not redone
    assert not list((tmp_path / "seq").rglob("*.tmp"))
    seq = Sequence(tmp_path / "seq")
    assert seq.frames == [0, 1, 2, 3, 4, 5]
    for frame in seq.frames:  # every file is a complete EXR
        seq.read(frame, 16, ["color", "depth", "normal", "motion", "roughness"])


def test_the_denoiser_keeps_texture_at_the_pixel_scale():
    """A fine checker (a few pixels a check) on a lit sphere and ground, at a target's size (over 200 pixels,
    where OIDN's prefilter was once on): 8 spp denoised as datasets are rendered keeps the checker's detail that
    64 spp without denoising shows (OIDN's prefilter blurred the albedo guide, and the colour lost it)."""
    from wdss.ops.tonemap import hable
    from wdss.render.blender import BlenderScene
    from wdss.render.exposure import auto_exposure

    def material(scale: float) -> Material:
        return Material("checker", [0.8, 0.1, 0.5], [0.7, 0.6, 0.1], scale, [0.6, 0.6], 0.0, 0.0)

    sphere = Thing("uv_sphere", [0.0, 0.0, 1.0], [0.0, 0.0, 0.0], 1.0, material(60.0))
    camera = CameraPath(4.0, 1.5, 0.3, 0.0, 0.0, 20.0, [0.0, 0.0, 1.0], 0.0, 40.0)
    spec = SceneSpec(7, material(40.0), [sphere], "forest", 1.0, 0.0, [0.8, 0.0, 0.5], 3.0, camera)

    def render(samples: int, denoise: bool) -> np.ndarray:
        return BlenderScene(spec, samples=samples, denoise=denoise, filter_width=0.01).render(0, 256, 208)["Combined"]

    denoised, reference = render(8, denoise=True)[:3], render(64, denoise=False)[:3]
    exposure = auto_exposure(reference)  # as a dataset is pre-exposed: the metric's tone curve does not saturate

    def detail(color: np.ndarray) -> float:  # Laplacian energy of the tone-mapped colour
        x = hable(torch.from_numpy(color * exposure))
        lap = 4 * x[:, 1:-1, 1:-1] - x[:, :-2, 1:-1] - x[:, 2:, 1:-1] - x[:, 1:-1, :-2] - x[:, 1:-1, 2:]
        return float((lap**2).mean())

    assert detail(denoised) > 0.4 * detail(reference)  # with the prefilter: a few %


def test_a_native_render_records_its_convention_and_its_own_lr_gbuffer_guides_joint_bilateral_better(tmp_path):
    """At 2x a native LR pixel's centre falls between HR pixel centres: the HR G-buffer point-sampled there is a
    neighbour's surface, the LR frame's own G-buffer is the one its colour was shaded with."""
    from wdss.data import Collate, FrameDataset
    from wdss.data.preprocess import prediction_color
    from wdss.nets.upsamplers.joint_bilateral import joint_bilateral_upsample
    from wdss.ops.tonemap import hable
    from wdss.training.metrics import psnr

    folder = render_sequence(
        tmp_path,
        "native",
        11,
        frames=1,
        resolution=(192, 96),
        scales=(2,),
        lr_mode="native",
        samples=8,
        objects=(30, 40),
    )
    sampling = json.loads((folder / "sequence.json").read_text())["sampling"]
    assert sampling["lr"] == {"48P": {"scale": 2, "lr": "native", "jitter": None}}
    assert sampling["gbuffer"] == "point-sampled"
    keys = ["lr", "lr_guide", "gbuffer", "brdf", "target", "emission"]
    dataset = FrameDataset([Sequence(folder)], keys, scale=2.0, lr_source="native")
    batch = Collate(dataset.keys, dataset.prep, 2.0)([dataset[0]])

    def score(irradiance: torch.Tensor) -> float:
        display = hable(prediction_color(irradiance, batch), exposure=10.0).clamp(0, 1)
        return float(psnr(display, hable(batch["target"], exposure=10.0).clamp(0, 1)))

    own = score(joint_bilateral_upsample(batch["lr"], batch["gbuffer"], lr_guide=batch["lr_guide"]))
    sampled = score(joint_bilateral_upsample(batch["lr"], batch["gbuffer"]))
    assert own > sampled + 0.1, (own, sampled)  # 24.39 against 22.69 dB when written


def test_bench_noise_re_renders_the_targets_exactly_with_their_seed_and_measures_noise_with_another(rendered):
    from wdss.bench.render import bench_noise

    folder, _ = rendered

    def ceiling(noise_seed: int) -> float:
        table = bench_noise([str(folder)], [1], noise_seed, record=noise_seed == 1)
        return float(table.columns[3]._cells[0])

    same, other = ceiling(0), ceiling(1)
    assert same > 60.0  # the recorded scene spec, exposure and camera give back the stored target
    assert 10.0 < other < same - 20.0  # 2 spp without a denoiser: plainly noisy
    recorded = json.loads((folder / "sequence.json").read_text())["noise"]
    assert recorded["frames"] == [1] and abs(recorded["ceiling_psnr_db"] - other) < 0.01


def test_a_render_with_noise_ceiling_records_what_bench_noise_measures_and_keeps_it_on_resume(tmp_path):
    from wdss.bench.render import bench_noise

    kwargs = dict(frames=1, resolution=SIZE, scales=(2,), samples=2, denoise=False, spec=controlled_scene())
    folder = render_sequence(tmp_path, "seq", 7, noise_ceiling=True, **kwargs)
    recorded = json.loads((folder / "sequence.json").read_text())["noise"]
    assert recorded["frames"] == [1]  # the scored frames: frame 0 is only history
    measured = float(bench_noise([str(folder)], [1], 1, record=False).columns[3]._cells[0])
    assert 10.0 < recorded["ceiling_psnr_db"] < 60.0 and abs(recorded["ceiling_psnr_db"] - measured) < 0.01
    render_sequence(tmp_path, "seq", 7, noise_ceiling=True, **kwargs)  # resumed: measured once
    assert json.loads((folder / "sequence.json").read_text())["noise"] == recorded


def test_a_jittered_lr_render_is_shaded_at_its_pixels_plus_the_jitter_and_records_it(tmp_path):
    """At 2x, LR pixel i shaded at i + 0.5 + 0.25 lies on HR pixel 2i + 1's centre, and at i + 0.5 - 0.25 on
    2i's: the jittered LR G-buffer is then exactly the HR one point-sampled there (the lens shift's sign and unit)."""
    from wdss.render.blender import BlenderScene

    scene = BlenderScene(controlled_scene(), samples=1, denoise=False, filter_width=0.01)
    width, height = SIZE
    hr = scene.render(1, width, height)["Depth"][0]
    for jitter, first in (((0.25, 0.25), 1), ((-0.25, -0.25), 0), ((0.25, -0.25), None)):
        lr = scene.render(1, width // 2, height // 2, jitter=jitter)["Depth"][0]
        # (0.25, -0.25): x on odd HR columns, y on even rows
        expected = hr[0::2, 1::2] if first is None else hr[first::2, first::2]
        same = np.isclose(lr, expected, rtol=1e-4, atol=1e-4).mean()
        assert same > 0.99, (jitter, same)  # a silhouette pixel may flip with the filter's 0.01-pixel spread
    centred = scene.render(1, width // 2, height // 2)["Depth"][0]
    assert np.isclose(centred, hr[1::2, 1::2], rtol=1e-4, atol=1e-4).mean() < 0.9  # between HR centres: not a copy

    folder = render_sequence(
        tmp_path, "jittered", 7, frames=2, resolution=SIZE, scales=(2,), lr_mode="jittered", samples=1,
        denoise=False, spec=controlled_scene(),
    )  # fmt: skip
    meta = json.loads((folder / "sequence.json").read_text())
    assert meta["sampling"]["lr"]["16P"]["lr"] == "native" and "Halton" in meta["sampling"]["lr"]["16P"]["jitter"]
    from wdss.ops.sampling import halton_jitter

    assert [f["lr_jitter"] for f in meta["frames"]] == [list(halton_jitter(f)) for f in range(3)]
    seq = Sequence(folder)
    assert seq.lr_jitter(2) == halton_jitter(2)
