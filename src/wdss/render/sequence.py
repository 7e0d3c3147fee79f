"""Render sequences to disk in the authors' Unreal layout: resumable per frame, with a sidecar and a progress bar.

A sequence of ``frames`` frames is rendered from frame 0 to ``frames`` inclusive: frame 0 exists so that
frame 1 has a previous frame (its motion vectors point to frame 0). Low-resolution folders for each scale
are either nearest-exact point samples of the high-resolution buffers (``lr_mode="downsample"``, as in the
authors' data) or native renders at the lower resolution with point-sampled, aliased G-buffers
(``lr_mode="native"``), each LR frame shaded at its pixel centres or, with ``lr_mode="jittered"``, at a
per-frame sub-pixel jitter (:func:`wdss.ops.sampling.halton_jitter`, recorded per frame as ``lr_jitter``), as
engines hand their upscalers. Motion vectors are in high-resolution pixels in every folder.

Each file is written atomically (temporary name, then rename), so a killed render leaves no half-written
EXR; a frame whose files all exist is skipped when the render is run again.
"""

from __future__ import annotations

import dataclasses
import inspect
import json
import logging
import os
import sys
import time
from collections.abc import Callable, Iterable, Mapping
from pathlib import Path
from typing import Any

import numpy as np
import torch
from rich.progress import BarColumn, MofNCompleteColumn, Progress, TextColumn, TimeRemainingColumn

from wdss.data.exr import write_exr
from wdss.data.layouts import SceneError, UnrealLayout
from wdss.errors import ConfigError
from wdss.ops.sampling import JITTER_PHASES, halton_jitter, lr_size, point_sample
from wdss.progress import duration
from wdss.render.exposure import auto_exposure
from wdss.render.scene_file import check_scene, file_digest
from wdss.render.spec import SceneSpec, camera_pose, intrinsics, random_scene

__all__ = [
    "RenderOnFirstUse",
    "frame_files",
    "preset_settings",
    "render_preset",
    "render_sequence",
    "render_sequences",
    "sampling_convention",
]

log = logging.getLogger(__name__)


def _stems() -> list[str]:
    return sorted({slot.stem for slot in UnrealLayout.SLOTS.values()})


def frame_files(folder: Path, frame: int, heights: Iterable[int]) -> list[Path]:
    """Every file one frame writes."""
    return [folder / f"{h}P" / f"{stem}.{frame:04d}.exr" for h in heights for stem in _stems()]


# Stored as 16-bit half when ``half`` is on: everything but depth and motion, which need float32's range and
# sub-pixel precision (Unreal's own captures are half as well).
HALF_BUFFERS = ("color", "base_color", "normal", "specular", "metallic", "roughness", "nov", "emission")


def write_unreal_frame(
    folder: Path, frame: int, buffers: Mapping[str, np.ndarray], compression: str, half: bool = False
) -> None:
    files: dict[str, dict[str, np.ndarray]] = {}
    halves: dict[str, list[str]] = {}
    for buffer, slot in UnrealLayout.SLOTS.items():
        if buffer not in buffers:  # an optional buffer this frame was rendered without (emission)
            continue
        for channel, plane in zip(slot.channels, buffers[buffer], strict=True):
            files.setdefault(slot.stem, {})[channel] = plane
            if half and buffer in HALF_BUFFERS:
                halves.setdefault(slot.stem, []).append(channel)
    for stem, channels in files.items():
        write_exr(folder / f"{stem}.{frame:04d}.exr", channels, compression=compression, half=halves.get(stem, []))


def _expose(buffers: dict[str, np.ndarray], exposure: float) -> None:
    """The sequence's pre-exposure applied to its radiance buffers, in place."""
    for name in ("color", "emission"):
        if name in buffers:
            buffers[name] = buffers[name] * np.float32(exposure)


def sampling_convention(lr_mode: str, filter_width: float, folders: Mapping[int, int]) -> dict[str, Any]:
    """How each LR folder relates to the HR frame, as ``sequence.json`` records it (``data.lr_source`` reads it).

    ``point``: LR pixel i is HR pixel floor((i + 0.5) s), colour and G-buffer alike (the authors' data); ``native``:
    rendered at LR, every buffer sampled at the LR pixel centres (between HR pixel centres at even scales), as an
    engine renders its LR frame; with a ``jitter`` (``lr_mode="jittered"``), at ``i + 0.5 + j`` for the frame's
    ``lr_jitter`` ``j`` (in ``frames``, LR pixels, x right, y down). G-buffers are point-sampled (raster-like) at a
    pixel filter of at most 0.01 pixels, else filtered (anti-aliased) by it."""
    lr = "point" if lr_mode == "downsample" else "native"
    jitter = f"per frame (frames[].lr_jitter): Halton(2, 3), {JITTER_PHASES} phases" if lr_mode == "jittered" else None
    return {
        "lr": {f"{h}P": {"scale": s, "lr": lr, "jitter": jitter} for h, s in sorted(folders.items(), reverse=True)},
        "gbuffer": "point-sampled" if filter_width <= 0.01 else "filtered",
        "filter_width_px": filter_width,
    }


# How the LR folders are made (render.lr_mode): point samples of the HR frame, or rendered at LR without and with
# a per-frame sub-pixel jitter.
LR_MODES = ("downsample", "native", "jittered")


def _lr_jitter(lr_mode: str, frame: int) -> tuple[float, float] | None:
    """Where ``frame``'s LR pixels are shaded, from their centres: its Halton jitter where the LR frames are
    jittered, else ``None`` (the one place both the renders and the sidecar take it from)."""
    return halton_jitter(frame) if lr_mode == "jittered" else None


def _frame_record(frame: int, camera_to_world: np.ndarray, lr_mode: str) -> dict[str, Any]:
    """The frame's sidecar entry: its camera and, where the LR frames are jittered, its ``lr_jitter``."""
    jitter = _lr_jitter(lr_mode, frame)
    return {
        "frame": frame,
        "camera_to_world": camera_to_world.tolist(),
        **({} if jitter is None else {"lr_jitter": list(jitter)}),
    }


def _write_json(path: Path, data: Any) -> None:
    tmp = path.with_name(f".{path.name}.tmp")
    tmp.write_text(json.dumps(data, indent=1))
    os.replace(tmp, path)


def render_sequence(
    out_dir: str | Path,
    name: str,
    seed: int,
    *,
    frames: int = 16,
    resolution: tuple[int, int] = (384, 216),
    scales: Iterable[int] = (2, 3, 4),
    lr_mode: str = "downsample",
    samples: int = 8,
    lr_samples: int = 4,
    denoise: bool = True,
    filter_width: float = 0.01,
    threads: int = 0,
    objects: tuple[int, int] = (10, 40),
    compression: str = "zip",
    half: bool = True,
    exposure: float | str = "auto",
    scene: str | Path | None = None,
    camera: str = "auto",
    lighting: str = "auto",
    noise_ceiling: bool = False,
    progress: Progress | None = None,
    spec: SceneSpec | None = None,
) -> Path:
    """Render one sequence into ``out_dir/name`` and return that folder. ``resolution`` is (width, height).

    The scene is ``random_scene(seed)`` unless a ``spec`` is given, or the ``.glb``/``.gltf``/``.blend`` file
    ``scene`` framed by ``camera`` and lit as ``lighting`` says (:mod:`wdss.render.scene_file`; ``seed``
    then seeds the fitted camera path and the added lighting). ``exposure``: the factor every frame's
    radiance is multiplied by, or ``"auto"``: chosen from probe renders by :func:`wdss.render.exposure.auto_exposure`
    and recorded in ``sequence.json`` (so a resumed render applies the same factor). ``noise_ceiling``: once every
    frame is rendered, re-render the scored frames (1..frames) with another seed and record the targets' noise
    ceiling in ``sequence.json`` (:mod:`wdss.render.noise`; kept when the sequence is resumed).
    """
    scene_path = _scene_file(name, scene, camera, lighting, spec)
    options = _Options.checked(
        frames, resolution, scales, lr_mode, samples, lr_samples, denoise, filter_width, threads, compression, half,
        exposure,
    )  # fmt: skip
    folder = Path(out_dir) / name
    settings = _settings(options, scene_path, camera, lighting)
    previous_meta = _previous_meta(folder, seed, settings)
    todo = [f for f in range(frames + 1) if not all(p.exists() for p in frame_files(folder, f, options.heights))]
    measure = noise_ceiling and not (previous_meta and "noise" in previous_meta)
    task = progress.add_task(name, total=frames + 1, completed=frames + 1 - len(todo)) if progress else None
    if scene_path is not None and previous_meta and not todo and not measure:
        return folder  # nothing to do: the file is not even loaded
    staged = _stage_scene(name, seed, options, spec, objects, scene_path, camera, lighting, settings)
    folder.mkdir(parents=True, exist_ok=True)
    meta = _sidecar(name, seed, settings, options, staged, previous_meta)
    _write_json(folder / "sequence.json", meta)
    for stale in folder.rglob(".*.tmp"):  # a render killed while writing leaves only its temporary file
        stale.unlink()
    if todo or measure:
        _render(staged.blender_scene(), folder, meta, todo, measure, options, staged, (progress, task))
    return folder


@dataclasses.dataclass(frozen=True)
class _Options:
    """How a sequence is rendered and stored: :func:`render_sequence`'s options, checked."""

    frames: int
    width: int
    height: int
    scales: list[int]
    lr_mode: str
    samples: int
    lr_samples: int
    denoise: bool
    filter_width: float
    threads: int
    compression: str
    half: bool
    exposure: float | str

    @classmethod
    def checked(
        cls,
        frames: int,
        resolution: tuple[int, int],
        scales: Iterable[int],
        lr_mode: str,
        samples: int,
        lr_samples: int,
        denoise: bool,
        filter_width: float,
        threads: int,
        compression: str,
        half: bool,
        exposure: float | str,
    ) -> _Options:
        """The options, once the LR mode, the exposure and the scales (each dividing the resolution) are valid."""
        if lr_mode not in LR_MODES:
            raise ConfigError(f"render.lr_mode must be one of {', '.join(LR_MODES)}, got {lr_mode!r}")
        width, height = resolution
        scales = [int(s) for s in scales]
        if exposure != "auto" and not (isinstance(exposure, (int, float)) and exposure > 0):
            raise ConfigError(f"render.exposure must be 'auto' or a positive number, got {exposure!r}")
        for s in scales:
            if width % s or height % s:
                raise ConfigError(f"render.resolution {width}x{height} is not divisible by scale {s}")
        return cls(
            frames, width, height, scales, lr_mode, samples, lr_samples, denoise, filter_width, threads, compression,
            half, exposure,
        )  # fmt: skip

    @property
    def heights(self) -> list[int]:
        """The heights of a frame's folders: the HR one, then one per scale."""
        return [self.height] + [self.height // s for s in self.scales]


def _scene_file(name: str, scene: str | Path | None, camera: str, lighting: str, spec: SceneSpec | None) -> Path | None:
    """The checked scene file to render (None: a procedural scene); a file and a ``spec`` both is an error."""
    scene_path = check_scene(scene, camera, lighting, where=f"sequence {name!r}")
    if scene_path is not None and spec is not None:
        raise ConfigError(f"sequence {name!r}: give a procedural spec or a scene file (render.scene), not both")
    return scene_path


def _settings(options: _Options, scene_path: Path | None, camera: str, lighting: str) -> dict[str, Any]:
    """What ``sequence.json`` records as the sequence's settings (a render with other settings is refused there)."""
    settings = {
        "frames": options.frames,
        "resolution": [options.width, options.height],
        "scales": options.scales,
        "lr_mode": options.lr_mode,
        "samples": options.samples,
        "lr_samples": options.lr_samples,
        "denoise": options.denoise,
        **({"denoise_prefilter": "none"} if options.denoise else {}),  # see stale_render
        "passes": ["emission"],  # buffers beyond the authors' layout (see stale_render)
        "filter_width": options.filter_width,
        "compression": options.compression,
        "half": options.half,
        "exposure": options.exposure,
        "blender": "bpy 5.0.1, Cycles CPU",
    }
    if scene_path is not None:  # only for files: procedural sidecars keep their settings (and resume)
        settings["scene"] = {"file": scene_path.name, "sha256": file_digest(scene_path)}
        settings["camera"], settings["lighting"] = camera, lighting
    return settings


def _previous_meta(folder: Path, seed: int, settings: dict[str, Any]) -> dict[str, Any] | None:
    """The sidecar of an earlier render into ``folder`` (None: there is none), refused when made with another seed
    or other settings."""
    sidecar = folder / "sequence.json"
    previous_meta = json.loads(sidecar.read_text()) if sidecar.exists() else None
    if previous_meta and (previous_meta.get("seed") != seed or previous_meta.get("settings") != settings):
        raise ConfigError(
            f"{folder} holds a sequence rendered with other settings (seed {previous_meta.get('seed')}); "
            "remove it or render into another folder"
        )
    return previous_meta


@dataclasses.dataclass(frozen=True)
class _Staged:
    """A sequence's scene before any frame is rendered: its camera (``lens``, ``poses`` of frames -1..frames), its
    description for the sidecar, and its Blender scene (a file's is loaded at once, a procedural one built only when
    a frame is to be rendered)."""

    lens: float
    poses: Mapping[int, np.ndarray]
    description: dict[str, Any]
    blender_scene: Callable[[], Any]


def _stage_scene(
    name: str,
    seed: int,
    options: _Options,
    spec: SceneSpec | None,
    objects: tuple[int, int],
    scene_path: Path | None,
    camera: str,
    lighting: str,
    settings: dict[str, Any],
) -> _Staged:
    """The sequence's scene: the procedural ``spec`` (``random_scene(seed)`` without one), or the scene file loaded
    and framed (before the folder is made: a file with no mesh, or no camera for camera=file, creates nothing)."""
    if scene_path is None:
        spec = spec or random_scene(seed, min_objects=objects[0], max_objects=objects[1])
        poses = {f: camera_pose(spec.camera, f) for f in range(-1, options.frames + 1)}
        return _Staged(spec.camera.lens, poses, spec.to_dict(), lambda: _procedural_scene(spec, options))
    from wdss.render.scene_file import FileScene

    loaded = FileScene(
        scene_path,
        seed=seed,
        frames=options.frames,
        resolution=(options.width, options.height),
        camera=camera,
        lighting=lighting,
        samples=options.samples,
        denoise=options.denoise,
        filter_width=options.filter_width,
        threads=options.threads,
        where=f"sequence {name!r}",
        digest=settings["scene"]["sha256"],
    )
    return _Staged(loaded.lens, loaded.poses, loaded.description, lambda: loaded)


def _procedural_scene(spec: SceneSpec, options: _Options) -> Any:
    """The procedural scene ``spec`` built in Blender (:class:`wdss.render.blender.BlenderScene`)."""
    from wdss.render.blender import BlenderScene

    return BlenderScene(
        spec,
        samples=options.samples,
        denoise=options.denoise,
        filter_width=options.filter_width,
        threads=options.threads,
    )


def _sidecar(
    name: str,
    seed: int,
    settings: dict[str, Any],
    options: _Options,
    staged: _Staged,
    previous_meta: dict[str, Any] | None,
) -> dict[str, Any]:
    """The sequence's ``sequence.json``: what made it, its conventions and cameras, and what an earlier render of it
    recorded (frame times, the exposure chosen, the noise ceiling)."""
    width, height, lens = options.width, options.height, staged.lens
    return {
        "name": name,
        "seed": seed,
        "layout": "unreal",
        "settings": settings,
        "intrinsics": {
            "lens_mm": lens,
            "sensor_width_mm": 36.0,
            "fx_fy_cx_cy": intrinsics(lens, width, height).tolist(),
        },
        "conventions": {
            "camera_to_world": "4x4, Blender camera: looks down -z, y up",
            "motion": "HR pixels, current minus previous screen position, y up",
            "depth": "planar camera depth, background 0",
        },
        "sampling": sampling_convention(
            options.lr_mode, options.filter_width, {height // s: s for s in options.scales}
        ),
        "scene": staged.description,
        "frames": [_frame_record(f, staged.poses[f], options.lr_mode) for f in range(options.frames + 1)],
        "render_seconds": (previous_meta or {}).get("render_seconds", {}),
        # The pre-exposure applied to the radiance of every frame (None until the probes have chosen it).
        "exposure": options.exposure if options.exposure != "auto" else (previous_meta or {}).get("exposure"),
        # The targets' noise ceiling measured on these frames (python -m wdss.bench noise --record) stays theirs.
        **({"noise": previous_meta["noise"]} if previous_meta and "noise" in previous_meta else {}),
    }


def _render(
    scene: Any,
    folder: Path,
    meta: dict[str, Any],
    todo: list[int],
    measure: bool,
    options: _Options,
    staged: _Staged,
    progress: tuple[Progress | None, Any],
) -> None:
    """Render the frames of ``todo`` in order, the exposure chosen first where it is still to be, and the sidecar
    rewritten after each frame with its time (a frame is done once it is recorded); then, with ``measure``, the
    targets' noise ceiling (``progress``: the bar and its task)."""
    sidecar = folder / "sequence.json"
    if meta["exposure"] is None:  # recorded before any file is written: a resumed render applies the same
        meta["exposure"] = _probe_exposure(scene, options.frames, options.width, options.height)
        _write_json(sidecar, meta)
    bar, task = progress
    for frame in todo:
        start = time.perf_counter()
        _render_frame(scene, folder, frame, options, staged, meta["exposure"])
        meta["render_seconds"][str(frame)] = round(time.perf_counter() - start, 3)
        _write_json(sidecar, meta)
        if bar is not None:
            bar.advance(task)
    if measure:
        from wdss.render.noise import measure_noise

        meta["noise"] = measure_noise(scene, folder, meta["exposure"], range(1, options.frames + 1))
        _write_json(sidecar, meta)


def _render_frame(scene: Any, folder: Path, frame: int, options: _Options, staged: _Staged, exposure: float) -> None:
    """Render and write one frame: its HR buffers, then each scale's LR buffers (point samples of the HR frame, or
    rendered at LR)."""
    from wdss.render.convert import to_buffers

    width, height, lens = options.width, options.height, staged.lens
    camera_to_world, previous = staged.poses[frame], staged.poses[frame - 1]
    hr = to_buffers(scene.render(frame, width, height), camera=camera_to_world, previous_camera=previous, lens=lens)
    _expose(hr, exposure)
    write_unreal_frame(folder / f"{height}P", frame, hr, options.compression, options.half)
    for s in options.scales:
        size = lr_size(height, width, s)
        if options.lr_mode == "downsample":
            lr = {k: point_sample(torch.from_numpy(v)[None], size)[0].numpy() for k, v in hr.items()}
        else:
            jitter = _lr_jitter(options.lr_mode, frame)
            passes = scene.render(frame, size[1], size[0], samples=options.lr_samples, jitter=jitter)
            lr = to_buffers(passes, camera=camera_to_world, previous_camera=previous, lens=lens, motion_scale=float(s))
            _expose(lr, exposure)
        write_unreal_frame(folder / f"{size[0]}P", frame, lr, options.compression, options.half)


# What a config (or one of its sequences) may set: render_sequence's keyword options.
_SETTINGS = set(inspect.signature(render_sequence).parameters) - {"out_dir", "name", "seed", "progress", "spec"}


def _probe_exposure(scene: Any, frames: int, width: int, height: int) -> float:
    """The sequence's auto exposure from quick quarter-size renders of its first, middle and last frames: one
    frame can be unrepresentative of a camera path (a lamp filling the first view)."""
    size = (max(8, width // 4), max(8, height // 4))
    # Without the denoiser: OpenImageDenoise is not bit-reproducible across runs, and the exposure scales every
    # frame, so a render of the same seed must find the same factor (16 spp here cost ~1 spp of a full frame).
    denoise, scene.denoise = scene.denoise, False
    try:
        probes = [scene.render(f, *size, samples=16)["Combined"][:3] for f in sorted({0, frames // 2, frames})]
    finally:
        scene.denoise = denoise
    return auto_exposure(np.concatenate(probes, axis=-1))


def render_sequences(out_dir: str | Path, sequences: Iterable[Mapping[str, Any]], **settings: Any) -> list[Path]:
    """Render every ``{name, seed[, frames, scene, camera, lighting, ...]}`` of ``sequences`` into ``out_dir``
    with a shared progress bar; a sequence's own keys override ``settings``.

    Every sequence's scene settings are checked before the first is rendered."""
    out_dir = Path(out_dir)
    sequences = [dict(s) for s in sequences]
    keys = _SETTINGS
    unknown = sorted(set(settings) - keys)
    if unknown:
        raise ConfigError(f"render: unknown setting(s) {', '.join(unknown)}; known: {', '.join(sorted(keys))}")
    names: set[str] = set()
    for index, seq in enumerate(sequences):
        if "name" not in seq or "seed" not in seq:
            raise ConfigError(f"render.sequences[{index}] needs a name and a seed; got {seq}")
        where = f"sequence {seq['name']!r}"
        unknown = sorted(set(seq) - keys - {"name", "seed"})
        if unknown:
            raise ConfigError(f"render.sequences[{index}] ({where}): unknown key(s) {', '.join(unknown)}")
        if seq["name"] in names:
            raise ConfigError(f"render.sequences[{index}]: {where} appears twice (one folder each)")
        names.add(seq["name"])
        merged = {**settings, **seq}
        check_scene(merged.get("scene"), merged.get("camera", "auto"), merged.get("lighting", "auto"), where=where)
    columns = (
        TextColumn("[bold]{task.description}"),
        BarColumn(),
        MofNCompleteColumn(),
        TextColumn("{task.fields[rate]}"),
        TimeRemainingColumn(),
    )
    # rich draws nothing into a log file or pipe (e.g. `make data > log`): plain lines there instead
    reporter = _RateProgress(*columns, transient=False) if sys.stdout.isatty() else _LineProgress()
    with reporter as progress:
        folders = []
        for seq in sequences:
            overrides = {k: v for k, v in seq.items() if k not in ("name", "seed")}  # e.g. per-sequence frames
            folders.append(
                render_sequence(out_dir, seq["name"], int(seq["seed"]), **{**settings, **overrides}, progress=progress)
            )
        return folders


class _RateProgress(Progress):
    """A progress bar whose tasks show frames per second (rich's speed estimate)."""

    def add_task(self, *args: Any, **kwargs: Any):  # type: ignore[override]
        kwargs.setdefault("rate", "")
        return super().add_task(*args, **kwargs)

    def advance(self, task_id, advance: float = 1) -> None:  # type: ignore[override]
        super().advance(task_id, advance)
        task = self._tasks[task_id]
        speed = task.speed
        self.update(task_id, rate=f"{speed:.2f} frames/s" if speed else "")


class _LineProgress:
    """The part of rich's Progress that :func:`render_sequence` uses, as one flushed line per finished frame."""

    def __init__(self) -> None:
        self._tasks: list[dict[str, Any]] = []

    def __enter__(self) -> _LineProgress:
        return self

    def __exit__(self, *exc: object) -> None:
        return None

    def add_task(self, description: str, total: float, completed: float = 0, **_: Any) -> int:
        done = int(completed)
        self._tasks.append({"name": description, "total": int(total), "done": done, "resumed": done})
        self._tasks[-1]["start"] = time.perf_counter()
        if completed:
            print(f"render {description}: {int(completed)}/{int(total)} frames already on disk", flush=True)
        return len(self._tasks) - 1

    def advance(self, task_id: int, advance: float = 1) -> None:
        task = self._tasks[task_id]
        task["done"] += int(advance)
        # Seconds per frame rendered by this run (the scene's set-up included), not counting resumed frames.
        rate = (time.perf_counter() - task["start"]) / max(task["done"] - task["resumed"], 1)
        eta = duration(rate * (task["total"] - task["done"]))
        line = f"render {task['name']}: frame {task['done']}/{task['total']} ({rate:.1f} s/frame, ETA {eta})"
        print(line, flush=True)


def preset_settings(name: str) -> dict[str, Any]:
    """The settings of ``conf/render/<name>.yaml`` exactly as ``python -m wdss.render -cn <name>`` composes them.

    A config loader of its own composes the preset, not ``hydra.initialize_config_dir``: that refuses to run
    inside a Hydra app (``wdss.train``, whose DataModule renders its dataset on first use), and the app's
    own loader may not search ``conf/render``. The ``hydra`` node of the preset is dropped.
    """
    from hydra import version
    from hydra._internal.config_loader_impl import ConfigLoaderImpl
    from hydra._internal.utils import create_config_search_path
    from hydra.types import RunMode
    from omegaconf import OmegaConf, open_dict

    from wdss.paths import CONF_DIR

    version.setbase("1.3")  # as `python -m wdss.render` (every entry point of the project uses 1.3)
    loader = ConfigLoaderImpl(config_search_path=create_config_search_path(str(CONF_DIR / "render")))
    cfg = loader.load_configuration(config_name=name, overrides=[], run_mode=RunMode.RUN, from_shell=False)
    with open_dict(cfg):
        del cfg["hydra"]
    return OmegaConf.to_container(cfg, resolve=True)


def stale_render(meta: Mapping[str, Any]) -> str | None:
    """Why a sequence wdss rendered earlier (its ``sequence.json``) should be rendered again, or ``None``.

    Earlier versions ran OpenImageDenoise with its prefilter on frames of 200 pixels and more, which blurred
    pixel-scale texture out of the high-resolution targets, and wrote no emission pass, without which emitters are
    demodulated as if lit; later ones still recorded no sampling convention, and the presets point-sampled their LR
    folders from the HR frame (when each changed: docs/results.md)."""
    settings = meta.get("settings") or {}
    prefiltered = settings.get("denoise") and min(settings.get("resolution") or [0]) >= 200
    if prefiltered and "denoise_prefilter" not in settings:
        return "its targets were denoised with OIDN's prefilter, which blurred pixel-scale texture out of them"
    if "emission" not in (settings.get("passes") or []):
        return "it has no emission pass (Emissive.NNNN.exr), which demodulation subtracts from the colour"
    if "sampling" not in meta:
        return (
            "it records no LR sampling convention (its LR folders were point-sampled from the HR frame; the presets "
            "now render them natively, as an engine renders its LR frame)"
        )
    return None


def render_preset(out_dir: str | Path, name: str = "mini") -> list[Path]:
    """Render the sequences of ``conf/render/<name>.yaml`` into ``out_dir`` (a DataModule's ``prepare``)."""
    settings = preset_settings(name)
    for key in ("out_dir", "preview", "preview_frame"):
        settings.pop(key, None)
    print(f"wdss: rendering the {name!r} dataset into {out_dir} (Blender Cycles on the CPU; resumable)", flush=True)
    return render_sequences(out_dir, settings.pop("sequences"), **settings)


class RenderOnFirstUse:
    """A DataModule's ``prepare`` (``data.prepare``, a :class:`wdss.data.prepare.Preparer`): render the preset
    ``conf/render/<name>.yaml`` into the dataset's own folder ``home`` when it does not exist yet, or resume
    that render. A ``data.root`` elsewhere that does not exist is refused (:meth:`refusal`), so that a typo
    renders nothing; ``anywhere=True`` renders the preset into any ``data.root``."""

    def __init__(self, name: str = "mini", home: str | Path | None = None, anywhere: bool = False) -> None:
        self.name, self.home, self.anywhere = name, None if home is None else Path(home), bool(anywhere)

    def refusal(self, root: str | Path) -> str | None:
        """Why ``root`` is not rendered into (None: it is), checked before anything is created."""
        root = Path(root)
        if root.exists() or self.anywhere or self.home is None or root.resolve() == self.home.resolve():
            return None
        return (
            f"data root {root} does not exist (the {self.name!r} dataset renders on first use only into "
            f"{self.home}; to render it into {root}: data.prepare.anywhere=true)"
        )

    def resumes(self, root: str | Path) -> bool:
        """Whether a render stopped part-way in the existing folder ``root`` is this preset's to resume: only in
        its own folder (or anywhere, when asked), never in a folder of other frames that lacks a split's sequence."""
        return self.anywhere or (self.home is not None and Path(root).resolve() == self.home.resolve())

    def stale(self, meta: Mapping[str, Any]) -> str | None:
        """Why a sequence rendered earlier (its ``sequence.json``) must be rendered again (:func:`stale_render`)."""
        return stale_render(meta)

    def outdated(self, rendered: Mapping[str, Mapping[str, Any]]) -> str | None:
        """Why sequences rendered earlier into this preset's folder (``sequence.json`` by name) are not the preset's
        today (another seed or frame count: the preset changed since), or ``None``. Resuming would mix the two."""
        preset = preset_settings(self.name)
        for seq in preset["sequences"]:
            meta = rendered.get(seq["name"])
            if meta is None:
                continue
            frames = int(seq.get("frames", preset["frames"]))
            then = (meta.get("seed"), int((meta.get("settings") or {}).get("frames", -1)))
            if then != (int(seq["seed"]), frames):
                return (
                    f"{seq['name']} was rendered from an earlier version of the {self.name!r} preset (seed {then[0]}, "
                    f"{then[1]} frames; now seed {seq['seed']}, {frames} frames)"
                )
        return None

    def __call__(self, root: str | Path) -> list[Path]:
        why = self.refusal(root)
        if why:
            raise SceneError(why)
        return render_preset(root, self.name)
