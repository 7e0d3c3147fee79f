"""Tone mapping for metrics and pictures: linear HDR ``(..., 3, H, W)`` in, display values in [0, 1] out."""

from __future__ import annotations

import torch
from torch import Tensor

__all__ = ["TONEMAPS", "gamma", "hable", "reinhard", "srgb", "tonemap"]

# The WDSS authors' Hable ("Uncharted 2") constants, exposure and white point.
HABLE = {"A": 0.15, "B": 0.50, "C": 0.10, "D": 0.20, "E": 0.02, "F": 0.30}


def _hable_curve(x: Tensor) -> Tensor:
    a, b, c, d, e, f = (HABLE[k] for k in "ABCDEF")
    return (x * (a * x + c * b) + d * e) / (x * (a * x + b) + d * f) - e / f


def hable(x: Tensor, *, exposure: float = 10.0, white: float = 11.2) -> Tensor:
    """Hable's filmic curve of ``exposure * x``, normalised by the curve at ``white``, clamped to [0, 1]."""
    # The curve saturates long before 1e6, and its quadratic terms would overflow near float32's maximum.
    x = torch.nan_to_num(x, nan=0.0).clamp(0.0, 1e6)
    white_scale = 1.0 / _hable_curve(torch.tensor(white, dtype=x.dtype, device=x.device))
    return (_hable_curve(exposure * x) * white_scale).clamp(0.0, 1.0)


def reinhard(x: Tensor) -> Tensor:
    """``x / (1 + x)``."""
    x = x.clamp_min(0.0)
    return x / (1.0 + x)


def srgb(x: Tensor) -> Tensor:
    """The sRGB transfer function (piecewise: linear toe, 2.4 power) of ``x`` clamped to [0, 1]."""
    x = x.clamp(0.0, 1.0)
    return torch.where(x <= 0.0031308, 12.92 * x, 1.055 * x.clamp_min(0.0031308) ** (1 / 2.4) - 0.055)


def gamma(x: Tensor, power: float = 2.2) -> Tensor:
    """DFASR's tone mapping: ``x^(1/power)`` clamped to [0, 1]."""
    return x.clamp(0.0, 1.0) ** (1.0 / power)


TONEMAPS = {"hable": hable, "reinhard": reinhard, "srgb": srgb, "gamma": gamma}


def tonemap(x: Tensor, name: str = "hable") -> Tensor:
    """Apply the tone map called ``name`` (``hable``, ``reinhard``, ``srgb`` or ``gamma``)."""
    if name not in TONEMAPS:
        raise ValueError(f"unknown tone map {name!r}: expected one of {', '.join(TONEMAPS)}")
    return TONEMAPS[name](x)
