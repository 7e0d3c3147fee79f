"""Tone mapping for metrics and pictures: linear HDR ``(..., 3, H, W)`` in, display values in [0, 1] out."""

from __future__ import annotations

import torch
from torch import Tensor

__all__ = ["TONEMAPS", "ToneMap", "gamma", "hable", "luminance", "median_luminance", "reinhard", "srgb", "tonemap"]

# The WDSS authors' Hable ("Uncharted 2") constants, exposure and white point.
HABLE = {"A": 0.15, "B": 0.50, "C": 0.10, "D": 0.20, "E": 0.02, "F": 0.30}


def _hable_curve(x: Tensor) -> Tensor:
    a, b, c, d, e, f = (HABLE[k] for k in "ABCDEF")
    return (x * (a * x + c * b) + d * e) / (x * (a * x + b) + d * f) - e / f


def hable(x: Tensor, *, exposure: float | Tensor = 10.0, white: float = 11.2) -> Tensor:
    """Hable's filmic curve of ``exposure * x``, normalised by the curve at ``white``, clamped to [0, 1].

    ``exposure`` may be a tensor that broadcasts against ``x`` (one exposure per image: ``(N, 1, 1, 1)``).
    """
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


def tonemap(x: Tensor, name: str = "hable", exposure: float | Tensor | None = None) -> Tensor:
    """Apply the tone map called ``name`` (``hable``, ``reinhard``, ``srgb`` or ``gamma``).

    ``exposure``: Hable's exposure (default 10, the authors'); for the other curves a factor applied to ``x``
    first (default 1).
    """
    if name not in TONEMAPS:
        raise ValueError(f"unknown tone map {name!r}: expected one of {', '.join(TONEMAPS)}")
    if exposure is None:
        return TONEMAPS[name](x)
    if name == "hable":
        return hable(x, exposure=exposure)
    return TONEMAPS[name](x * exposure)


DEFAULT_EXPOSURE = {"hable": 10.0}  # the curve's own exposure; 1 for the others
MIDDLE_GREY = 0.18  # the linear median luminance that each curve's default exposure shows well (Hable: 0.46)


def luminance(x):
    """Rec. 709 luminance of linear colour ``(..., 3, H, W)`` (a torch tensor or a numpy array)."""
    return 0.2126 * x[..., 0, :, :] + 0.7152 * x[..., 1, :, :] + 0.0722 * x[..., 2, :, :]


def median_luminance(x: Tensor) -> Tensor:
    """Per-image median Rec. 709 luminance ``(N, 1, 1, 1)`` of linear colour ``(N, 3, H, W)``."""
    return torch.nan_to_num(luminance(x).flatten(1), nan=0.0).median(dim=1).values.view(-1, 1, 1, 1)


class ToneMap:
    """The display transform of metrics, pictures and tone-mapped losses: a curve and an exposure.

    ``exposure``: ``None`` (the curve's default: Hable's 10, which suits radiance pre-exposed as wdss's
    renderer writes it, median luminance ~0.18), a number, or ``"auto"``: per image, the default exposure
    times ``0.18 / median luminance`` of the *reference* (the target), for foreign data whose exposure wdss
    did not choose. The same exposure is applied to the prediction and the target of an image.
    """

    def __init__(self, name: str = "hable", exposure: float | str | None = None) -> None:
        if name not in TONEMAPS:
            raise ValueError(f"unknown tone map {name!r}: expected one of {', '.join(TONEMAPS)}")
        if not (exposure is None or exposure == "auto" or (isinstance(exposure, (int, float)) and exposure > 0)):
            raise ValueError(f"tone map exposure must be a positive number, null or 'auto', got {exposure!r}")
        self.name, self.exposure = name, exposure

    def exposure_for(self, reference: Tensor | None) -> float | Tensor | None:
        if self.exposure != "auto":
            return self.exposure
        if reference is None:
            raise ValueError("tone map exposure 'auto' needs the reference (target) image")
        base = DEFAULT_EXPOSURE.get(self.name, 1.0)
        return base * MIDDLE_GREY / median_luminance(reference.float()).clamp_min(1e-6)

    def __call__(self, x: Tensor, reference: Tensor | None = None) -> Tensor:
        """Tone-map ``x``; ``reference`` (the target, same batch) sets the exposure when it is ``"auto"``."""
        return tonemap(x, self.name, self.exposure_for(reference))
