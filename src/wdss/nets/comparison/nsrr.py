"""NSRR (Xiao et al. 2020, "Neural Supersampling for Real-time Rendering"), from its published description.

Per frame, a feature extractor on the low-resolution RGB-D; zero-upsampling of features to the output grid;
backward warping of the previous frame's upsampled features with the high-resolution motion vectors; a
feature-reweighting network that scores the warped history against the current frame (weights in [0, 10]);
a U-Net reconstruction of colour. This implementation uses one previous frame (NSRR used four) and reduced
widths by default; its loss in the paper is 1 - SSIM + 0.1 perceptual (here: the configured terms).

``skip=True`` (not NSRR's design; ``recipe.skip``, which ``experiment=cpu`` turns on) adds the U-Net's output to the
bilinearly upsampled LR colour (in log1p space): without it, a few hundred CPU steps learn the training scenes' mean
colour rather than to carry the LR colour through (docs/results.md, "methods" sweep).
"""

from __future__ import annotations

from collections.abc import Sequence

import torch
import torch.nn.functional as F
from torch import Tensor, nn

from wdss.nets.base import SuperResolutionNet
from wdss.nets.blocks import from_log, scale_exit, to_log
from wdss.ops.warp import warp_backward

__all__ = ["NSRR", "zero_upsample"]


def zero_upsample(x: Tensor, size: tuple[int, int]) -> Tensor:
    """Each low-resolution pixel at the output pixel under its cell centre, zeros elsewhere (NSRR's upsampling)."""
    n, c, h, w = x.shape
    rows = ((torch.arange(h, device=x.device) + 0.5) * size[0] / h).long().clamp_max(size[0] - 1)
    cols = ((torch.arange(w, device=x.device) + 0.5) * size[1] / w).long().clamp_max(size[1] - 1)
    out = x.new_zeros(n, c, *size)
    out[:, :, rows[:, None], cols[None, :]] = x
    return out


def _block(cin: int, cout: int) -> nn.Sequential:
    return nn.Sequential(nn.Conv2d(cin, cout, 3, padding=1), nn.ReLU(), nn.Conv2d(cout, cout, 3, padding=1), nn.ReLU())


class NSRR(SuperResolutionNet):
    """NSRR with one history frame. ``widths``: feature extractor; ``unet``: U-Net widths per level."""

    def __init__(
        self,
        widths: Sequence[int] = (32, 32, 8),
        unet: Sequence[int] = (64, 128),
        reweight_width: int = 32,
        input_log: bool = True,
        skip: bool = False,
    ) -> None:
        super().__init__()
        self.input_log, self.skip = input_log, bool(skip)
        layers: list[nn.Module] = []
        cin = 4  # RGB-D
        for width in widths:
            layers += [nn.Conv2d(cin, width, 3, padding=1), nn.ReLU()]
            cin = width
        self.extract = nn.Sequential(*layers)
        features = 4 + widths[-1]  # NSRR concatenates the extracted features with the RGB-D input
        self.reweight = nn.Sequential(
            nn.Conv2d(8, reweight_width, 3, padding=1), nn.ReLU(),
            nn.Conv2d(reweight_width, reweight_width, 3, padding=1), nn.ReLU(),
            nn.Conv2d(reweight_width, 1, 3, padding=1), nn.Tanh(),
        )  # fmt: skip
        self.encoders = nn.ModuleList()
        cin = 2 * features
        for width in unet:
            self.encoders.append(_block(cin, width))
            cin = width
        self.decoders = nn.ModuleList()
        for width in reversed(unet[:-1]):
            self.decoders.append(_block(cin + width, width))
            cin = width
        self.out = nn.Conv2d(cin, 3, 3, padding=1)
        if self.skip:
            scale_exit(self.out)

    @property
    def inputs(self) -> tuple[str, ...]:
        return ("lr_color", "lr_gbuffer", "prev_lr_color", "prev_lr_gbuffer", "motion")

    def _rgbd(self, color: Tensor, gbuffer: Tensor) -> Tensor:
        color = to_log(color) if self.input_log else color
        return torch.cat([color, gbuffer[:, :1]], 1)

    def forward(
        self,
        lr_color: Tensor,
        lr_gbuffer: Tensor,
        prev_lr_color: Tensor,
        prev_lr_gbuffer: Tensor,
        motion: Tensor,
        brdf: Tensor,
    ) -> dict:
        size = motion.shape[-2:]
        current, previous = self._rgbd(lr_color, lr_gbuffer), self._rgbd(prev_lr_color, prev_lr_gbuffer)
        cur = zero_upsample(torch.cat([current, self.extract(current)], 1), size)
        prev = warp_backward(zero_upsample(torch.cat([previous, self.extract(previous)], 1), size), motion)
        weight = 5.0 * (self.reweight(torch.cat([cur[:, :4], prev[:, :4]], 1)) + 1.0)  # in [0, 10]
        x = torch.cat([cur, prev * weight], 1)
        skips = []
        for index, encoder in enumerate(self.encoders):
            x = encoder(x if index == 0 else F.max_pool2d(x, 2, ceil_mode=True))
            skips.append(x)
        for decoder, skip in zip(self.decoders, reversed(skips[:-1]), strict=True):
            x = F.interpolate(x, size=skip.shape[-2:], mode="bilinear", align_corners=False)
            x = decoder(torch.cat([x, skip], 1))
        color = self.out(x)
        if self.skip:
            upsampled = F.interpolate(lr_color.float(), size=size, mode="bilinear", align_corners=False)
            color = color + (to_log(upsampled) if self.input_log else upsampled)
        color = from_log(color) if self.input_log else color.clamp_min(0)
        # NSRR reconstructs colour: colour / F goes through the shared remodulation unchanged.
        return {"irradiance": color / brdf, "coefficients": None}
