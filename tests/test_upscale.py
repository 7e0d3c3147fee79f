"""wdss.upscale: a checkpoint's model on a sequence, frames wdss reads back, metrics, resume, unreadable frames,
the comparison panels, a scale the model was not trained at."""

from __future__ import annotations

import json
import shutil

import numpy as np
import pytest
import torch
from hydra import compose, initialize_config_dir
from omegaconf import OmegaConf, open_dict
from PIL import Image

from tests.helpers import fixture_batches, tiny_checkpoint
from tests.test_train import compose_train, run_module
from wdss.data.layouts import Sequence
from wdss.data.synthetic import write_sequence
from wdss.paths import CONF_DIR, PROJECT_ROOT
from wdss.training.module import SuperResolutionModule
from wdss.upscale import UpscaleError, scale_warning, upscale

FIXTURE = PROJECT_ROOT / "tests" / "fixtures" / "rendered" / "fixture_000"


def compose_upscale(tmp_path, *overrides: str):
    with initialize_config_dir(config_dir=str(CONF_DIR / "inference"), version_base="1.3"):
        return compose("upscale", overrides=[f"paths.log_dir={tmp_path}", "video=false", *overrides])


def written(out_dir, frames) -> dict[int, np.ndarray]:
    """The colour of each frame, read back from the output folder as wdss reads a sequence."""
    sequence = Sequence(out_dir)
    return {f: sequence.read(f, sequence.hr, ["color"])["color"] for f in frames}


def test_upscale_writes_frames_that_wdss_reads_back_and_prints_the_metrics(tmp_path, capsys, tail_calls):
    ckpt = tiny_checkpoint(tmp_path / "model.ckpt", "transform=swt", "basis=haar")
    out = tmp_path / "up"
    metrics = upscale(compose_upscale(tmp_path, f"ckpt_path={ckpt}", f"input={FIXTURE}", f"output={out}"))
    assert len(tail_calls) == 5  # channels-last, image only: the SWT tail ran on cells, as engines run it
    module = SuperResolutionModule.load_from_checkpoint(ckpt, map_location="cpu", weights_only=True).eval()
    with torch.no_grad():  # the same model on the same frames through the data path (history: the input's)
        expected = {int(b["frame"][0]): module(b)["color"][0].numpy() for b in fixture_batches(module.inputs)}
    assert sorted(expected) == [0, 1, 2, 3, 4]
    for frame, colour in written(out, expected).items():
        # Folded, channels-last and its tail on cells, as against unfolded NCHW: float32 rounding apart
        np.testing.assert_allclose(colour, expected[frame], rtol=1e-5, atol=1e-6)
        assert (out / "48P" / f"PretonemapMetallic.{frame:04d}.exr").is_file() and (
            out / "png" / f"{frame:04d}.png"
        ).is_file()
    record = json.loads((out / "upscale.json").read_text())
    assert sorted(record["frames"]) == ["0", "1", "2", "3", "4"] and {"psnr", "ssim", "flip"} <= set(
        record["frames"]["2"]
    )
    assert metrics["psnr"] == pytest.approx(np.mean([v["psnr"] for v in record["frames"].values()]))
    printed = capsys.readouterr().out
    assert "frame 0002: PSNR" in printed and "overall (5 frames): PSNR" in printed


def test_a_killed_recurrent_upscale_resumes_without_redoing_finished_frames(tmp_path, capsys):
    ckpt = tiny_checkpoint(tmp_path / "model.ckpt", "variant=dfasr")  # recurrent: frame t sees its output at t - 1
    out = tmp_path / "up"
    cfg = compose_upscale(tmp_path, f"ckpt_path={ckpt}", f"input={FIXTURE}", f"output={out}")
    upscale(cfg)
    uninterrupted = written(out, range(5))
    for frame in (3, 4):  # killed during frame 3: its EXR (written last) is missing
        (out / "48P" / f"PretonemapMetallic.{frame:04d}.exr").unlink()
    (out / "png" / "0004.png").unlink()
    finished = {f: (out / "48P" / f"PretonemapMetallic.{f:04d}.exr").stat().st_mtime_ns for f in range(3)}
    capsys.readouterr()
    upscale(cfg)
    assert "3 of 5 frames already done" in capsys.readouterr().out
    assert {f: (out / "48P" / f"PretonemapMetallic.{f:04d}.exr").stat().st_mtime_ns for f in range(3)} == finished
    # Frame 3 is fed frame 2's output as read back: the result is the uninterrupted run's.
    for frame, colour in written(out, range(5)).items():
        np.testing.assert_allclose(colour, uninterrupted[frame], rtol=1e-5, atol=1e-6)
    with pytest.raises(UpscaleError, match="holds the frames of another upscale .*scale 2.0 \\(now 3.0\\)"):
        upscale(compose_upscale(tmp_path, f"ckpt_path={ckpt}", f"input={FIXTURE}", f"output={out}", "scale=3"))


def test_a_frame_that_cannot_be_read_stops_the_run_or_is_skipped_and_named(tmp_path, capsys):
    sequence = shutil.copytree(FIXTURE, tmp_path / "scene")
    broken = sequence / "48P" / "BaseColorDepth.0002.exr"
    broken.write_bytes(broken.read_bytes()[:200])  # truncated
    ckpt = tiny_checkpoint(tmp_path / "model.ckpt", "transform=dwt", "basis=haar", "temporal=none")
    args = (f"ckpt_path={ckpt}", f"input={sequence}", f"output={tmp_path / 'up'}")
    with pytest.raises(UpscaleError, match=f"frame 2 cannot be read: .*{broken}"):
        upscale(compose_upscale(tmp_path, *args))
    capsys.readouterr()
    metrics = upscale(compose_upscale(tmp_path, *args, "on_error=skip"))
    printed = capsys.readouterr()
    assert f"frame 0002 SKIPPED, it cannot be read: cannot read EXR {broken}" in printed.out
    assert "1 frame(s) SKIPPED" in printed.err and str(broken) in printed.err
    assert sorted(p.name for p in (tmp_path / "up" / "png").iterdir()) == [
        "0000.png",
        "0001.png",
        "0003.png",
        "0004.png",
    ]
    assert list(json.loads((tmp_path / "up" / "upscale.json").read_text())["skipped"]) == ["2"]
    assert "overall (4 frames)" in printed.out and np.isfinite(metrics["psnr"])


def test_an_input_without_hr_colour_is_upscaled_in_its_own_layout(tmp_path):
    """An engine's capture: HR G-buffers and LR colour only (no target), in DFASR's layout, a recurrent model."""
    sequence = write_sequence(tmp_path / "capture", layout="dfasr", size=(24, 36), scales=(2,), frames=(1, 2, 3))
    shutil.rmtree(sequence / "Nojitter-24P")  # no HR colour
    ckpt = tiny_checkpoint(tmp_path / "model.ckpt", "variant=dfasr")
    out = tmp_path / "up"
    args = (f"ckpt_path={ckpt}", f"input={sequence}", f"output={out}", "compare=true")
    metrics = upscale(compose_upscale(tmp_path, *args))
    assert metrics == {}
    colour = written(out, (1, 2, 3))
    assert (out / "Nojitter-24P" / "SyntheticPreTonemapHDRColor.0002.exr").is_file()
    assert all(c.shape == (3, 24, 36) and np.isfinite(c).all() for c in colour.values())
    # No target to show: baseline | prediction under their labels
    assert np.asarray(Image.open(out / "compare" / "0002.png")).shape == (14 + 24, 2 * 36, 3)


def test_compare_shows_the_target_and_the_error_x4_where_the_input_has_the_hr_colour(tmp_path):
    ckpt = tiny_checkpoint(tmp_path / "model.ckpt", "transform=swt", "basis=haar")
    out = tmp_path / "up"
    args = (f"ckpt_path={ckpt}", f"input={FIXTURE}", f"output={out}", "frames=[1,3]", "compare=true", "metrics=false")
    upscale(compose_upscale(tmp_path, *args))
    panel = np.asarray(Image.open(out / "compare" / "0002.png")).astype(int)
    assert panel.shape == (14 + 48, 4 * 96, 3)  # bilinear_demodulated | prediction | target | error x4, labelled
    assert all(panel[:14, i * 96 : (i + 1) * 96].max() > 200 for i in range(4))  # a label over each tile
    base, pred, target, error = (panel[14:, i * 96 : (i + 1) * 96] for i in range(4))
    assert np.array_equal(pred, np.asarray(Image.open(out / "png" / "0002.png")))  # as png/ shows it
    expected = ([s["target"] for s in fixture_batches(["target"]) if int(s["frame"][0]) == 2][0])[0]
    module = SuperResolutionModule.load_from_checkpoint(ckpt, map_location="cpu", weights_only=True)
    shown = (module.tone(expected[None], expected[None])[0].permute(1, 2, 0).numpy() * 255).round()
    assert np.abs(target - shown).max() <= 1  # the input's HR colour, tone-mapped as the metrics see it
    assert np.abs(error - np.clip(np.abs(pred - target) * 4, 0, 255)).max() <= 4  # from unrounded tiles
    assert error.max() > 0 and np.abs(base - pred).max() > 0


def test_a_scale_outside_the_trained_ones_is_warned_about_recorded_and_upscaled(tmp_path, capsys):
    """The run's scales come from its ``.hydra/config.yaml`` beside ``checkpoints/`` (``data.scale``, unresolved
    as Hydra saves it); a checkpoint outside a run folder gets no warning (its scales are unknown)."""
    run = tmp_path / "run"
    ckpt = tiny_checkpoint(run / "checkpoints" / "last.ckpt", "transform=dwt", "basis=haar", "temporal=none")
    config = compose_train(["scale=arbitrary"])
    with open_dict(config):
        del config["hydra"]
    (run / ".hydra").mkdir()
    OmegaConf.save(config, run / ".hydra" / "config.yaml")  # data.scale: ${scale.train} = [2.0, 4.0]
    args = (f"ckpt_path={ckpt}", f"input={FIXTURE}", "frames=[0,2]")
    upscale(compose_upscale(tmp_path, *args, "scale=5", f"output={tmp_path / 'up5'}"))
    warning = "scale 5x is outside the scales the model was trained at (2x to 4x): going on, expect artefacts"
    err = capsys.readouterr().err
    assert f"wdss.upscale: WARNING: {warning}" in err and err.count("WARNING") == 1
    record = json.loads((tmp_path / "up5" / "upscale.json").read_text())
    assert record["warnings"] == [warning] and sorted(record["frames"]) == ["0", "1"]
    upscale(compose_upscale(tmp_path, *args, "scale=3", f"output={tmp_path / 'up3'}"))
    assert "WARNING" not in capsys.readouterr().err
    assert json.loads((tmp_path / "up3" / "upscale.json").read_text())["warnings"] == []
    assert scale_warning(2.5, {"choices": (2.0, 3.0, 4.0)}).startswith("scale 2.5x is outside") and "2x, 3x, 4x" in (
        scale_warning(2.5, {"choices": (2.0, 3.0, 4.0)})
    )
    assert scale_warning(3.0, {"choices": (2.0, 3.0, 4.0)}) is None and scale_warning(3.0, None) is None
    assert "(2x only)" in scale_warning(4.0, 2.0) and scale_warning(2.0, 2.0) is None


@pytest.mark.slow
def test_python_m_wdss_upscale_writes_a_side_by_side_video(tmp_path):
    import av

    ckpt = tiny_checkpoint(tmp_path / "model.ckpt", "transform=swt", "basis=haar")
    args = (f"ckpt_path={ckpt}", f"input={FIXTURE}", "scale=2", "compare=true", f"paths.log_dir={tmp_path}")
    done = run_module(tmp_path, "wdss.upscale", *args)
    assert done.returncode == 0, done.stderr[-3000:]
    out = tmp_path / "upscale" / "fixture_000_2x"  # the default output folder
    assert "overall (5 frames): PSNR" in done.stdout
    with av.open(str(out / "fixture_000_2x.mp4")) as video:
        frames = [frame.to_ndarray(format="rgb24") for frame in video.decode(video=0)]
    assert len(frames) == 5 * 18 and frames[0].shape[1] == 4 * 96  # 5 frames looped to 3 s; baseline | ... | error


@pytest.mark.parametrize(
    "overrides",
    [("transform=swt", "basis=haar"), ("variant=dfasr",), ("experiment=cpu", "transform=swt", "recipe.exit_init=1.0")],
)
def test_upscale_in_bfloat16_stays_close_to_float32_and_keeps_its_own_folder(tmp_path, overrides):
    """The network under bfloat16 autocast (a recurrent one fed its own output back; the default CPU recipe with its
    learned kernel, which computes in float32; its exit initialised, so that the network adds to the kernel from the
    start), metrics and files in float32."""
    ckpt = tiny_checkpoint(tmp_path / "model.ckpt", *overrides)
    args = (f"ckpt_path={ckpt}", f"input={FIXTURE}")
    upscale(compose_upscale(tmp_path, *args, f"output={tmp_path / 'fp32'}"))
    metrics = upscale(compose_upscale(tmp_path, *args, f"output={tmp_path / 'bf16'}", "precision=bfloat16"))
    full, reduced = written(tmp_path / "fp32", range(5)), written(tmp_path / "bf16", range(5))
    for frame in range(5):
        assert reduced[frame].dtype == np.float32
        error = np.abs(reduced[frame] - full[frame]).max() / np.abs(full[frame]).max()
        assert 0 < error <= 3e-2  # bfloat16 keeps 8 bits of mantissa
    assert np.isfinite(metrics["psnr"])
    with pytest.raises(
        UpscaleError, match="holds the frames of another upscale .*precision 'bfloat16' \\(now 'float32'\\)"
    ):
        upscale(compose_upscale(tmp_path, *args, f"output={tmp_path / 'bf16'}"))
    with pytest.raises(UpscaleError, match="precision must be one of float32, bfloat16, float16, got 'half'"):
        upscale(compose_upscale(tmp_path, *args, "precision=half"))


def test_an_output_folder_that_is_holds_or_lies_inside_the_input_is_refused_and_the_input_kept(tmp_path):
    """output=<the input> would overwrite its ground-truth frames: refused before anything is written."""
    ckpt = tiny_checkpoint(tmp_path / "model.ckpt", "transform=swt", "basis=haar")
    source = tmp_path / "shots" / "fixture_000"
    shutil.copytree(FIXTURE, source)
    before = {p: p.read_bytes() for p in source.rglob("*") if p.is_file()}
    for output in (source, source / "up", tmp_path / "shots"):
        with pytest.raises(UpscaleError, match=r"is, holds or lies inside the input .*choose another output="):
            upscale(compose_upscale(tmp_path, f"ckpt_path={ckpt}", f"input={source}", f"output={output}"))
    assert {p: p.read_bytes() for p in source.rglob("*") if p.is_file()} == before
    foreign = tmp_path / "mine"
    foreign.mkdir()
    (foreign / "notes.txt").write_text("keep")
    with pytest.raises(UpscaleError, match=r"holds files but no upscale.json: it is not an upscale folder"):
        upscale(compose_upscale(tmp_path, f"ckpt_path={ckpt}", f"input={source}", f"output={foreign}"))
    assert [p.name for p in foreign.iterdir()] == ["notes.txt"]


def test_a_rerun_with_other_preprocessing_is_refused_rather_than_mixed_into_the_folder(tmp_path):
    ckpt = tiny_checkpoint(tmp_path / "model.ckpt", "transform=swt", "basis=haar")
    args = (f"ckpt_path={ckpt}", f"input={FIXTURE}", f"output={tmp_path / 'up'}", "frames=[0,2]")
    upscale(compose_upscale(tmp_path, *args))
    upscale(compose_upscale(tmp_path, *args))  # the same again: resumes, nothing to do
    with pytest.raises(UpscaleError, match=r"holds the frames of another upscale \(preprocessing "):
        upscale(compose_upscale(tmp_path, *args, "+preprocessing.color_max=4.0"))


def test_the_trained_scales_are_read_from_the_run_folder_resolving_nothing(tmp_path):
    from wdss.checkpoint import CheckpointError
    from wdss.data.dataset import parse_scale
    from wdss.upscale import trained_scales

    ckpt = tmp_path / "run" / "checkpoints" / "last.ckpt"
    ckpt.parent.mkdir(parents=True)
    config = tmp_path / "run" / ".hydra" / "config.yaml"
    config.parent.mkdir()
    config.write_text("scale:\n  train: {choices: [2, 3]}\ndata:\n  scale: ${scale.train}\n")
    assert trained_scales(ckpt) == parse_scale({"choices": [2, 3]})  # wdss's own interpolation, followed by hand
    config.write_text("scale:\n  train: ${oc.env:HOME}\ndata:\n  scale: ${scale.train}\n")
    with pytest.raises(CheckpointError, match=r"config.yaml \(the run of checkpoint .*\): data.scale=\$\{oc.env"):
        trained_scales(ckpt)
    config.write_text('data:\n  scale: "${oc.create:{_target_: pathlib.Path.touch, self: x}}"\n')
    with pytest.raises(CheckpointError, match=r"data.scale=\$\{oc.create"):
        trained_scales(ckpt)
