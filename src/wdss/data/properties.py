"""Properties of data wdss did not render, given to frames it did: which of them breaks guidance?

Engines and other renderers hand over G-buffers that differ from wdss's point-sampled ones: anti-aliased
(filtered) albedo and normals beside unfiltered depth, normals not renormalised after filtering, noisy
few-sample G-buffers, emitters without an emission buffer, depth in other units, noisy LR colour. Each property
here turns a stacked raw batch (:class:`wdss.data.preprocess.RawBatch`, every role, before preprocessing) into one
with that property, so that every method is scored on the same frames through the same metric path with and
without it (``python -m wdss.bench guidance``). They imitate the property, not a renderer: ``filtered`` is a
Gaussian of 0.5 px on the rendered buffers, whose tails reach further than Cycles' 1.5 px Blackman-Harris
(render with ``filter_width=1.5`` for that one).
"""

from __future__ import annotations

from collections.abc import Callable, Iterable

import torch
import torch.nn.functional as F
from torch import Tensor

from wdss.data.preprocess import RawBatch

__all__ = ["PROPERTIES", "gaussian_blur", "with_properties"]

_FILTERED = ("color", "emission", "base_color", "normal", "metallic", "specular", "roughness", "nov")


def gaussian_blur(t: Tensor, sigma: float = 0.5, radius: int = 2) -> Tensor:
    """``t`` (N, C, H, W) filtered by a separable Gaussian of ``sigma`` pixels (borders repeated), in its dtype."""
    x = torch.arange(-radius, radius + 1, dtype=torch.float32, device=t.device)
    kernel = torch.exp(-(x**2) / (2 * sigma**2))
    kernel = kernel / kernel.sum()
    c = t.shape[1]
    out = F.pad(t.float(), (radius, radius, radius, radius), mode="replicate")
    out = F.conv2d(out, kernel.view(1, 1, 1, -1).expand(c, 1, 1, -1), groups=c)
    out = F.conv2d(out, kernel.view(1, 1, -1, 1).expand(c, 1, -1, 1), groups=c)
    return out.to(t.dtype)


def _filtered(role: str, buffers: dict[str, Tensor], g: torch.Generator) -> None:
    """Anti-aliased: colour and G-buffer filtered alike (at each role's own resolution), depth left unfiltered."""
    for name in _FILTERED:
        if name in buffers:
            buffers[name] = gaussian_blur(buffers[name])


def _no_emission(role: str, buffers: dict[str, Tensor], g: torch.Generator) -> None:
    """Emitters without an emission buffer: their light stays in the colour."""
    if "emission" in buffers:
        buffers["emission"] = torch.zeros_like(buffers["emission"])


def _unnormalised_normals(role: str, buffers: dict[str, Tensor], g: torch.Generator) -> None:
    """Normals of length 0.5-1, as filtered normals are when nobody renormalises them."""
    if "normal" in buffers:
        n = buffers["normal"]
        buffers["normal"] = n * (0.5 + 0.5 * torch.rand(n[:, :1].shape, generator=g)).to(n)


def _gbuffer_noise(role: str, buffers: dict[str, Tensor], g: torch.Generator) -> None:
    """Few-sample G-buffers: albedo and normals with Gaussian noise of 0.02 (albedo kept non-negative)."""
    for name in ("base_color", "normal"):
        if name in buffers:
            t = buffers[name].float() + 0.02 * torch.randn(buffers[name].shape, generator=g)
            buffers[name] = (t.clamp_min(0.0) if name == "base_color" else t).to(buffers[name].dtype)


def _lr_noise(role: str, buffers: dict[str, Tensor], g: torch.Generator) -> None:
    """A noisier LR colour (multiplicative Gaussian noise of 10 %), as a few-sample engine frame is."""
    if role in ("lr", "prev_lr") and "color" in buffers:
        c = buffers["color"].float()
        buffers["color"] = (c * (1 + 0.1 * torch.randn(c.shape, generator=g))).clamp_min(0.0).to(buffers["color"].dtype)


def _depth_in_centimetres(role: str, buffers: dict[str, Tensor], g: torch.Generator) -> None:
    """Depth in centimetres (Unreal's unit) instead of metres: the far clamp then cuts at 1 m."""
    if "depth" in buffers:
        buffers["depth"] = buffers["depth"].float() * 100


PROPERTIES: dict[str, Callable[[str, dict[str, Tensor], torch.Generator], None]] = {
    "filtered": _filtered,
    "no_emission": _no_emission,
    "unnormalised_normals": _unnormalised_normals,
    "gbuffer_noise": _gbuffer_noise,
    "lr_noise": _lr_noise,
    "depth_cm": _depth_in_centimetres,
}


def with_properties(raw: RawBatch, names: Iterable[str], generator: torch.Generator) -> RawBatch:
    """``raw`` with each named property (:data:`PROPERTIES`) given to every role's buffers, in place."""
    names = list(names)
    unknown = [n for n in names if n not in PROPERTIES]
    if unknown:
        raise ValueError(f"unknown data properties {unknown}; known: {', '.join(PROPERTIES)}")
    for role, buffers in raw.roles.items():
        for name in names:
            PROPERTIES[name](role, buffers, generator)
    if "depth_cm" in names:  # the frames' depth ranges are read with the depth: in the same unit
        raw.ranges = {role: r * 100 for role, r in raw.ranges.items()}
    return raw
