"""wdss.export: the ONNX graph of a checkpoint's model matches torch on onnxruntime (CPU), with its input layout."""

from __future__ import annotations

import json

import numpy as np
import onnx
import pytest
import torch
from hydra import compose, initialize_config_dir
from onnx import numpy_helper

from tests.helpers import fixture_batches, tiny_checkpoint
from tests.test_train import run_module
from wdss.export import MOTION_VECTORS, ExportError, export, relative_error, run_onnx
from wdss.paths import CONF_DIR
from wdss.training.module import SuperResolutionModule

CONFIGS = {
    "none": ["transform=none"],
    "dwt": ["transform=dwt", "basis=haar"],
    "swt_rir": ["transform=swt", "basis=db4", "model.net.gbuffer_block=rir"],
    "fusion_ll": ["variant=fusion_ll"],
    "dfasr": ["variant=dfasr"],
    "learned_bilateral": ["transform=swt", "basis=db4", "residual=learned_bilateral", "recipe.output_space=log"],
    "learned_bilateral_tap_brdf": [
        "transform=swt", "basis=db4", "residual=learned_bilateral", "recipe.output_space=log",
        "recipe.tap_brdf=true",
    ],
}  # fmt: skip


def compose_export(tmp_path, *overrides: str):
    with initialize_config_dir(config_dir=str(CONF_DIR / "inference"), version_base="1.3"):
        return compose("export", overrides=[f"paths.log_dir={tmp_path}", *overrides])


def torch_colour(module: SuperResolutionModule, batches: list[dict]) -> tuple[dict, torch.Tensor]:
    """The last batch as the graph takes it (a recurrent model's history: its output of the frame before, warped)
    and the module's colour on it."""
    previous = None
    with torch.no_grad():
        for batch in batches:
            if module.temporal == "recurrent":
                batch = module._with_history(batch, previous)
            out = module(batch)
            previous = out["irradiance"]
    return batch, out["color"]


def check_parity(path, module: SuperResolutionModule, batches: list[dict], tolerance: float = 1e-4) -> float:
    batch, reference = torch_colour(module, batches)
    assert (reference > 0).float().mean() > 0.1  # a random network whose output is not all clamped to zero
    session_inputs = json.loads(path.with_suffix(".json").read_text())["inputs"]
    outputs = run_onnx(path, {i["name"]: batch[i["name"]].numpy() for i in session_inputs})
    error = relative_error(outputs["color"], reference.numpy())
    assert error <= tolerance, error
    return error


def initializers(path) -> list[np.ndarray]:
    return [numpy_helper.to_array(i) for i in onnx.load(path).graph.initializer]


def check_constants(path, module: SuperResolutionModule, height: int, width: int) -> None:
    """No float64 constant (engines do not run float64) and none larger than the frame's longer side but the
    weights: grids are stored per axis and expanded in the graph, never per pixel."""
    arrays = initializers(path)
    assert not [a.shape for a in arrays if a.dtype == np.float64]
    largest = max(max(p.numel() for p in module.parameters()), height, width)
    assert max(a.size for a in arrays) <= largest


def perturb_kernel(ckpt) -> None:
    """The learned kernel's last layer starts at zero (joint bilateral exactly): give it values, so that parity also
    covers its logit corrections and BRDF exponents."""
    state = torch.load(ckpt, weights_only=True)
    weights = state["state_dict"]
    g = torch.Generator().manual_seed(0)
    weights["net.upsampler.mlp.4.weight"] = 0.5 * torch.randn(weights["net.upsampler.mlp.4.weight"].shape, generator=g)
    weights["net.upsampler.mlp.4.bias"] = torch.full_like(weights["net.upsampler.mlp.4.bias"], 0.5)
    torch.save(state, ckpt)


@pytest.mark.parametrize("name", CONFIGS)
def test_onnx_graph_matches_torch_on_a_fixture_frame(name, tmp_path):
    ckpt = tiny_checkpoint(tmp_path / "model.ckpt", *CONFIGS[name])
    if name.startswith("learned_bilateral"):
        perturb_kernel(ckpt)
    path = export(compose_export(tmp_path, f"ckpt_path={ckpt}", "height=48", "width=96", "scale=2"))
    assert path == tmp_path / "model_96x48_2x.onnx"
    module = SuperResolutionModule.load_from_checkpoint(ckpt, map_location="cpu", weights_only=True).eval()
    check_parity(path, module, fixture_batches(module.inputs)[:2])
    graph = onnx.load(path)
    assert graph.opset_import[0].version >= 17
    names = {i.name for i in graph.graph.initializer}
    layout = json.loads(path.with_suffix(".json").read_text())
    # In the order of the network's forward; the BRDF factor last where the network does not take it.
    expected = ["lr", "gbuffer", "spatial_mask", "scale", "history", "temporal_mask"]
    if name == "learned_bilateral":  # the kernel's guide: the G-buffer the LR was shaded with
        expected += ["lr_guide", "brdf"]
    elif name == "learned_bilateral_tap_brdf":  # and the F the LR was demodulated with
        expected += ["brdf", "lr_brdf", "lr_guide"]
    else:
        expected += ["brdf"]
    assert [i.name for i in graph.graph.input] == [i["name"] for i in layout["inputs"]] == expected
    assert [o.name for o in graph.graph.output] == ["color", "irradiance"]
    assert layout["lr_sampling"].startswith("LR pixels shaded at their centres")  # no lr_jitter input (above)
    assert layout["inputs"][1]["channels"][:4] == ["base_color.r", "base_color.g", "base_color.b", "depth"]
    assert layout["history"].startswith("recurrent" if name == "dfasr" else "the previous HR frame")
    # No frame-sized constant (an exporter folds in-place padding into one): weights are the largest tensors.
    largest = max(p.numel() for p in module.parameters())
    assert max(int(np.prod(i.dims)) for i in graph.graph.initializer) <= largest
    check_constants(path, module, 48, 96)
    # What an engine needs frame after frame, beside the channels.
    prep = layout["preprocessing"]
    assert prep["depth"].startswith("planar camera depth (scene units); depth > 100") and "max(hi, 1)" in prep["depth"]
    assert prep["spatial_mask"].startswith("1 where |depth - up(depth_lr)| > 0.01 or n . normalize(up(n_lr)) < 0.9")
    assert "LR frame's own" in prep["lr_brdf"]
    assert "median Rec. 709 luminance of lit pixels to 0.18" in layout["exposure"]
    assert layout["motion_vectors"] == MOTION_VECTORS and MOTION_VECTORS["units"] == "HR pixels"
    temporal = layout["temporal"]
    assert temporal["trained_with"] == ("recurrent" if name == "dfasr" else "gt_history")
    assert temporal["first_frame"]["history"].startswith("lr upsampled bilinearly")
    if name != "dfasr":
        assert temporal["training_history"].startswith("the ground-truth history")
    if name == "swt_rir":  # the RIR blocks run folded: one 3x3 convolution each, no expansion or reduction
        assert any(".fused.weight" in n for n in names) and not any(".expand." in n for n in names)
        assert layout["rir_folded"]


def test_a_fixed_size_graph_computes_its_per_pixel_grids_at_384x216(tmp_path):
    """Issue 41: a fixed 384x216 graph stored the joint-bilateral kernels' tent weights per pixel, in float64 (39 MB
    for 0.18 M parameters; the constant folder's size limit spared 1080p's)."""
    ckpt = tiny_checkpoint(tmp_path / "model.ckpt", *CONFIGS["learned_bilateral_tap_brdf"])
    perturb_kernel(ckpt)
    path = export(compose_export(tmp_path, f"ckpt_path={ckpt}", "height=216", "width=384", "scale=2"))  # verified
    module = SuperResolutionModule.load_from_checkpoint(ckpt, map_location="cpu", weights_only=True)
    check_constants(path, module, 216, 384)
    assert path.stat().st_size < 10e6, path.stat().st_size


@pytest.mark.slow
def test_a_fixed_size_graph_at_1080p_stores_no_float64_and_stays_small(tmp_path):
    ckpt = tiny_checkpoint(tmp_path / "model.ckpt", *CONFIGS["learned_bilateral_tap_brdf"])
    path = export(compose_export(tmp_path, f"ckpt_path={ckpt}", "height=1080", "width=1920", "scale=2"))
    module = SuperResolutionModule.load_from_checkpoint(ckpt, map_location="cpu", weights_only=True)
    check_constants(path, module, 1080, 1920)
    assert path.stat().st_size < 10e6, path.stat().st_size


def test_dynamic_export_takes_other_even_sizes_and_the_training_preprocessing(tmp_path):
    run = tmp_path / "run"
    (run / ".hydra").mkdir(parents=True)
    (run / ".hydra" / "config.yaml").write_text("data:\n  preprocessing:\n    color_max: 10.0\n    depth_far: 50.0\n")
    ckpt = tiny_checkpoint(run / "checkpoints" / "last.ckpt", "transform=swt", "basis=haar")
    path = export(compose_export(tmp_path, f"ckpt_path={ckpt}", "height=32", "width=64", "dynamic=true"))
    module = SuperResolutionModule.load_from_checkpoint(ckpt, map_location="cpu", weights_only=True).eval()
    for scale in (2.0, 4.0):  # LR 24x48 (a native folder) and 12x24 (point-sampled), HR 48x96: not the traced size
        check_parity(path, module, fixture_batches(module.inputs, scale)[:1])
    check_constants(path, module, 32, 64)
    layout = json.loads(path.with_suffix(".json").read_text())
    assert layout["size"]["dynamic"] and layout["inputs"][0]["shape"] == [1, 3, "2*half_lr_height", "2*half_lr_width"]
    assert layout["preprocessing"]["color_max"] == 10.0 and layout["preprocessing"]["depth_far"] == 50.0
    assert layout["preprocessing"]["brdf_knee"] == 0.0  # a run from before the knee: the hard switch it trained with
    assert layout["preprocessing"]["depth"].startswith("planar camera depth (scene units); depth > 50")


def test_fp16_export_stays_close_to_float32_torch(tmp_path):
    ckpt = tiny_checkpoint(tmp_path / "model.ckpt", "transform=dwt", "basis=haar")
    path = export(compose_export(tmp_path, f"ckpt_path={ckpt}", "height=48", "width=96", "fp16=true"))
    assert path.name == "model_96x48_2x_fp16.onnx"
    module = SuperResolutionModule.load_from_checkpoint(ckpt, map_location="cpu", weights_only=True).eval()
    batch, reference = torch_colour(module, fixture_batches(module.inputs)[:1])
    inputs = {k: v.half().numpy() for k, v in batch.items() if isinstance(v, torch.Tensor)}
    assert relative_error(run_onnx(path, inputs)["color"], reference.numpy()) <= 1e-2


def test_export_refuses_an_opset_below_17_and_other_formats(tmp_path):
    ckpt = tiny_checkpoint(tmp_path / "model.ckpt", "transform=none")
    with pytest.raises(ExportError, match="opset must be >= 17"):
        export(compose_export(tmp_path, f"ckpt_path={ckpt}", "height=48", "width=96", "opset=16"))
    with pytest.raises(ExportError, match="format must be onnx"):
        export(compose_export(tmp_path, f"ckpt_path={ckpt}", "format=tensorrt"))


@pytest.mark.slow
def test_python_m_wdss_export_writes_graph_and_layout_and_checks_them(tmp_path):
    ckpt = tiny_checkpoint(tmp_path / "model.ckpt", "variant=dfasr")
    args = (f"ckpt_path={ckpt}", "height=48", "width=96", f"paths.log_dir={tmp_path}")
    done = run_module(tmp_path, "wdss.export", *args)
    assert done.returncode == 0, done.stderr[-3000:]
    assert (tmp_path / "model_96x48_2x.onnx").is_file() and (tmp_path / "model_96x48_2x.json").is_file()
    assert "onnxruntime (CPU) vs torch on the example inputs" in done.stdout


@pytest.mark.parametrize(
    ("overrides", "message"),
    [
        (("height=-216", "width=384"), "height and width must be positive, got height=-216 width=384"),
        (("scale=0.5",), "scale must be at least 1, got 0.5"),
        (("dynamic=true", "height=216", "width=384", "scale=3"), "has an LR frame of 128x72"),  # even: passes this
        (
            ("dynamic=true", "height=218", "width=384", "scale=2"),
            r"an LR frame of 192x109; choose another example size",
        ),
        (("dynamic=true", "height=24", "width=48", "scale=2"), "at least 16: height=24 width=48"),
    ],
)
def test_a_size_the_graph_cannot_be_traced_at_is_refused_in_one_line_before_anything_is_read(
    tmp_path, overrides, message
):
    cfg = compose_export(tmp_path, f"ckpt_path={tmp_path / 'absent.ckpt'}", *overrides)
    if "128x72" in message:  # an even LR of 128x72 at 3x: the size check passes, the missing checkpoint is next
        with pytest.raises(Exception, match="absent.ckpt"):
            export(cfg)
        return
    with pytest.raises(ExportError, match=message):
        export(cfg)
