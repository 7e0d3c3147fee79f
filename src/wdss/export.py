"""Export entry point: ``python -m wdss.export ckpt_path=PATH [format=onnx] [height=1080 width=1920 scale=2]
[dynamic=true] [fp16=true]``.

Writes the model a checkpoint holds as one ONNX graph (opset >= 17) for an engine: the whole network, wavelet
synthesis included, with its RIR blocks folded into their 3x3 convolutions first, and the remodulation by the BRDF
factor, so that the graph maps the inputs an engine can compute to the HR colour. Inputs are named by their batch
keys (:mod:`wdss.data.batch`), ``scale`` among them; outputs are ``color`` (linear HDR) and ``irradiance``
(the demodulated prediction, which a recurrent model feeds back). Beside it, ``<name>.json`` describes the input
layout an engine must feed: channels and their order, resolution, demodulation, what the graph applies itself
(log1p), the radiance's exposure, the motion vectors' convention and, for a temporal model, how to make its history
frame after frame (the first frame's included) and what it was trained on. onnxruntime then checks the graph
against torch on the example inputs. The graph stores no float64 constant and none larger than the frame's longer
side: per-pixel ones are computed in it (:func:`fold_constants`).
"""

from __future__ import annotations

import copy
import inspect
import json
import logging
from pathlib import Path
from typing import Any

import numpy as np
import torch
from omegaconf import DictConfig, OmegaConf
from torch import Tensor, nn

from wdss.checkpoint import read_checkpoint, training_preprocessing
from wdss.data.batch import GBUFFER_STACK, LR_GEOMETRY, LR_GUIDE
from wdss.data.dataset import Preprocessing
from wdss.errors import UserError, entry_point
from wdss.nets.blocks import RIRBlock, fold_rir_blocks
from wdss.nets.profile import dummy_inputs
from wdss.ops.sampling import lr_size, point_sample
from wdss.ops.tonemap import MIDDLE_GREY
from wdss.paths import CONF_DIR
from wdss.training.module import SuperResolutionModule

__all__ = ["ExportError", "InferenceGraph", "export", "export_onnx", "fold_constants", "input_layout", "main"]

MIN_OPSET = 17
OUTPUTS = ("color", "irradiance")
# Most a graph may differ from torch on the example inputs (max |difference| / max |torch output|).
TOLERANCE = {"float32": 1e-4, "float16": 1e-2}

_RGB = ("r", "g", "b")
_XYZ = ("x", "y", "z")


def _channels(buffer: str) -> list[str]:
    names = {"base_color": _RGB, "normal": _XYZ, "motion": ("x", "y")}.get(buffer)
    return [f"{buffer}.{c}" for c in names] if names else [buffer]


# Engine-facing description of every batch key a graph may take: resolution (high or low), channels in order,
# meaning. The one contract between data and model (wdss.data.batch), written out for another renderer.
CHANNELS: dict[str, tuple[str, list[str], str]] = {
    "lr": (
        "low",
        list(_RGB),
        "max(LR colour - LR emission, 0) / lr_brdf when demodulated (emission where separated), else the LR colour;"
        " see preprocessing",
    ),
    "lr_color": ("low", list(_RGB), "LR colour"),
    "lr_brdf": ("low", list(_RGB), "the BRDF factor lr was divided by: see preprocessing.lr_brdf"),
    "lr_guide": (
        "low",
        [c for b in LR_GUIDE for c in _channels(b)],
        "the G-buffer the LR colour was shaded with (the LR frame's own; preprocessed as the HR stack's channels)",
    ),
    "brdf": (
        "high",
        list(_RGB),
        "HR BRDF factor (wdss.ops.brdf.safe_brdf of F at preprocessing.brdf_knee): color = irradiance * brdf",
    ),
    "gbuffer": ("high", [c for b in GBUFFER_STACK for c in _channels(b)], "HR G-buffer stack"),
    "spatial_mask": (
        "high",
        ["mask"],
        "1 where the HR G-buffer differs from the bilinearly upsampled LR one: see preprocessing.spatial_mask",
    ),
    "history": ("high", list(_RGB), "previous irradiance, warped to this frame by the motion vectors"),
    "temporal_mask": (
        "high",
        ["depth_difference", "albedo_difference.r", "albedo_difference.g", "albedo_difference.b", "normal_term"],
        "|depth - warped previous depth|, |albedo - warped previous albedo|, (1 - n . n_previous) / 2: see "
        "temporal.temporal_mask",
    ),
    "motion": ("high", ["motion.x", "motion.y"], "HR pixels, current minus previous position, y up"),
    "lr_gbuffer": ("low", [c for b in LR_GEOMETRY for c in _channels(b)], "LR depth and normal"),
    "prev_lr_color": ("low", list(_RGB), "the previous frame's LR colour"),
    "prev_lr_gbuffer": (
        "low",
        [c for b in LR_GEOMETRY for c in _channels(b)],
        "the previous frame's LR depth and normal",
    ),
    "history2": ("high", list(_RGB), "irradiance of frame t-2 warped to t through t-1"),
}


# Motion vectors as wdss's data holds them (wdss.ops.warp, wdss.render.convert) and every history is warped with.
MOTION_VECTORS = {
    "units": "HR pixels",
    "sign": "current minus previous screen position (x right, y up)",
    "warp": (
        "the pixel at column x, row y (rows down) of this frame was at column x - mv.x, row y + mv.y of the previous "
        "frame: wdss.ops.warp.warp_backward samples the previous frame there, bilinearly at pixel centres "
        "(grid_sample, align_corners=False), zeros outside the frame"
    ),
}


def _depth_rule(prep: Preprocessing) -> str:
    """How a depth channel is preprocessed (wdss.data.preprocess.clean)."""
    far = f"depth > {prep.depth_far:g} set to 0 (background), then " if prep.depth_far is not None else ""
    if not prep.depth_normalize:
        return f"planar camera depth as rendered ({far.removesuffix(', then ') or 'unchanged'})"
    return (
        f"planar camera depth (scene units); {far}d' = (d - lo) / (1e-6 + max(hi, 1) - lo), (lo, hi) the min "
        "and max of the whole HR frame's depth after that step; an LR depth (lr_guide, lr_gbuffer) takes its HR "
        "frame's (lo, hi), a previous frame's depth (temporal_mask) its own frame's"
    )


def _temporal(module: SuperResolutionModule, graph: InferenceGraph, prep: Preprocessing) -> dict[str, Any] | None:
    """How a temporal graph is fed frame after frame, and what its history was in training."""
    if "history" not in graph.inputs:
        return None
    trained = {
        "gt_history": (
            "the ground-truth history (temporal=gt_history): the reference HR frame t-1's irradiance, "
            + ("max(colour - emission, 0) / its own brdf" if prep.demodulate else "its colour")
            + ", warped; the model never saw its own output as history in training, which is all an engine has"
        ),
        "recurrent": (
            "its own previous irradiance output, warped, over sequences of frames (temporal=recurrent), as an "
            "engine runs it"
        ),
    }[module.temporal]
    return {
        "trained_with": module.temporal,
        "training_history": trained,
        "feed": (
            "history = this graph's irradiance output of frame t-1, warped to frame t by frame t's motion vectors "
            "(as wdss.upscale feeds any temporal model on frames without HR colour)"
        ),
        "first_frame": {
            "history": "lr upsampled bilinearly to the HR size (align_corners=False), as wdss.upscale starts",
            "temporal_mask": (
                "against an all-zero previous G-buffer: |depth|, |albedo| and 0.5 (the previous frame of "
                "wdss.upscale's first frame)"
            ),
        },
        "temporal_mask": (
            "the previous frame's depth, albedo and normal warped as its irradiance (bilinear, zeros outside, "
            "normals renormalised: zero stays zero, a normal term of 0.5), compared with this frame's: "
            "|depth - depth'|, |albedo - albedo'| per channel, (1 - n . n') / 2 (wdss.ops.warp.temporal_mask)"
        ),
    }


class ExportError(UserError, RuntimeError):
    """A model that cannot be exported as asked, or a graph that does not match torch."""


class InferenceGraph(nn.Module):
    """The module's inference path as one traceable function: the network on the inputs it names, then the
    remodulation (``SuperResolutionModule.forward``). ``inputs`` is a dict of batch tensors by key."""

    def __init__(self, net: nn.Module) -> None:
        super().__init__()
        self.net = net
        self.net_args = tuple(inspect.signature(net.forward).parameters)

    @property
    def inputs(self) -> tuple[str, ...]:
        """The graph's input names, in the order of the network's forward, the BRDF factor last. A graph takes LR
        frames shaded at their pixel centres: ``lr_jitter`` is not among them (its path is a per-sample gather)."""
        wanted = (set(self.net.inputs) - {"lr_jitter"}) | {"scale"}
        names = [k for k in self.net_args if k in wanted]
        return (*names, "brdf") if "brdf" not in names else tuple(names)

    def forward(self, inputs: dict[str, Tensor]) -> tuple[Tensor, Tensor]:
        # Only the image: a network that can skip its subbands (WDSSNet) then takes its faster tail.
        image_only = {"subbands": False} if "subbands" in self.net_args else {}
        irradiance = self.net(**{k: inputs[k] for k in self.net_args if k in inputs}, **image_only)["irradiance"]
        return irradiance * inputs["brdf"], irradiance


def example_inputs(graph: InferenceGraph, height: int, width: int, scale: float) -> dict[str, Tensor]:
    """Random inputs of every graph input at an ``height x width`` output and ``scale`` (positive values)."""
    inputs = dummy_inputs(graph.net, height, width, scale)
    inputs["brdf"] = 0.2 + 0.8 * torch.rand(1, 3, height, width)
    if "lr_brdf" in inputs:  # the F the LR was demodulated with: the HR one at the LR pixels, as in point-sampled data
        inputs["lr_brdf"] = point_sample(inputs["brdf"], inputs["lr_brdf"].shape[-2:])
    return {k: inputs[k] for k in graph.inputs}


def _dynamic_shapes(graph: InferenceGraph) -> dict:
    """Dynamic height and width of every image input, each a multiple of 2 (HR and LR apart). The network pads odd
    sizes by branching on their parity; a graph holds one branch, the even one, which torch.export then keeps."""
    from torch.export import Dim

    dims = {
        "high": {2: 2 * Dim("half_height", min=8), 3: 2 * Dim("half_width", min=8)},
        "low": {2: 2 * Dim("half_lr_height", min=8), 3: 2 * Dim("half_lr_width", min=8)},
    }
    return {"inputs": {k: None if k == "scale" else dims[CHANNELS[k][0]] for k in graph.inputs}}


def export_onnx(
    module: SuperResolutionModule,
    path: str | Path,
    *,
    height: int,
    width: int,
    scale: float,
    dynamic: bool = False,
    fp16: bool = False,
    opset: int = 18,
) -> tuple[InferenceGraph, dict[str, Tensor], Tensor]:
    """Write ``module``'s inference graph to ``path`` (RIR blocks folded); return the graph, the example inputs it
    was traced with and torch's float32 ``color`` on them."""
    if opset < MIN_OPSET:
        raise ExportError(f"opset must be >= {MIN_OPSET}, got {opset}")
    for name in ("onnxscript", "onnx_ir"):  # their optimiser logs every pass at INFO, which Hydra's logging shows
        logging.getLogger(name).setLevel(logging.WARNING)
    # torch.onnx warns that torchvision's operators are not registered: wdss uses none of them
    logging.getLogger("torch.onnx._internal.exporter._registration").setLevel(logging.ERROR)
    net = module.net.eval()
    if net.fixed_scale and float(scale) != float(net.scale):
        raise ExportError(f"this {net.__class__.__name__} upsamples by {net.scale} only, not by {scale}")
    fold_rir_blocks(net)
    graph = InferenceGraph(net).eval()
    inputs = example_inputs(graph, height, width, scale)
    with torch.no_grad():
        irradiance = net(**{k: v for k, v in inputs.items() if k in graph.net_args}).get("irradiance")
    if irradiance is None:
        raise ExportError(f"{net.__class__.__name__} outputs a display image, no linear irradiance: not exported")
    reference = irradiance * inputs["brdf"]
    if fp16:  # a copy: the module keeps its float32 weights
        graph = copy.deepcopy(graph).half()
        inputs = {k: v.half() for k, v in inputs.items()}
    program = torch.onnx.export(
        graph,
        (),
        kwargs={"inputs": inputs},
        input_names=list(graph.inputs),
        output_names=list(OUTPUTS),
        opset_version=opset,
        dynamo=True,
        dynamic_shapes=_dynamic_shapes(graph) if dynamic else None,
        optimize=False,  # below, with a size limit of its own
        verbose=False,
    )
    fold_constants(program.model, max(height, width))
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    program.save(str(path), external_data=False)
    return graph, inputs, reference


def fold_constants(model: Any, longest_axis: int) -> None:
    """Optimise an exported graph (``onnx_ir.Model``, in place) as ``torch.onnx.export(optimize=True)`` does
    (onnxscript's constant folding and rewrites, then its fusions), folding no constant of more than
    ``longest_axis`` elements (the traced frame's longer side).

    In a fixed-size graph every tensor computed from the frame's size alone is a constant: the joint-bilateral
    kernels' tent weights, offsets and masks (16 taps, twice for the learned kernel). onnxscript folds constants of
    up to 512 x 512 elements by default, so a frame below that (384x216: 82944 pixels) stored each of them per
    pixel (in float64 while the taps' positions were), a graph many times its weights' size (docs/performance.md),
    whereas 1080p's, above the limit, stayed computed. Folding only up to the longer side keeps the per-axis grids
    (``(1, W)`` and ``(1, H)``) as constants and builds every per-pixel one in the graph from them, at any size
    (onnxruntime folds them again in memory when it loads the graph). A product of weights larger than the longer
    side also stays an operator, computed from its (smaller) factors."""
    import onnxscript.optimizer
    import onnxscript.rewriter.onnx_fusions

    onnxscript.optimizer.optimize_ir(model, output_size_limit=int(longest_axis))
    onnxscript.rewriter.onnx_fusions.fuse(model)


def run_onnx(path: str | Path, inputs: dict[str, Any]) -> dict[str, np.ndarray]:
    """The graph's outputs by name on onnxruntime's CPU execution provider."""
    import onnxruntime

    session = onnxruntime.InferenceSession(str(path), providers=["CPUExecutionProvider"])
    feed = {i.name: np.asarray(inputs[i.name]) for i in session.get_inputs()}
    return dict(zip([o.name for o in session.get_outputs()], session.run(None, feed), strict=True))


def relative_error(output: np.ndarray, reference: np.ndarray) -> float:
    """``max |output - reference| / max |reference|``."""
    reference = np.asarray(reference, dtype=np.float64)
    return float(np.abs(np.asarray(output, dtype=np.float64) - reference).max() / max(np.abs(reference).max(), 1e-30))


def input_layout(
    module: SuperResolutionModule,
    graph: InferenceGraph,
    prep: Preprocessing,
    *,
    height: int,
    width: int,
    scale: float,
    dynamic: bool,
    dtype: str,
    opset: int,
) -> dict[str, Any]:
    """The sidecar of an exported graph: what an engine must feed it, channel by channel."""
    inputs = _input_records(graph, height, width, scale, dynamic, dtype)
    net = graph.net
    return {
        "format": "onnx",
        "opset": opset,
        "dtype": dtype,
        "layout": "NCHW, batch of 1",
        # wdss's networks take a per-frame jitter in torch (the batch key lr_jitter); a graph does not (yet).
        "lr_sampling": "LR pixels shaded at their centres (no jitter input): render the LR frame unjittered",
        "size": _size_record(height, width, scale, dynamic),
        "inputs": inputs,
        "outputs": [
            {
                "name": "color",
                "channels": list(_RGB),
                "description": "HR linear HDR colour = irradiance * brdf"
                + (" (add the HR emission: the graph does not take it)" if prep.separates_emission else ""),
            },
            {"name": "irradiance", "channels": list(_RGB), "description": "HR demodulated prediction"},
        ],
        "preprocessing": _preprocessing_record(prep),
        # The graph applies log1p to lr and history itself: feed linear values.
        "log1p_inside": bool(net.input_log),
        "exposure": _exposure_rule(),
        "display": {"tonemap": module.hparams.tonemap_name, "exposure": module.hparams.tonemap_exposure},
        "history": _history_rule(module, graph),
        # Frame after frame: what the history is, on the first frame too, and what it was in training.
        "temporal": _temporal(module, graph, prep),
        "motion_vectors": MOTION_VECTORS if {"history", "motion"} & set(graph.inputs) else None,
        "rir_folded": any(isinstance(m, RIRBlock) for m in net.modules()),
    }


def _input_records(
    graph: InferenceGraph, height: int, width: int, scale: float, dynamic: bool, dtype: str
) -> list[dict[str, Any]]:
    """Each graph input's name, shape, dtype, resolution and channels (the sidecar's ``inputs``)."""
    lr_height, lr_width = lr_size(height, width, scale)
    sizes = {
        "high": ["2*half_height", "2*half_width"] if dynamic else [height, width],
        "low": ["2*half_lr_height", "2*half_lr_width"] if dynamic else [lr_height, lr_width],
    }
    inputs = []
    for name in graph.inputs:
        if name == "scale":
            inputs.append({"name": name, "shape": [1], "dtype": dtype, "description": "the upsampling factor s"})
            continue
        resolution, channels, description = CHANNELS[name]
        shape = [1, len(channels), *sizes[resolution]]
        inputs.append(
            {
                "name": name,
                "shape": shape,
                "dtype": dtype,
                "resolution": resolution,
                "channels": channels,
                "description": description,
            }
        )
    return inputs


def _size_record(height: int, width: int, scale: float, dynamic: bool) -> dict[str, Any]:
    """The output and LR sizes the graph runs at (the sidecar's ``size``)."""
    lr_height, lr_width = lr_size(height, width, scale)
    return {
        "dynamic": dynamic,
        # dynamic: any size whose HR and LR heights and widths are even (the graph holds the even branch)
        "height": None if dynamic else height,
        "width": None if dynamic else width,
        "lr_height": None if dynamic else lr_height,
        "lr_width": None if dynamic else lr_width,
        "lr_size": "h = round(H / s), w = round(W / s)",
    }


def _preprocessing_record(prep: Preprocessing) -> dict[str, Any]:
    """How the engine's buffers become the graph's inputs: demodulation, the BRDF factor, depth, normals, colour
    clipping and the spatial mask (the sidecar's ``preprocessing``)."""
    thresholds = prep.spatial_thresholds
    return {
        "demodulate": prep.demodulate,
        # Emitted radiance subtracted from the colour before demodulation (lr, history) and added to the output
        "emission_separated": prep.separates_emission,
        "brdf": {
            "extranet": "F = base_color + (1 - metallic) * 0.08 * specular",
            "split_sum": "F = base (1 - metallic) + F0 A + B, (A, B) = wdss.ops.brdf.ggx_lut(NoV, roughness)",
        }[prep.brdf],
        "brdf_name": prep.brdf,
        # The factor divided by (lr, history) and multiplied by (brdf): safe_brdf(F, knee)
        "brdf_knee": prep.brdf_knee,
        "brdf_factor": (
            f"F + (1 - F) exp(-(F / {prep.brdf_knee:g})^2)"
            if prep.brdf_knee > 0
            else "F, or 1 where F <= 1e-4 (or not finite)"
        ),
        "depth_far": prep.depth_far,  # depth beyond it is set to 0 (background)
        "depth_normalize": prep.depth_normalize,  # per frame (min, max) -> (0, 1); LR by its HR frame's range
        "depth": _depth_rule(prep),
        "normals": "unit length, world space",
        "color_max": prep.color_max,  # colour clipped to [0, color_max] before anything else, when set
        "spatial_thresholds": dict(prep.spatial_thresholds),
        "spatial_mask": (
            f"1 where |depth - up(depth_lr)| > {thresholds['depth']:g} or n . normalize(up(n_lr)) < "
            f"{thresholds['normal']:g} or the mean over r, g, b of |base_color - up(base_color_lr)| > "
            f"{thresholds['albedo']:g}, else 0 (wdss.ops.warp.spatial_mask): the HR G-buffer against the LR "
            "frame's own (lr_guide's channels), up = bilinear upsampling to the HR size (pixel centres aligned, "
            "align_corners=False, border values beyond), depths preprocessed as depth says"
        ),
        "lr_brdf": (
            "the factor lr was divided by: brdf_factor of F computed as brdf says from the LR frame's own "
            "buffers (a native LR render's G-buffer; in wdss's point-sampled data the HR buffers at the LR pixel "
            "centres, nearest-exact, where it equals the HR brdf point-sampled), not the HR brdf resampled"
        ),
    }


def _exposure_rule() -> str:
    """The renderer's exposure rule, stated from its constants (the sidecar's ``exposure``)."""
    from wdss.render.exposure import MAX_DARKENING, SATURATED_SHARE, SATURATION  # here: wdss.render loads its package

    return (
        "colour (and emission) is linear radiance pre-exposed as the training frames were: wdss's renders "
        "multiply every frame of a sequence, at every resolution, by one factor that brings the median Rec. 709 "
        f"luminance of lit pixels to {MIDDLE_GREY:g} (lower where more than {SATURATED_SHARE:.0%} of the values "
        f"would exceed {SATURATION:g}, never below {MAX_DARKENING:g} x that median; wdss.render.exposure). "
        "Multiply the engine's pre-tonemap colour and emission by its exposure before demodulating; the outputs "
        "are in that exposed space"
    )


def _history_rule(module: SuperResolutionModule, graph: InferenceGraph) -> str | None:
    """What the graph's history input is, on the first frame too (None: it takes none; the sidecar's ``history``)."""
    if module.temporal == "recurrent":
        return (
            "recurrent: the previous frame's irradiance output warped by this frame's motion vectors "
            "(wdss.ops.warp.warp_backward: bilinear, zeros outside); on the first frame, lr upsampled bilinearly "
            "(align_corners=False)"
        )
    if "history" in graph.inputs:
        return (
            "the previous HR frame's irradiance, warped by the motion vectors: trained on the ground-truth "
            "frame's, fed its own irradiance output by an engine; on the first frame, lr upsampled bilinearly "
            "(align_corners=False); see temporal"
        )
    return None


def check_size(height: int, width: int, scale: float, dynamic: bool) -> None:
    """Refuse, in one line, an output size the graph cannot be traced at (torch would fail deep inside export):
    not positive, a scale below 1, and with ``dynamic`` an example size whose HR or LR side is odd or under 16 (the
    dynamic graph holds the even branch, 2 x a dimension of at least 8)."""
    if height < 1 or width < 1:
        raise ExportError(f"height and width must be positive, got height={height} width={width}")
    if not scale >= 1:
        raise ExportError(f"scale must be at least 1, got {scale:g}")
    lr_height, lr_width = lr_size(height, width, scale)
    sides = (height, width, lr_height, lr_width)
    if dynamic and (any(side % 2 for side in sides) or min(sides) < 16):
        raise ExportError(
            f"dynamic=true traces at an example size whose HR and LR sides are even and at least 16: height={height} "
            f"width={width} at {scale:g}x has an LR frame of {lr_width}x{lr_height}; choose another example size "
            "(e.g. height=1080 width=1920 scale=2), any even size runs on the graph"
        )


def export(cfg: DictConfig) -> Path:
    """Export the checkpoint of ``cfg.ckpt_path`` as ``cfg.format``; the path of the graph written."""
    if cfg.format != "onnx":
        raise ExportError(f"format must be onnx, got {cfg.format!r}")
    height, width, scale = int(cfg.height), int(cfg.width), float(cfg.scale)
    dynamic, fp16 = bool(cfg.dynamic), bool(cfg.fp16)
    check_size(height, width, scale, dynamic)
    ckpt = Path(str(cfg.ckpt_path))
    read_checkpoint(ckpt)  # a wdss checkpoint whose model config builds only allowlisted callables
    module = SuperResolutionModule.load_from_checkpoint(ckpt, map_location="cpu", weights_only=True)
    if cfg.output:
        path = Path(str(cfg.output))
    else:
        size = "dynamic" if dynamic else f"{width}x{height}_{scale:g}x"
        path = ckpt.with_name(f"{ckpt.stem}_{size}{'_fp16' if fp16 else ''}.onnx")
    overrides = OmegaConf.to_container(cfg.preprocessing, resolve=True) if cfg.get("preprocessing") else {}
    prep = Preprocessing(**{**training_preprocessing(ckpt), **overrides})
    graph, inputs, reference = export_onnx(
        module, path, height=height, width=width, scale=scale, dynamic=dynamic, fp16=fp16, opset=int(cfg.opset)
    )
    dtype = "float16" if fp16 else "float32"
    layout = input_layout(
        module, graph, prep, height=height, width=width, scale=scale, dynamic=dynamic, dtype=dtype, opset=int(cfg.opset)
    )
    layout.update({"file": path.name, "checkpoint": str(ckpt.resolve())})
    sidecar = path.with_suffix(".json")
    sidecar.write_text(json.dumps(layout, indent=1) + "\n")
    print(f"wdss.export: {ckpt} -> {path} ({path.stat().st_size / 1e6:.2f} MB, opset {cfg.opset}, {dtype})")
    print(f"  inputs: {', '.join(graph.inputs)}; outputs: {', '.join(OUTPUTS)}; layout: {sidecar}")
    if cfg.verify:
        error = relative_error(run_onnx(path, {k: v.numpy() for k, v in inputs.items()})["color"], reference.numpy())
        print(f"  onnxruntime (CPU) vs torch on the example inputs: max |difference| / max = {error:.2e}")
        if not error <= TOLERANCE[dtype]:
            raise ExportError(f"{path}: onnxruntime differs from torch by {error:.2e} > {TOLERANCE[dtype]:g}")
    return path


@entry_point("wdss.export", CONF_DIR / "inference", "export")
def main(cfg: DictConfig) -> None:
    export(cfg)


if __name__ == "__main__":
    main()
