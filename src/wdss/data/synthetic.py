"""Synthetic scenes with known content, written in either layout: for tests, benchmarks and smoke runs.

The content is analytic: a textured plane translating by ``motion`` pixels per frame (so the motion vectors
are exact), a black, emissive patch (F = 0, colour 5: it must pass through demodulation), a textured emissive
patch (colour = irradiance * F + 2: only the emission buffer tells the two parts apart), depth beyond the far
plane in one corner, and irradiance = (colour - emission) / F known everywhere else. The emission buffer is
written only when asked (``emission=True``): the authors' and DFASR's data have none. Low-resolution folders are
nearest-exact point samples of the high-resolution buffers, as in the authors' data.
"""

from __future__ import annotations

import json
from collections.abc import Iterable
from pathlib import Path

import numpy as np
import torch

from wdss.data.exr import write_exr
from wdss.data.layouts import DFASRLayout, UnrealLayout
from wdss.ops.sampling import lr_size, point_sample

__all__ = ["synthetic_frame", "write_sequence"]


def synthetic_frame(frame: int, height: int, width: int, motion: tuple[float, float] = (1.0, -1.0), seed: int = 0):
    """The buffers of one frame, ``(C, H, W)`` float32 arrays, and its irradiance.

    ``motion`` is ``(mv_x, mv_y)``: the content moves right by ``mv_x`` and, y being up, down by ``-mv_y``
    pixels per frame.
    """
    rng = np.random.default_rng(seed)
    phase = rng.uniform(0, 2 * np.pi, size=4)
    v, u = np.meshgrid(np.arange(height, dtype=np.float64), np.arange(width, dtype=np.float64), indexing="ij")
    # Texture coordinates move with the content: the point at (u, v) now was at (u - mv_x, v + mv_y).
    tu, tv = u - motion[0] * frame, v + motion[1] * frame
    base = np.stack([0.5 + 0.4 * np.sin(0.7 * tu + phase[c]) * np.cos(0.5 * tv + phase[3]) for c in range(3)])
    metallic = ((np.floor(tu / 4) + np.floor(tv / 4)) % 2)[None]
    roughness = (0.5 + 0.45 * np.sin(0.3 * tu + 0.2 * tv))[None]
    specular = np.full((1, height, width), 0.5)
    depth = (2.0 + 0.05 * tu + 0.03 * tv)[None]
    normal = np.stack([0.3 * np.sin(0.2 * tu), 0.3 * np.cos(0.25 * tv), np.ones_like(tu)])
    normal /= np.linalg.norm(normal, axis=0, keepdims=True)
    nov = np.clip(normal[2:3], 0, 1)
    irradiance = np.stack([0.2 + 1.5 * (0.5 + 0.5 * np.sin(0.11 * tu + 0.07 * tv + c)) for c in range(3)])
    brdf = base + (1 - metallic) * 0.08 * specular
    color = irradiance * brdf
    # An emitter with black albedo (F = 0): its colour must survive demodulation untouched.
    emitter = (np.abs(tu - width / 2) < width / 8) & (np.abs(tv - height / 2) < height / 8)
    for buf in (base, specular):
        buf[:, emitter] = 0.0
    metallic[:, emitter] = 0.0
    color[:, emitter] = 5.0
    # A textured surface that also emits: demodulating its colour whole would divide the emission by F.
    glow = (np.abs(tu - width / 4) < width / 10) & (np.abs(tv - 3 * height / 4) < height / 10) & ~emitter
    emission = np.zeros_like(color)
    emission[:, emitter] = 5.0
    emission[:, glow] = 2.0
    color = color + np.where(glow, 2.0, 0.0)
    # Background beyond the far plane in the top-left corner of the screen (does not move).
    sky = (u < width / 6) & (v < height / 6)
    depth[:, sky] = 1e4
    buffers = {
        "color": color,
        "base_color": base,
        "depth": depth,
        "normal": normal,
        "specular": specular,
        "metallic": metallic,
        "roughness": roughness,
        "nov": nov,
        "motion": np.broadcast_to(np.array(motion).reshape(2, 1, 1), (2, height, width)).copy(),
        "emission": emission,
    }
    return {k: v.astype(np.float32) for k, v in buffers.items()}


def _downsample(buffers: dict[str, np.ndarray], size: tuple[int, int]) -> dict[str, np.ndarray]:
    return {k: point_sample(torch.from_numpy(v)[None], size)[0].numpy() for k, v in buffers.items()}


def _write_unreal(folder: Path, frame: int, buffers: dict[str, np.ndarray], compression: str, half: bool) -> None:
    files: dict[str, dict[str, np.ndarray]] = {}
    for buffer, slot in UnrealLayout.SLOTS.items():
        if buffer not in buffers:
            continue
        for channel, plane in zip(slot.channels, buffers[buffer], strict=True):
            files.setdefault(slot.stem, {})[channel] = plane
    for stem, channels in files.items():
        write_exr(folder / f"{stem}.{frame:04d}.exr", channels, compression=compression, half=half)


def _write_dfasr(
    folder: Path, prefix: str, frame: int, buffers: dict[str, np.ndarray], names: Iterable[str], compression: str
) -> None:
    files: dict[str, dict[str, np.ndarray]] = {}
    for buffer in names:
        slot = DFASRLayout.SLOTS[buffer]
        for channel, plane in zip(slot.channels, buffers[buffer], strict=True):
            files.setdefault(slot.stem, {})[channel] = plane
    for stem, channels in files.items():
        write_exr(folder / f"{prefix}{stem}.{frame:04d}.exr", channels, compression=compression)


def write_sequence(
    path: str | Path,
    *,
    layout: str = "unreal",
    frames: Iterable[int] = (1, 2, 3),
    size: tuple[int, int] = (24, 36),
    scales: Iterable[int] = (2, 3),
    motion: tuple[float, float] = (1.0, -1.0),
    compression: str = "zip",
    half: bool = False,
    cameras: bool = False,
    seed: int = 0,
    emission: bool = False,
) -> Path:
    """Write one synthetic sequence folder in ``layout`` (``unreal`` or ``dfasr``) and return its path; with
    ``emission``, the emission buffer too."""
    path = Path(path)
    height, width = size
    low = [lr_size(height, width, s) for s in scales]
    for frame in frames:
        hr = synthetic_frame(frame, height, width, motion, seed)
        if not emission:
            del hr["emission"]
        if layout == "unreal":
            _write_unreal(path / f"{height}P", frame, hr, compression, half)
            for lr_hw in low:
                _write_unreal(path / f"{lr_hw[0]}P", frame, _downsample(hr, lr_hw), compression, half)
        elif layout == "dfasr":
            gbuffers = [b for b in DFASRLayout.SLOTS if b != "color" and b in hr]
            _write_dfasr(path / f"GBuffer-{height}P", "Synthetic", frame, hr, gbuffers, compression)
            _write_dfasr(path / f"Nojitter-{height}P", "Synthetic", frame, hr, ["color"], compression)
            for lr_hw in low:
                lr = _downsample(hr, lr_hw)
                _write_dfasr(path / f"Nojitter-{lr_hw[0]}P", "Synthetic", frame, lr, list(lr), compression)
        else:
            raise ValueError(f"unknown layout {layout!r}: expected unreal or dfasr")
    if cameras:
        meta = {"frames": [{"frame": f, "camera_to_world": np.eye(4).tolist()} for f in frames], "seed": seed}
        (path / "sequence.json").write_text(json.dumps(meta, indent=1))
    return path
