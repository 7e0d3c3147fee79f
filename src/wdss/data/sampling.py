"""Low-resolution grids, point sampling at any scale, patches and G-buffer-consistent flips.

Pixel grids are aligned at cell centres, the convention the network's INR offsets assume (LIIF's): an
image of ``n`` pixels covers ``[-1, 1]`` and pixel ``i`` has its centre at ``-1 + (2 i + 1) / n``. A
low-resolution frame at scale ``s`` of a ``H x W`` frame has ``h = round(H / s)`` rows (at least 1) and
covers the same extent, so its effective scale is ``H / h`` per axis (``s`` exactly when ``s`` divides
``H``). Low-resolution pixel ``i`` is the high-resolution pixel under its centre: ``floor((i + 0.5) H / h)``
(torch's ``nearest-exact``), i.e. point sampling as a rasteriser at the lower resolution would do.
"""

from __future__ import annotations

import numpy as np
import torch
import torch.nn.functional as F
from torch import Tensor

__all__ = ["crop", "flip", "lr_size", "point_sample", "scale_matches"]


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
