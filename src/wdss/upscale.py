"""Upscale entry point: ``python -m wdss.upscale ckpt_path=PATH input=SEQUENCE scale=2 [output=DIR]
[frames=[start,stop]] [compare=true] [on_error=skip] [precision=bfloat16]``.

Runs a trained model on a sequence of one's own frames, in any layout wdss reads, reading only the buffers the
model needs (the LR colour from a native folder that matches the scale, else point-sampled from the HR frame),
frame by frame in order: a recurrent model is fed its own previous output, warped, as in evaluation. Writes into
``output`` (default ``<paths.log_dir>/upscale/<sequence>_<s>x``):

* per frame, the HR prediction as linear HDR EXR under the input's own name for the HR colour buffer, so that
  wdss reads the folder back as a sequence, and ``png/<frame>.png`` tone-mapped as the module's metrics see it
  (with ``compare``: ``compare/<frame>.png``, bilinear-demodulated baseline | prediction, and where the input
  holds the HR colour | target | error x4, as the eval videos show them);
* ``<sequence>_<s>x.mp4`` of the PNGs at the sequence's frame rate, a short one looped to last 3 s (:mod:`wdss.video`);
* ``upscale.json``: what made the frames (checkpoint digest, input, scale), each frame's metrics, skipped frames,
  warnings (a scale outside those the model was trained at).

When the input holds the HR colour (a wdss dataset) it is the target: PSNR, SSIM and FLIP are printed per frame
and overall. A rerun of a killed run resumes: a frame whose files all exist is not computed again (each file is
written under a temporary name and renamed, the EXR last). A frame that fails to read stops the run with the
file's name, or, with ``on_error=skip``, is reported and left out.
"""

from __future__ import annotations

from wdss.errors import UserError, entry_point
from wdss.memory import restart_with_retained_memory

if __name__ == "__main__":
    # A process that loops over frames keeps the memory one frame frees for the next, rather than mapping it anew and
    # faulting it in (wdss.memory). Started again before the heavy imports below, so that this costs little.
    restart_with_retained_memory()

import dataclasses
import hashlib
import json
import os
import re
import sys
from pathlib import Path
from typing import Any

import numpy as np
import torch
from omegaconf import DictConfig, OmegaConf
from torch import Tensor

from wdss.callbacks.images import comparison_panel
from wdss.checkpoint import CheckpointError, read_checkpoint, training_preprocessing
from wdss.config.targets import TargetRefused, refuse_interpolation
from wdss.data.dataset import Collate, FrameDataset, Preprocessing, ScaleSpec, parse_scale
from wdss.data.exr import ExrError, read_exr, write_exr
from wdss.data.layouts import SceneError, Sequence
from wdss.data.preprocess import prediction_color, target_irradiance
from wdss.nets.base import SuperResolutionNet
from wdss.nets.blocks import fold_rir_blocks
from wdss.nets.upsamplers.baselines import Upsample
from wdss.paths import CONF_DIR
from wdss.progress import Progress
from wdss.training.module import SuperResolutionModule
from wdss.video import LABELS, Mp4Writer, labelled

__all__ = ["UpscaleError", "main", "output_name", "upscale"]

RECORD = "upscale.json"
# The network's precision, by autocast: its convolutions and matrix products in bfloat16 or float16, what needs
# float32 (the wavelet synthesis, the learned kernel's softmax) in float32, as are the metrics and files. In bfloat16
# the network runs faster on CPUs with AVX512-BF16 or AMX, a little off float32 (docs/performance.md); float16 suits
# GPUs.
PRECISIONS = {"float32": torch.float32, "bfloat16": torch.bfloat16, "float16": torch.float16}
SHOWN = ("psnr", "ssim", "flip")  # printed per frame (every metric is recorded)
_READ_ERRORS = (SceneError, ExrError, OSError)


class UpscaleError(UserError):
    """An upscale that cannot run as asked."""


def output_name(seq: Sequence, frame: int) -> str:
    """The file, relative to the output folder, of a frame's prediction: the input's HR colour file, or (an input
    without HR colour) its LR colour file in the HR folder of its layout."""
    name = seq.file("color", seq.hr, frame)
    if name is not None:
        return name
    for height in seq.resolutions[1:]:
        name = seq.file("color", height, frame)
        if name is not None:
            folder, _, file = name.partition("/")
            return re.sub(r"\d+P$", f"{seq.hr}P", folder) + f"/{file}"
    raise SceneError(f"sequence {seq.name!r}, frame {frame}: no colour buffer at any resolution")


def trained_scales(ckpt: Path) -> ScaleSpec | None:
    """``data.scale`` of the run that wrote the checkpoint (``<run>/.hydra/config.yaml``, where
    :func:`wdss.checkpoint.training_preprocessing` finds the run's preprocessing), or None where it is unknown."""
    config = ckpt.resolve().parent.parent / ".hydra" / "config.yaml"
    if not config.is_file():
        return None
    try:
        saved = OmegaConf.to_container(OmegaConf.load(config), resolve=False)  # data: nothing in it is resolved
        node = (saved.get("data") or {}).get("scale")
        if node == "${scale.train}":  # the one interpolation wdss writes there, followed by hand
            node = (saved.get("scale") or {}).get("train")
    except Exception:  # a config of another version: no warning rather than no upscale
        return None
    try:
        refuse_interpolation(node, "data.scale")
    except TargetRefused as err:
        raise CheckpointError(f"{config} (the run of checkpoint {ckpt}): {err}") from err
    try:
        return None if node is None else parse_scale(node)
    except Exception:
        return None


def scale_warning(scale: float, trained: ScaleSpec | None) -> str | None:
    """Why ``scale`` is outside the scales the model was trained at (its output there was never trained for, nor
    tested), or None."""
    if trained is None:
        return None
    if isinstance(trained, dict):
        choices = trained["choices"]
        inside, said = any(abs(scale - s) < 1e-6 for s in choices), ", ".join(f"{s:g}x" for s in choices)
    elif isinstance(trained, tuple):
        inside, said = trained[0] - 1e-6 <= scale <= trained[1] + 1e-6, f"{trained[0]:g}x to {trained[1]:g}x"
    else:
        inside, said = abs(scale - trained) < 1e-6, f"{trained:g}x only"
    if inside:
        return None
    return f"scale {scale:g}x is outside the scales the model was trained at ({said}): going on, expect artefacts"


def _digest(path: Path) -> str:
    sha = hashlib.sha256()
    with path.open("rb") as file:
        for block in iter(lambda: file.read(1 << 20), b""):
            sha.update(block)
    return sha.hexdigest()


def _save_png(path: Path, rgb: np.ndarray) -> None:
    """An 8-bit PNG written under a temporary name, then renamed: a killed run leaves no half file."""
    from PIL import Image

    path.parent.mkdir(parents=True, exist_ok=True)
    tmp = path.with_name(f".{path.name}.{os.getpid()}.tmp")
    Image.fromarray(rgb).save(tmp, format="PNG")
    os.replace(tmp, path)


def _to(value: Any, device: torch.device) -> Any:
    """A batch value on ``device``, an image channels-last (the network's layout)."""
    if not isinstance(value, Tensor):
        return value
    return value.to(device, memory_format=torch.channels_last) if value.dim() == 4 else value.to(device)


def _to_uint8(image: Tensor) -> np.ndarray:
    return (image[0].permute(1, 2, 0).cpu().numpy() * 255).round().astype(np.uint8)


class Record:
    """``upscale.json`` of an output folder: the run's identity, and per frame its metrics or why it was skipped.

    A folder made by another checkpoint, input or scale is refused, never mixed into.
    """

    def __init__(self, out_dir: Path, identity: dict[str, Any], unrecorded: dict[str, Any] | None = None) -> None:
        """``unrecorded``: what an older record that lacks a key of ``identity`` stands for ("as trained": the
        identity's own value; None: unknown, so refused)."""
        self.path = out_dir / RECORD
        self.identity = identity
        self.frames: dict[str, dict[str, float]] = {}
        self.skipped: dict[str, str] = {}
        self.warnings: list[str] = []
        if self.path.exists():
            old = json.loads(self.path.read_text())
            old = {"precision": "float32", **old}  # a folder from before the option ran in float32
            for key, stands in (unrecorded or {}).items():
                old.setdefault(key, identity[key] if stands == "as trained" else "not recorded")
            if {k: old.get(k) for k in identity} != identity:
                differ = ", ".join(f"{k} {old.get(k)!r} (now {v!r})" for k, v in identity.items() if old.get(k) != v)
                raise UpscaleError(
                    f"{out_dir} holds the frames of another upscale ({differ}): choose another output= or remove it"
                )
            self.frames = old.get("frames", {})

    def save(self) -> None:
        self.path.parent.mkdir(parents=True, exist_ok=True)
        tmp = self.path.with_name(f".{self.path.name}.{os.getpid()}.tmp")
        record = {**self.identity, "frames": self.frames, "skipped": self.skipped, "warnings": self.warnings}
        tmp.write_text(json.dumps(record, indent=1))
        os.replace(tmp, self.path)


def check_output(out_dir: Path, source: Path) -> None:
    """Refuse an output folder that is, holds or lies inside the input (its frames would be overwritten or read back
    as input), and an existing folder with files but no upscale record (wdss writes only into its own folders)."""
    out, inp = out_dir.resolve(), Path(source).resolve()
    if out == inp or inp in out.parents or out in inp.parents:
        raise UpscaleError(
            f"output={out_dir} is, holds or lies inside the input {source}: the upscaled frames would overwrite or "
            "mix with the input's; choose another output="
        )
    if out.is_dir() and not (out / RECORD).exists() and any(out.iterdir()):
        raise UpscaleError(
            f"output={out_dir} holds files but no {RECORD}: it is not an upscale folder, and wdss writes only into "
            "its own; choose an empty or new folder"
        )


def _describe(values: dict[str, float]) -> str:
    units = {"psnr": " dB"}
    return ", ".join(f"{k.upper()} {values[k]:.4g}{units.get(k, '')}" for k in SHOWN if k in values)


def upscale(cfg: DictConfig) -> dict[str, float]:
    """Upscale ``cfg.input`` with the model of ``cfg.ckpt_path``; the mean metrics (empty without a target)."""
    dtype = _precision(cfg)
    ckpt = Path(str(cfg.ckpt_path))
    read_checkpoint(ckpt)  # a wdss checkpoint whose model config builds only allowlisted callables
    device = torch.device(str(cfg.device))
    module = _load_model(ckpt, device)
    seq = Sequence(str(cfg.input), str(cfg.layout))
    scale = float(cfg.scale)
    warning = _check_scale(module.net, scale, ckpt)
    inputs = _model_inputs(cfg, module, seq, scale, ckpt)
    out_dir = Path(str(cfg.output or Path(str(cfg.paths.log_dir)) / "upscale" / f"{seq.name}_{scale:g}x"))
    check_output(out_dir, seq.source.path)
    record = _open_record(out_dir, ckpt, inputs, scale, str(cfg.precision), warning)
    run = _Upscaler(module, inputs, out_dir, record, bool(cfg.compare), str(cfg.on_error), device, dtype)
    done = run.announce(ckpt, scale)
    run.frames(done, f"upscale {seq.name} {scale:g}x")
    frames = [f for _, f in inputs.dataset.items]
    if cfg.video:
        _video(out_dir, seq, scale, [run.files(f)[-1] for f in frames if run.complete(f)], cfg.fps)
    return _summary(record, seq, scale, out_dir, frames)


def _precision(cfg: DictConfig) -> torch.dtype:
    """The network's precision (``precision``), with ``on_error`` checked first."""
    if cfg.on_error not in ("stop", "skip"):
        raise UpscaleError(f"on_error must be stop or skip, got {cfg.on_error!r}")
    if str(cfg.precision) not in PRECISIONS:
        raise UpscaleError(f"precision must be one of {', '.join(PRECISIONS)}, got {cfg.precision!r}")
    return PRECISIONS[str(cfg.precision)]


def _load_model(ckpt: Path, device: torch.device) -> SuperResolutionModule:
    """The checkpoint's module in eval mode on ``device``, as engines run it (wdss.bench inference): RIR blocks
    folded, and channels-last: oneDNN's convolutions skip their reorders and an SWT head computes its tail on cells."""
    module = SuperResolutionModule.load_from_checkpoint(ckpt, map_location=device, weights_only=True).eval()
    fold_rir_blocks(module.net)
    return module.to(memory_format=torch.channels_last)


def _check_scale(net: SuperResolutionNet, scale: float, ckpt: Path) -> str | None:
    """Refuse a scale a fixed-scale network cannot upsample by; warn (on stderr) of one outside those the model was
    trained at, and return that warning."""
    if net.fixed_scale and scale != float(net.scale):
        raise UpscaleError(f"the model ({net.__class__.__name__}) upsamples by {net.scale} only, not by {scale:g}")
    warning = scale_warning(scale, trained_scales(ckpt))
    if warning:
        print(f"wdss.upscale: WARNING: {warning}", file=sys.stderr, flush=True)
    return warning


@dataclasses.dataclass
class _Inputs:
    """The input's frames as the model is fed them, and what they hold."""

    seq: Sequence
    dataset: FrameDataset
    collate: Collate
    prep: Preprocessing
    overrides: dict  # of the training run's preprocessing (``preprocessing``)
    keys: set[str]  # the batch keys read
    has_target: bool  # metrics against the input's HR colour
    shows_target: bool  # the HR colour read: for the metrics, or shown beside them
    feed_back: bool  # the history is the model's own previous output


def _model_inputs(cfg: DictConfig, module: SuperResolutionModule, seq: Sequence, scale: float, ckpt: Path) -> _Inputs:
    """The dataset of the frames to upscale (``frames``), reading only the buffers the model needs (and ``compare``
    shows), preprocessed as in training (with ``preprocessing``'s overrides)."""
    overrides = OmegaConf.to_container(cfg.preprocessing, resolve=True) if cfg.get("preprocessing") else {}
    prep = Preprocessing(**{**training_preprocessing(ckpt), **overrides})
    hr_color = seq.has("color", seq.hr)
    has_target = bool(cfg.metrics) and hr_color
    shows_target = hr_color and bool(cfg.metrics or cfg.compare)
    # The history a temporal model gets: its own previous output (recurrent; also a gt_history model on frames
    # without HR colour, as an engine runs it), or the previous HR frame read from the input (gt_history).
    feed_back = module.temporal == "recurrent" or (module.temporal == "gt_history" and not hr_color)
    keys = set(module.inputs)
    if feed_back:
        keys = (keys - {"history"}) | {"motion"}
    if not shows_target:
        keys.discard("target")
    if cfg.compare:
        keys |= {"lr", "brdf", "emission"}  # bilinear_demodulated beside the prediction
    frames = {seq.name: tuple(cfg.frames)} if cfg.frames is not None else None
    dataset = FrameDataset(
        [seq], sorted(keys), scale=scale, patch=None, preprocessing=prep, first_frame="zeros", frame_ranges=frames
    )
    collate = Collate(dataset.keys, prep, scale)
    return _Inputs(seq, dataset, collate, prep, overrides, keys, has_target, shows_target, feed_back)


def _open_record(
    out_dir: Path, ckpt: Path, inputs: _Inputs, scale: float, precision: str, warning: str | None
) -> Record:
    """The output folder's record (refused when another upscale made the folder), its warnings saved at once."""
    record = Record(
        out_dir,
        {
            "checkpoint_sha256": _digest(ckpt),
            "input": str(inputs.seq.source.path.resolve()),
            "scale": scale,
            "precision": precision,
            # Everything that changes a frame is part of the folder's identity: a rerun with other preprocessing
            # is refused rather than mixed in (folders from before this was recorded: as made without overrides).
            "preprocessing": json.loads(json.dumps(dataclasses.asdict(inputs.prep), default=str)),
        },
        unrecorded={"preprocessing": None if inputs.overrides else "as trained"},
    )
    record.warnings = [warning] if warning else []
    if record.warnings:  # recorded even when every frame is already done
        record.save()
    return record


class _Upscaler:
    """The frame loop of one upscale: each frame not done yet read, fed its history, run and written, in order."""

    def __init__(
        self,
        module: SuperResolutionModule,
        inputs: _Inputs,
        out_dir: Path,
        record: Record,
        compare: bool,
        on_error: str,
        device: torch.device,
        dtype: torch.dtype,
    ) -> None:
        self.module, self.inputs, self.out_dir, self.record = module, inputs, out_dir, record
        self.compare, self.on_error, self.device, self.dtype = compare, on_error, device, dtype
        self.baseline = Upsample("bilinear", demodulated=True)

    def files(self, frame: int) -> list[Path]:
        """A frame's outputs, the EXR (written last) first."""
        paths = [self.out_dir / output_name(self.inputs.seq, frame), self.out_dir / "png" / f"{frame:04d}.png"]
        return paths + ([self.out_dir / "compare" / f"{frame:04d}.png"] if self.compare else [])

    def complete(self, frame: int) -> bool:
        try:
            written = all(p.exists() for p in self.files(frame))
        except SceneError:  # no colour at any resolution: the frame fails to read
            return False
        return written and (not self.inputs.has_target or str(frame) in self.record.frames)

    def announce(self, ckpt: Path, scale: float) -> list[int]:
        """Print what the run does, and return the frames already done (a rerun resumes)."""
        inputs = self.inputs
        seq, dataset = inputs.seq, inputs.dataset
        lr_height = dataset.native_lr(seq)
        done = [frame for _, frame in dataset.items if self.complete(frame)]
        lr = f"from the native {lr_height}P folder" if lr_height else f"point-sampled from {seq.hr}P"
        history = (
            "fed back from the output" if inputs.feed_back else "from the input" if "history" in inputs.keys else "none"
        )
        target = (
            "metrics against the HR colour"
            if inputs.has_target
            else "target shown"
            if inputs.shows_target
            else "no target"
        )
        print(
            f"wdss.upscale: {seq.name} ({seq.layout.name} layout, {len(dataset)} frames) at {scale:g}x with {ckpt}: "
            f"LR {lr}, history {history}, {target} -> {self.out_dir}",
            flush=True,
        )
        if done:
            print(f"  {len(done)} of {len(dataset)} frames already done in {self.out_dir}: resuming", flush=True)
        return done

    def frames(self, done: list[int], label: str) -> None:
        """Upscale every frame not in ``done``, in order."""
        dataset = self.inputs.dataset
        previous: tuple[int, Tensor] | None = None  # (frame, irradiance) of the last frame computed
        with Progress(label, len(dataset)) as progress:
            for index, (_, frame) in enumerate(dataset.items):
                if frame in done:
                    progress.advance(text=None)
                    continue
                batch = self._read(index, frame, progress)
                if batch is None:
                    continue
                if self.inputs.feed_back:
                    history, previous = self._history(index, frame, done, previous)
                    batch = self.module._with_history(batch, history)
                out = self._predict(batch)
                text = self._write(frame, batch, out["color"])
                previous = (frame, out["irradiance"].float())  # warped in float32 into the next frame's history
                progress.advance(text=text)

    def _read(self, index: int, frame: int, progress: Progress) -> dict[str, Any] | None:
        """The frame's batch on the device, or None for a frame that cannot be read with ``on_error=skip`` (recorded
        and reported)."""
        try:
            batch = self.inputs.collate([self.inputs.dataset[index]])
        except _READ_ERRORS as err:
            if self.on_error == "stop":
                raise UpscaleError(f"frame {frame} cannot be read: {err} (on_error=skip goes on)") from err
            self.record.skipped[str(frame)] = str(err)
            self.record.save()
            progress.advance(text=f"frame {frame:04d} SKIPPED, it cannot be read: {err}")
            return None
        return {k: _to(v, self.device) for k, v in batch.items()}

    def _history(
        self, index: int, frame: int, done: list[int], previous: tuple[int, Tensor] | None
    ) -> tuple[Tensor | None, tuple[int, Tensor] | None]:
        """The irradiance fed back into ``frame`` (None: the first frame, or the one before could not be read) and
        the ``previous`` it came from: the last frame computed, or the one before read back from its files when that
        was done by an earlier run."""
        items = self.inputs.dataset.items
        if (previous is None or previous[0] != frame - 1) and index and items[index - 1][1] in done:
            fed = self._read_back(index - 1)
            previous = (frame - 1, fed) if fed is not None else None
        history = previous[1] if previous is not None and previous[0] == frame - 1 else None
        return history, previous

    def _read_back(self, index: int) -> Tensor | None:
        """The irradiance a finished frame fed forward: its EXR colour less its emission, over its BRDF factor."""
        dataset = self.inputs.dataset
        try:
            batch = self.inputs.collate([dataset[index]])
            frame = dataset.items[index][1]
            planes = read_exr(self.files(frame)[0], self.inputs.seq.layout.SLOTS["color"].channels)
        except _READ_ERRORS:
            return None
        color = torch.from_numpy(np.stack(list(planes.values())))[None].to(self.device)
        known = {k: batch[k].to(self.device) for k in ("brdf", "emission") if k in batch}
        return target_irradiance({"target": color, **known})

    def _predict(self, batch: dict[str, Any]) -> dict[str, Tensor]:
        """The network's outputs in ``precision``; one without a linear HDR colour is refused."""
        with torch.inference_mode(), torch.autocast(self.device.type, self.dtype, enabled=self.dtype != torch.float32):
            out = self.module(batch, subbands=False)
        if out.get("color") is None:
            raise UpscaleError(
                f"{self.module.net.__class__.__name__} outputs a display image, no linear HDR colour to write"
            )
        return out

    def _write(self, frame: int, batch: dict[str, Any], color: Tensor) -> str:
        """Write the frame's pictures, its metrics into the record and its EXR (last: it marks the frame done);
        returns its progress line."""
        module, files = self.module, self.files(frame)
        reference = batch.get("target", color)  # the display exposure, when it is "auto"
        _save_png(files[1], _to_uint8(module.tone(color.float(), reference.float())))
        if self.compare:
            base = prediction_color(self.baseline(brdf=batch["brdf"], lr=batch["lr"])["irradiance"], batch)
            _save_png(files[2], _comparison(module, base, color, batch.get("target")))
        text = f"frame {frame:04d}"
        if self.inputs.has_target:
            values = {k: float(v[0]) for k, v in module.metrics(color.float(), batch["target"].float()).items()}
            self.record.frames[str(frame)] = values
            text += f": {_describe(values)}"
        self.record.skipped.pop(str(frame), None)
        self.record.save()
        channels = self.inputs.seq.layout.SLOTS["color"].channels
        write_exr(files[0], dict(zip(channels, color[0].float().cpu().numpy(), strict=True)))
        return text


def _comparison(module: SuperResolutionModule, base: Tensor, color: Tensor, target: Tensor | None) -> np.ndarray:
    """The labelled ``compare/<frame>.png``: baseline | prediction, and with a target | target | error x4 as the
    eval videos show them (:func:`wdss.callbacks.images.comparison_panel`, the baseline in the LR tile's place: at HR
    already, its nearest upsampling leaves it as it is)."""
    if target is None:
        tiles = [module.tone(x.float(), color.float()) for x in (base, color)]
        return labelled(_to_uint8(torch.cat(tiles, dim=-1)), ("bilinear_demodulated", "prediction"))
    panel = comparison_panel({"target": target, "lr_color": base}, {"color": color}, module.tone)
    return labelled(panel, ("bilinear_demodulated", *LABELS[1:]))


def _video(out_dir: Path, seq: Sequence, scale: float, pictures: list[Path], fps: float | None) -> None:
    """An MP4 of the frames' pictures, in order, written under a temporary name and renamed."""
    from PIL import Image

    if not pictures:
        return
    path = out_dir / f"{seq.name}_{scale:g}x.mp4"
    tmp = path.with_name(f".{path.stem}.{os.getpid()}.tmp.mp4")
    writer = Mp4Writer(tmp, float(fps or seq.frame_rate))
    try:
        for picture in pictures:
            writer.write(np.asarray(Image.open(picture).convert("RGB")))
    finally:
        writer.close()
    os.replace(tmp, path)
    looped = f", played {writer.loops} times to last {writer.min_seconds:g} s" if writer.loops > 1 else ""
    print(f"  video: {path} ({writer.frames} frames{looped})", flush=True)


def _summary(record: Record, seq: Sequence, scale: float, out_dir: Path, frames: list[int]) -> dict[str, float]:
    """Print and return the mean of every metric over the frames (finite values: identical frames' PSNR is inf)."""
    rows = [record.frames[str(f)] for f in frames if str(f) in record.frames]
    means = {}
    for key in rows[0] if rows else ():
        values = [row[key] for row in rows if np.isfinite(row[key])]
        if values:
            means[key] = float(np.mean(values))
    print(f"wdss.upscale: {seq.name} at {scale:g}x -> {out_dir}", flush=True)
    if means:
        print(f"  overall ({len(rows)} frames): {_describe(means)}", flush=True)
    skipped = {int(f): why for f, why in record.skipped.items() if int(f) in frames}
    if skipped:
        print(f"  {len(skipped)} frame(s) SKIPPED, they could not be read:", file=sys.stderr, flush=True)
        for frame, why in sorted(skipped.items()):
            print(f"    frame {frame}: {why}", file=sys.stderr, flush=True)
    return means


@entry_point("wdss.upscale", CONF_DIR / "inference", "upscale")
def main(cfg: DictConfig) -> None:
    upscale(cfg)


if __name__ == "__main__":
    main()
