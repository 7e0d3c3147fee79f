"""BRDF factors for demodulation: irradiance = colour / F, colour = irradiance * F.

Two factors, chosen by config:

* :func:`extranet_brdf` (the authors' and ExtraNet's): ``F = base + (1 - metallic) * 0.08 * specular``.
* :func:`split_sum_brdf`: the split-sum pre-integrated BRDF, ``F = diffuse + F0 * A + B`` with
  ``diffuse = base (1 - metallic)``, ``F0 = 0.08 specular (1 - metallic) + base metallic`` and ``(A, B)`` from
  a lookup table over ``(NoV, roughness)`` that wdss integrates itself (GGX, Smith height-correlated
  visibility, Schlick Fresnel; :func:`ggx_lut`).

Where F is zero or tiny (sky, emitters, black albedo) a division would blow up or lose the pixel; there the
factor tends to 1 (:func:`safe_brdf`), so the pixel passes through un-demodulated and remodulates to exactly
itself. How it gets there matters: a hard switch at ``F = 1e-4`` (``knee=0``, wdss's earlier factor) divides a
pixel with ``F = 0.001`` by 0.001 beside a sky pixel divided by 1. Filtered G-buffers whose filter has long tails
(or noisy ones) are full of such pixels near every silhouette against the sky, and their irradiance is 1000x
their neighbours', which every upsampler spreads: on such G-buffers bilinear and joint bilateral upsampling fall
far below their scores on clean ones (docs/results.md, "Data conventions and what they change"). ``knee > 0``
blends continuously, ``F + (1 - F) exp(-(F / knee)^2)``: 1 at ``F = 0``, F itself (to 1e-4) above ``4 knee``,
never below ~0.05 for the default ``knee = 0.02``. Demodulation and remodulation use the same factor, so any
positive factor is exact; the knee only decides how smooth the demodulated signal is. The default was chosen
on scenes rendered for the choice, no test scene: it changes nothing measurable on clean or Blender-anti-aliased
renders and recovers most of the loss above; larger knees gain more there but leave dark albedo partly modulated
(docs/decisions.md).
Every function works on ``(N, C, H, W)`` tensors.
"""

from __future__ import annotations

import functools
import math

import numpy as np
import torch
import torch.nn.functional as F
from torch import Tensor

__all__ = [
    "BRDF_EPS",
    "BRDF_KNEE",
    "demodulate",
    "extranet_brdf",
    "ggx_lut",
    "remodulate",
    "safe_brdf",
    "split_sum_brdf",
]

BRDF_EPS = 1e-4  # knee 0: at or below this F counts as zero and the pixel passes through
BRDF_KNEE = 0.02  # F under about this blends continuously to 1 (data.preprocessing.brdf_knee)


def extranet_brdf(base_color: Tensor, metallic: Tensor, specular: Tensor) -> Tensor:
    """``F = base + (1 - metallic) * 0.08 * specular`` (3 channels)."""
    return base_color + (1.0 - metallic) * 0.08 * specular


def split_sum_brdf(base_color: Tensor, metallic: Tensor, specular: Tensor, roughness: Tensor, nov: Tensor) -> Tensor:
    """Pre-integrated (split-sum) BRDF: ``base (1 - m) + F0 A(NoV, r) + B(NoV, r)`` (3 channels)."""
    lut = ggx_lut(device=base_color.device, dtype=base_color.dtype)  # (2, R, V)
    # grid_sample coordinates: x indexes NoV (last axis), y roughness; cell centres span [-1, 1].
    grid = torch.stack([nov.clamp(0, 1) * 2 - 1, roughness.clamp(0, 1) * 2 - 1], dim=-1)[:, 0]  # (N, H, W, 2)
    scale_bias = F.grid_sample(
        lut.expand(grid.shape[0], -1, -1, -1), grid, mode="bilinear", padding_mode="border", align_corners=True
    )
    f0 = 0.08 * specular * (1.0 - metallic) + base_color * metallic
    return base_color * (1.0 - metallic) + f0 * scale_bias[:, :1] + scale_bias[:, 1:]


def safe_brdf(brdf: Tensor, eps: float = BRDF_EPS, knee: float = BRDF_KNEE) -> Tensor:
    """The factor to divide by: ``knee=0``: F with every channel at or below ``eps`` (or not finite) replaced by 1;
    ``knee > 0``: ``F + (1 - F) exp(-(F / knee)^2)`` (non-finite and negative F count as 0), continuous in F."""
    if knee < 0:
        raise ValueError(f"the BRDF knee must be >= 0, got {knee}")
    if knee == 0:
        return torch.where(torch.isfinite(brdf) & (brdf > eps), brdf, torch.ones_like(brdf))
    brdf = torch.nan_to_num(brdf, nan=0.0, posinf=0.0, neginf=0.0).clamp_min(0.0)
    return brdf + (1.0 - brdf) * torch.exp(-((brdf / knee) ** 2))


def demodulate(color: Tensor, brdf: Tensor) -> Tensor:
    """Irradiance ``color / F``; ``brdf`` must come from :func:`safe_brdf`."""
    return color / brdf


def remodulate(irradiance: Tensor, brdf: Tensor) -> Tensor:
    """Colour ``irradiance * F``; ``brdf`` must come from :func:`safe_brdf`."""
    return irradiance * brdf


# --------------------------------------------------------------------------------------------------------
# The pre-integrated GGX table
# --------------------------------------------------------------------------------------------------------


@functools.cache
def _ggx_lut_numpy(size: int = 32, samples: int = 512) -> np.ndarray:
    """(2, size, size) table of the split-sum scale A and bias B; rows roughness, columns NoV, both 0..1.

    Integrates ``int f_GGX (n.l) dl = F0 A + B`` by importance sampling the GGX normal distribution with a
    Hammersley point set (deterministic), as in Karis' split-sum approximation. Roughness is perceptual
    (alpha = roughness^2). NoV is clamped to half a cell above 0, where the integral is singular.
    """
    i = np.arange(samples)
    u1 = (i + 0.5) / samples
    u2 = np.array([int(f"{k:032b}"[::-1], 2) for k in i], dtype=np.float64) / 2**32  # radical inverse
    nov = np.clip(np.linspace(0.0, 1.0, size), 0.5 / size, 1.0)[None, :, None]
    rough = np.linspace(0.0, 1.0, size)[:, None, None]
    alpha = np.maximum(rough**2, 1e-4)
    # Half vector from GGX: cos(theta_h)^2 = (1 - u) / (1 + (alpha^2 - 1) u); phi = 2 pi u2.
    cos_h = np.sqrt((1.0 - u1) / (1.0 + (alpha**2 - 1.0) * u1))
    sin_h = np.sqrt(1.0 - cos_h**2)
    phi = 2 * math.pi * u2
    view = np.stack(np.broadcast_arrays(np.sqrt(1.0 - nov**2), 0 * nov, nov))  # (3, 1, size, 1)
    half = np.stack([sin_h * np.cos(phi), sin_h * np.sin(phi), cos_h + 0 * phi])  # (3, size, 1, S)
    voh = (view * half).sum(0)
    light = 2 * voh * half - view
    nol = np.clip(light[2], 0.0, 1.0)
    noh = np.clip(half[2], 0.0, 1.0)
    voh = np.clip(voh, 0.0, 1.0)
    a2 = alpha**2
    # Smith height-correlated visibility V = 0.5 / (NoL sqrt(NoV^2 (1-a2) + a2) + NoV sqrt(NoL^2 (1-a2) + a2)).
    vis = 0.5 / (nol * np.sqrt(nov**2 * (1 - a2) + a2) + nov * np.sqrt(nol**2 * (1 - a2) + a2) + 1e-12)
    # pdf(l) = D NoH / (4 VoH), so f NoL / pdf = V * 4 NoL VoH / NoH (the D cancels).
    weight = np.where(nol > 0, vis * 4 * nol * voh / np.maximum(noh, 1e-12), 0.0)
    fresnel = (1 - voh) ** 5
    scale = ((1 - fresnel) * weight).mean(-1)
    bias = (fresnel * weight).mean(-1)
    return np.stack([scale, bias]).astype(np.float64)


def ggx_lut(size: int = 32, *, device: torch.device | str | None = None, dtype: torch.dtype = torch.float32) -> Tensor:
    """The split-sum table as a ``(1, 2, size, size)`` tensor (channels A, B; rows roughness, columns NoV)."""
    return torch.as_tensor(_ggx_lut_numpy(size), dtype=dtype, device=device)[None]
