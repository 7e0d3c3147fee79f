"""Training losses, each term weighted by config, on remodulated colour (docs/reference.md section 6).

The image terms compare colour in one space: ``linear`` HDR (the paper), ``log`` (``log1p``, DFASR), or
``tonemapped`` (the metric's display transform, so the loss weighs errors as PSNR/SSIM/FLIP will).
Terms: ``wavelet`` (L1 between predicted coefficients and the analysis of the target irradiance, in the space
the network's head predicts in: see ``WDSSNet.target_coefficients``),
``l1``, ``l2`` (mean squared error: its minimiser is the conditional mean, what PSNR rewards; L1's is the
median, which is the upsampler itself wherever the correction is small against the target's sampling noise),
``ssim`` (1 - SSIM), ``masked_l1`` (L1 inside the spatial mask), ``temporal`` (the change between
consecutive outputs against the change between consecutive targets, both previous frames warped; it needs
the previous prediction and does not collapse to plain L1), ``lpips`` (only with local backbone weights).
"""

from __future__ import annotations

from collections.abc import Mapping

import torch
import torch.nn.functional as F
from torch import Tensor, nn
from torchmetrics.functional.image import structural_similarity_index_measure

from wdss.ops.tonemap import ToneMap

__all__ = ["LOSS_SPACES", "LOSS_TERMS", "WDSSLoss", "temporal_difference_loss"]

LOSS_TERMS = ("wavelet", "l1", "l2", "ssim", "masked_l1", "temporal", "lpips")
LOSS_SPACES = ("linear", "log", "tonemapped")


def temporal_difference_loss(output: Tensor, warped_output_prev: Tensor, target: Tensor, warped_target_prev: Tensor):
    """``L1(y_hat_t - W(y_hat_{t-1}), y_t - W(y_{t-1}))``: penalises flicker the target does not have."""
    return F.l1_loss(output - warped_output_prev, target - warped_target_prev)


class WDSSLoss(nn.Module):
    """Weighted sum of the loss terms; ``weights`` maps term names to weights (0 or absent: off)."""

    def __init__(
        self,
        weights: Mapping[str, float],
        lpips: nn.Module | None = None,
        space: str = "linear",
        tone: ToneMap | None = None,
    ) -> None:
        super().__init__()
        if space not in LOSS_SPACES:
            raise ValueError(f"loss.space must be one of {', '.join(LOSS_SPACES)}, got {space!r}")
        self.space = space
        self.tone = tone or ToneMap()
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
        target_coefficients: Tensor | None = None,
        spatial_mask: Tensor | None = None,
        temporal: tuple[Tensor, Tensor] | None = None,
    ) -> dict[str, Tensor]:
        """The terms and their weighted ``total``. ``output``/``target``: remodulated linear HDR colour.

        ``coefficients``/``target_coefficients``: the predicted subbands and the analysis of the target in the
        same space (the network's :meth:`~wdss.nets.wdss.network.WDSSNet.target_coefficients`); the image terms
        compare ``output`` and ``target`` after mapping both into ``space``.
        """
        terms: dict[str, Tensor] = {}
        output, target = output.float(), target.float()  # losses in float32, also under mixed precision
        reference = target
        output, target = self.to_space(output, reference), self.to_space(target, reference)
        if temporal is not None:
            temporal = (self.to_space(temporal[0], reference), self.to_space(temporal[1], reference))
        w = self.weights
        if "l1" in w:
            terms["l1"] = F.l1_loss(output, target)
        if "l2" in w:
            terms["l2"] = F.mse_loss(output, target)
        if "ssim" in w:
            # SSIM's constants assume a known data range: 1 for display values, the target's range otherwise.
            data_range = 1.0 if self.space == "tonemapped" else float(target.detach().amax().clamp_min(1.0))
            ssim = structural_similarity_index_measure(
                output, target, data_range=data_range, gaussian_kernel=True, sigma=1.5, kernel_size=11
            )
            terms["ssim"] = 1.0 - ssim
        if "masked_l1" in w and spatial_mask is not None:
            # A mean over the masked pixels (all channels), not over the frame: the term's weight does not
            # shrink with the share of edges in the patch.
            inside = spatial_mask.expand_as(output)
            terms["masked_l1"] = ((output - target).abs() * inside).sum() / inside.sum().clamp_min(1.0)
        if "wavelet" in w and coefficients is not None and target_coefficients is not None:
            terms["wavelet"] = F.l1_loss(coefficients.float(), target_coefficients.float())
        if "temporal" in w and temporal is not None:
            warped_output_prev, warped_target_prev = temporal
            terms["temporal"] = temporal_difference_loss(output, warped_output_prev, target, warped_target_prev)
        if "lpips" in w and self.lpips is not None:
            terms["lpips"] = self.lpips(output.clamp(0, 1), target.clamp(0, 1)).mean()
        total = sum(w[name] * value for name, value in terms.items())
        terms["total"] = total if isinstance(total, Tensor) else torch.zeros((), device=output.device)
        return terms

    def to_space(self, color: Tensor, reference: Tensor) -> Tensor:
        """Linear colour mapped into the loss space (``reference``: the target, for an ``auto`` exposure)."""
        if self.space == "log":
            return torch.log1p(color.clamp_min(0))
        if self.space == "tonemapped":
            return self.tone(color, reference)
        return color
