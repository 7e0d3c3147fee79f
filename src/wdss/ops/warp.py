"""Temporal reprojection and the spatial and temporal masks (docs/reference.md sections 4 and 6).

Motion vectors are in high-resolution pixels, current minus previous screen position, with y pointing up.
A pixel at column x, row y of the current frame was at column ``x - mv_x`` and row ``y + mv_y`` (rows grow
downwards) of the previous frame; :func:`warp_backward` samples the previous frame there, bilinearly, with
zeros outside the frame.
"""

from __future__ import annotations

import torch
import torch.nn.functional as F
from torch import Tensor

from wdss.ops.sampling import upsample

__all__ = ["normalize_normals", "spatial_mask", "temporal_mask", "warp_backward"]


def warp_backward(previous: Tensor, motion: Tensor, *, origin: tuple[int, int] = (0, 0)) -> Tensor:
    """Previous-frame buffers ``(N, C, H', W')`` resampled into the current frame by ``motion`` ``(N, 2, H, W)``.

    ``origin``: where the current window's top-left pixel is in ``previous`` (rows, columns); ``(m, m)`` for
    previous buffers cut with a margin of ``m`` pixels on every side, so that history from outside the window is
    found. Without an origin, both cover the same pixels.
    """
    _, _, h, w = previous.shape
    mh, mw = motion.shape[-2:]
    oy, ox = origin
    if (oy, ox) == (0, 0) and (mh, mw) != (h, w):
        raise ValueError(f"motion vectors are {(mh, mw)}, the warped buffers {(h, w)}")
    ys = torch.arange(oy, oy + mh, device=motion.device, dtype=motion.dtype).view(1, mh, 1)
    xs = torch.arange(ox, ox + mw, device=motion.device, dtype=motion.dtype).view(1, 1, mw)
    # Pixel centres in grid_sample's normalised coordinates (align_corners=False: -1 and 1 are the edges).
    src_x = (xs + 0.5 - motion[:, 0]) * (2.0 / w) - 1.0
    src_y = (ys + 0.5 + motion[:, 1]) * (2.0 / h) - 1.0
    grid = torch.stack([src_x, src_y], dim=-1)
    # A NaN vector would poison its neighbours through the bilinear weights: send it outside (zeros).
    grid = torch.nan_to_num(grid, nan=-4.0, posinf=4.0, neginf=-4.0).clamp(-4.0, 4.0).to(previous.dtype)
    return F.grid_sample(previous, grid, mode="bilinear", padding_mode="zeros", align_corners=False)


def normalize_normals(normal: Tensor, eps: float = 1e-6) -> Tensor:
    """Unit normals; zero-length or non-finite ones become 0 (and so never count as similar)."""
    normal = torch.nan_to_num(normal, nan=0.0, posinf=0.0, neginf=0.0)
    length = (normal * normal).sum(1, keepdim=True).sqrt()  # much faster than Tensor.norm over dim 1 on CPU
    return torch.where(length > eps, normal / length.clamp_min(eps), torch.zeros_like(normal))


def spatial_mask(
    hr: dict[str, Tensor],
    lr: dict[str, Tensor],
    *,
    depth_threshold: float = 0.01,
    normal_threshold: float = 0.9,
    albedo_threshold: float = 0.1,
    jitter: Tensor | None = None,
) -> Tensor:
    """1 where the high-resolution G-buffer disagrees with the bilinearly upsampled low-resolution one (its pixels
    placed where they were shaded: ``jitter``, the batch key ``lr_jitter``).

    ``hr`` and ``lr`` hold ``depth``, ``normal`` and ``base_color``. A pixel is marked when
    ``|depth difference| > depth_threshold`` or ``n_hr . n_lr < normal_threshold`` or the mean absolute
    albedo difference exceeds ``albedo_threshold``. Returns ``(N, 1, H, W)`` of 0/1.
    """
    size = hr["depth"].shape[-2:]

    def up(t: Tensor) -> Tensor:
        return upsample(t, size, "bilinear", jitter)

    depth = (hr["depth"] - up(lr["depth"])).abs() > depth_threshold
    normal = (normalize_normals(hr["normal"]) * normalize_normals(up(lr["normal"]))).sum(1, keepdim=True)
    albedo = (hr["base_color"] - up(lr["base_color"])).abs().mean(1, keepdim=True) > albedo_threshold
    return (depth | (normal < normal_threshold) | albedo).to(hr["depth"].dtype)


def temporal_mask(current: dict[str, Tensor], warped_previous: dict[str, Tensor]) -> Tensor:
    """Continuous disagreement with the warped previous frame: ``(N, 5, H, W)``.

    Channels: ``|delta depth|``, ``|delta albedo|`` (3), ``(1 - n . n') / 2``. Pixels whose history fell outside
    the frame (warped normal 0) get the maximum normal term of 0.5.
    """
    depth = (current["depth"] - warped_previous["depth"]).abs()
    albedo = (current["base_color"] - warped_previous["base_color"]).abs()
    cos = (normalize_normals(current["normal"]) * normalize_normals(warped_previous["normal"])).sum(1, keepdim=True)
    return torch.cat([depth, albedo, (1.0 - cos) * 0.5], dim=1)
