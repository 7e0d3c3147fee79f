"""FuseSR (Zhong et al. 2023, "FuseSR: Super Resolution for Real-time Rendering through Efficient Multi-resolution
Fusion"), from its published description.

A 7-channel low-resolution encoder (irradiance, depth, normal); high-resolution G-buffers and BRDF brought onto
the low-resolution grid by ``pixel_unshuffle(s)`` and fused there (the "H-Net"); two history frames warped to the
current one and gated by an attention computed from them and the current features; residual blocks;
``pixel_shuffle(s)`` upsampling; the result is irradiance, multiplied by the BRDF by the shared remodulation.
FuseSR is a fixed-integer-scale method (x4, x8 in the paper): other scales are refused. Widths are reduced by
default (the paper: 6 residual blocks at 128 channels).

``skip=True`` (``recipe.skip``, which ``experiment=cpu`` turns on) adds the output to the bilinearly upsampled LR
irradiance (in log1p space), so FuseSR starts near ``bilinear_demodulated``: without it, a few hundred CPU steps
leave regions rare in the training patches (the sky) far too dark (docs/results.md, "methods" sweep).
"""

from __future__ import annotations

import torch
import torch.nn.functional as F
from torch import Tensor, nn

from wdss.nets.base import SuperResolutionNet
from wdss.nets.blocks import DoubleResidual, from_log, scale_exit, to_log

__all__ = ["FuseSR"]


class FuseSR(SuperResolutionNet):
    """FuseSR for one integer ``scale``; ``width`` channels and ``blocks`` residual blocks."""

    fixed_scale = True  # benchmarks run it at its own scale

    def __init__(
        self, scale: int = 4, width: int = 32, blocks: int = 6, input_log: bool = True, skip: bool = False
    ) -> None:
        super().__init__()
        if int(scale) != scale or scale < 2:
            raise ValueError(f"FuseSR needs an integer scale >= 2 (model.net.scale), got {scale}")
        self.scale = s = int(scale)
        self.input_log, self.skip = input_log, bool(skip)
        self.encoder = nn.Sequential(nn.Conv2d(7, width, 3, padding=1), nn.ReLU())
        # HR depth, normal, albedo and BRDF (10 channels), folded onto the LR grid.
        self.hr_encoder = nn.Sequential(nn.Conv2d(10 * s * s, width, 3, padding=1), nn.ReLU())
        self.history = nn.Sequential(nn.Conv2d(3 * s * s, width, 3, padding=1), nn.ReLU())  # shared by both frames
        self.attention = nn.Conv2d(3 * width, 2, 3, padding=1)
        self.body = nn.Sequential(*[DoubleResidual(width) for _ in range(blocks)])
        self.up = nn.Conv2d(2 * width, 3 * s * s, 3, padding=1)
        if self.skip:
            scale_exit(self.up)

    @property
    def inputs(self) -> tuple[str, ...]:
        return ("lr", "lr_gbuffer", "gbuffer", "history", "history2")

    def _log(self, x: Tensor) -> Tensor:
        return to_log(x) if self.input_log else x

    def forward(
        self, lr: Tensor, lr_gbuffer: Tensor, gbuffer: Tensor, history: Tensor, history2: Tensor, brdf: Tensor
    ) -> dict:
        (h, w), (height, width), s = lr.shape[-2:], gbuffer.shape[-2:], self.scale
        if (h * s, w * s) != (height, width):
            raise ValueError(
                f"this FuseSR upsamples by {s}: LR {w}x{h} to {width}x{height} is another scale (FuseSR is a "
                "fixed-scale method: train and test it at one integer scale)"
            )
        features = self.encoder(torch.cat([self._log(lr), lr_gbuffer], 1))
        hr = torch.cat([gbuffer[:, [3, 4, 5, 6, 0, 1, 2]], brdf], 1)  # wdss.data.GBUFFER_STACK indices
        fused = features + self.hr_encoder(F.pixel_unshuffle(hr, s))
        histories = [self.history(F.pixel_unshuffle(self._log(x), s)) for x in (history, history2)]
        gates = torch.sigmoid(self.attention(torch.cat([fused, *histories], 1)))  # motion-vector attention
        x = self.body(fused + gates[:, :1] * histories[0] + gates[:, 1:] * histories[1])
        out = F.pixel_shuffle(self.up(torch.cat([x, fused], 1)), s)
        if self.skip:
            out = out + self._log(F.interpolate(lr.float(), size=(height, width), mode="bilinear", align_corners=False))
        irradiance = from_log(out) if self.input_log else out.clamp_min(0)
        return {"irradiance": irradiance, "coefficients": None}
