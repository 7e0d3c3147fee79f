"""Training losses, each term weighted by config, on remodulated linear HDR colour (REFERENCE.md section 6).

The image terms compare linear HDR colour by default, or ``log1p`` of it (``space="log"``).
Terms: ``wavelet`` (L1 between predicted coefficients and the analysis of the target irradiance),
``l1``, ``ssim`` (1 - SSIM), ``masked_l1`` (L1 inside the spatial mask), ``temporal`` (the change between
consecutive outputs against the change between consecutive targets, both previous frames warped; it needs
the previous prediction and does not collapse to plain L1), ``lpips`` (only with local backbone weights).
"""

from __future__ import annotations

from collections.abc import Mapping

import torch
import torch.nn.functional as F
from torch import Tensor, nn
from torchmetrics.functional.image import structural_similarity_index_measure

from wdss.wavelets import WaveletTransform

__all__ = ["LOSS_TERMS", "WDSSLoss", "temporal_difference_loss"]

LOSS_TERMS = ("wavelet", "l1", "ssim", "masked_l1", "temporal", "lpips")


def temporal_difference_loss(output: Tensor, warped_output_prev: Tensor, target: Tensor, warped_target_prev: Tensor):
    """``L1(y_hat_t - W(y_hat_{t-1}), y_t - W(y_{t-1}))``: penalises flicker the target does not have."""
    return F.l1_loss(output - warped_output_prev, target - warped_target_prev)


class WDSSLoss(nn.Module):
    """Weighted sum of the loss terms; ``weights`` maps term names to weights (0 or absent: off)."""

    def __init__(self, weights: Mapping[str, float], lpips: nn.Module | None = None, space: str = "linear") -> None:
        super().__init__()
        if space not in ("linear", "log"):
            raise ValueError(f"loss.space must be 'linear' or 'log', got {space!r}")
        self.space = space
        unknown = set(weights) - set(LOSS_TERMS)
        if unknown:
            raise ValueError(f"unknown loss terms {sorted(unknown)}: expected some of {', '.join(LOSS_TERMS)}")
        self.weights = {k: float(v) for k, v in weights.items() if v}
        if "lpips" in self.weights and lpips is None:
            raise ValueError(
                "loss.weights.lpips > 0 needs LPIPS backbone weights: set loss.lpips.backbone and loss.lpips.linear "
                "to local files (no package here ships ImageNet VGG weights), or set the LPIPS weight to 0"
            )
        self.lpips = lpips

    def forward(
        self,
        output: Tensor,
        target: Tensor,
        *,
        coefficients: Tensor | None = None,
        target_irradiance: Tensor | None = None,
        wavelet: WaveletTransform | None = None,
        spatial_mask: Tensor | None = None,
        temporal: tuple[Tensor, Tensor] | None = None,
    ) -> dict[str, Tensor]:
        """The terms and their weighted ``total``. ``output``/``target``: remodulated linear HDR colour.

        With ``space="log"`` the image terms compare ``log1p`` of the colours (DFASR's choice: highlights no
        longer dominate); the wavelet term always compares linear irradiance coefficients.
        """
        terms: dict[str, Tensor] = {}
        output, target = output.float(), target.float()  # losses in float32, also under mixed precision
        if self.space == "log":
            output, target = torch.log1p(output.clamp_min(0)), torch.log1p(target.clamp_min(0))
            if temporal is not None:
                temporal = (torch.log1p(temporal[0].clamp_min(0)), torch.log1p(temporal[1].clamp_min(0)))
        w = self.weights
        if "l1" in w:
            terms["l1"] = F.l1_loss(output, target)
        if "ssim" in w:
            ssim = structural_similarity_index_measure(
                output, target, data_range=1.0, gaussian_kernel=True, sigma=1.5, kernel_size=11
            )
            terms["ssim"] = 1.0 - ssim
        if "masked_l1" in w and spatial_mask is not None:
            terms["masked_l1"] = ((output - target).abs() * spatial_mask).mean()
        if "wavelet" in w and coefficients is not None and wavelet is not None and wavelet.transform != "none":
            reference = target_irradiance
            if wavelet.transform == "dwt":  # the network pads odd frames to even before its DWT head
                h, wd = reference.shape[-2:]
                reference = F.pad(reference, (0, wd % 2, 0, h % 2), mode="replicate")
            terms["wavelet"] = F.l1_loss(coefficients, wavelet.analysis(reference))
        if "temporal" in w and temporal is not None:
            warped_output_prev, warped_target_prev = temporal
            terms["temporal"] = temporal_difference_loss(output, warped_output_prev, target, warped_target_prev)
        if "lpips" in w and self.lpips is not None:
            terms["lpips"] = self.lpips(output.clamp(0, 1), target.clamp(0, 1)).mean()
        total = sum(w[name] * value for name, value in terms.items())
        terms["total"] = total if isinstance(total, Tensor) else torch.zeros((), device=output.device)
        return terms
