"""Low-resolution grids, point sampling at any scale, patches and G-buffer-consistent flips.

Pixel grids are aligned at cell centres, the convention the network's INR offsets assume (LIIF's): an
image of ``n`` pixels covers ``[-1, 1]`` and pixel ``i`` has its centre at ``-1 + (2 i + 1) / n``. A
low-resolution frame at scale ``s`` of a ``H x W`` frame has ``h = round(H / s)`` rows (at least 1) and
covers the same extent, so its effective scale is ``H / h`` per axis (``s`` exactly when ``s`` divides
``H``). Low-resolution pixel ``i`` is the high-resolution pixel under its centre: ``floor((i + 0.5) H / h)``
(torch's ``nearest-exact``), i.e. point sampling as a rasteriser at the lower resolution would do.

An engine that jitters its LR frame shades pixel ``i`` at ``i + 0.5 + j`` LR pixels instead (``j``: the frame's
sub-pixel jitter, x right and y down, in ``[-0.5, 0.5)``); :func:`halton_jitter` is the sequence wdss renders with,
and the batch key ``lr_jitter`` carries each sample's (flipped with the image: :func:`flip_jitter`).
"""

from __future__ import annotations

import numpy as np
import torch
import torch.nn.functional as F
from torch import Tensor

__all__ = [
    "JITTER_PHASES",
    "crop",
    "flip",
    "flip_jitter",
    "halton_jitter",
    "lr_size",
    "point_sample",
    "centred",
    "scale_matches",
    "upsample",
]

# Frames in one cycle of the jitter sequence (engines use 8 or 16 phases of Halton(2, 3)).
JITTER_PHASES = 8


def lr_size(height: int, width: int, scale: float) -> tuple[int, int]:
    """The low-resolution grid of a ``height x width`` frame at ``scale`` (>= 1)."""
    if not 1.0 <= scale <= 8.0:
        raise ValueError(f"scale must lie in [1, 8], got {scale}")
    return max(1, round(height / scale)), max(1, round(width / scale))


def point_sample(hr: Tensor, size: tuple[int, int]) -> Tensor:
    """Nearest-exact point sampling of ``(N, C, H, W)`` onto an ``h x w`` grid (cell centres aligned)."""
    if tuple(size) == tuple(hr.shape[-2:]):
        return hr
    return F.interpolate(hr, size=tuple(size), mode="nearest-exact")


def _radical_inverse(index: int, base: int) -> float:
    """The van der Corput radical inverse of ``index`` in ``base``: its digits mirrored about the point."""
    result, digit = 0.0, 1.0 / base
    while index:
        index, rest = divmod(index, base)
        result += rest * digit
        digit /= base
    return result


def halton_jitter(frame: int, phases: int = JITTER_PHASES) -> tuple[float, float]:
    """The sub-pixel jitter ``(x, y)`` of ``frame`` in LR pixels, in ``[-0.5, 0.5)``: Halton(2, 3) point
    ``1 + frame mod phases`` minus one half, as engines jitter their projection (TAA, DLSS, FSR)."""
    index = 1 + frame % phases
    return _radical_inverse(index, 2) - 0.5, _radical_inverse(index, 3) - 0.5


def flip_jitter(jitter: Tensor, *, horizontal: bool, vertical: bool) -> Tensor:
    """A ``(..., 2)`` jitter of a mirrored frame: a sample right of its pixel centre lies left of it once mirrored."""
    sign = torch.tensor([-1.0 if horizontal else 1.0, -1.0 if vertical else 1.0], dtype=jitter.dtype)
    return jitter * sign.to(jitter.device)


def centred(jitter: Tensor | None) -> bool:
    """Whether every sample's LR pixels were shaded at their centres (``jitter`` None or zero). Graphs being
    compiled or exported keep the jittered path: the answer would depend on the data."""
    return jitter is None or (not torch.compiler.is_compiling() and not bool(jitter.any()))


def upsample(x: Tensor, size: tuple[int, int], mode: str = "bilinear", jitter: Tensor | None = None) -> Tensor:
    """``x`` (N, C, h, w) interpolated (``bilinear`` or ``bicubic``) onto an ``H x W`` grid, cell centres aligned,
    its pixels taken as shaded where ``jitter`` (N, 2; x, y in LR pixels) says; ``None`` or zero: at their centres
    (``F.interpolate``). Beyond the outer samples, the border value."""
    if centred(jitter):
        return F.interpolate(x, size=tuple(size), mode=mode, align_corners=False)
    if jitter.shape != (x.shape[0], 2):
        raise ValueError(f"jitter {tuple(jitter.shape)} is not the (N, 2) jitter of {tuple(x.shape)}")
    (h, w), (height, width) = x.shape[-2:], size
    # Normalised grid coordinates (align_corners=False): the HR pixel centres, less each sample's jitter.
    ys = (2 * torch.arange(height, device=x.device, dtype=x.dtype) + 1) / height - 1
    xs = (2 * torch.arange(width, device=x.device, dtype=x.dtype) + 1) / width - 1
    shift = 2 * jitter.to(x.dtype) / torch.tensor([w, h], device=x.device, dtype=x.dtype)  # (N, 2)
    gx = xs.view(1, 1, width).expand(x.shape[0], height, width) - shift[:, 0].view(-1, 1, 1)
    gy = ys.view(1, height, 1).expand(x.shape[0], height, width) - shift[:, 1].view(-1, 1, 1)
    return F.grid_sample(x, torch.stack([gx, gy], -1), mode=mode, padding_mode="border", align_corners=False)


def crop(array: np.ndarray, window: tuple[int, int, int, int] | None) -> np.ndarray:
    """The ``(y, x, h, w)`` window of a ``(C, H, W)`` array; zeros where it reaches beyond the frame."""
    if window is None:
        return array
    y, x, h, w = window
    height, width = array.shape[-2:]
    if y >= 0 and x >= 0 and y + h <= height and x + w <= width:
        return array[..., y : y + h, x : x + w]
    out = np.zeros((*array.shape[:-2], h, w), dtype=array.dtype)
    y0, y1, x0, x1 = max(y, 0), min(y + h, height), max(x, 0), min(x + w, width)
    if y0 < y1 and x0 < x1:
        out[..., y0 - y : y1 - y, x0 - x : x1 - x] = array[..., y0:y1, x0:x1]
    return out


def scale_matches(hr_height: int, lr_height: int, scale: float, tol: float = 1e-6) -> bool:
    """Whether a native low-resolution folder of ``lr_height`` rows is the frame at ``scale``."""
    return abs(hr_height / lr_height - scale) <= tol * scale


def flip(buffers: dict[str, Tensor], *, horizontal: bool, vertical: bool, camera: Tensor | None = None) -> dict:
    """Mirror every buffer of a sample, keeping motion vectors and world-space normals consistent.

    A mirrored image is the image of the world mirrored in the plane through the camera spanned by its
    view direction and up axis (horizontal flip) or right axis (vertical flip). Screen-space motion changes
    sign along the flipped axis; a world-space normal is reflected in that plane, which needs the camera's
    world-space axes: ``camera`` is the 3x3 camera-to-world rotation (columns right, up, backward). Without
    it, normals cannot be mirrored correctly, and flipping is refused.
    """
    if not (horizontal or vertical):
        return buffers
    if "normal" in buffers and camera is None:
        raise ValueError(
            "flipping world-space normals needs the camera rotation of the frame; this scene has none "
            "(set the data augmentation's flip to false, or use a scene with camera metadata)"
        )
    dims = [d for d, on in ((-1, horizontal), (-2, vertical)) if on]
    out = {}
    for name, value in buffers.items():
        value = value.flip(dims)
        if name == "motion":
            sign = torch.tensor([-1.0 if horizontal else 1.0, -1.0 if vertical else 1.0], dtype=value.dtype)
            value = value * sign.view(-1, 1, 1).to(value.device)
        elif name == "normal":
            for axis, on in ((0, horizontal), (1, vertical)):
                if on:
                    a = camera[:, axis].to(value.dtype).to(value.device).view(3, 1, 1)
                    value = value - 2.0 * (value * a).sum(0, keepdim=True) * a
        out[name] = value
    return out
