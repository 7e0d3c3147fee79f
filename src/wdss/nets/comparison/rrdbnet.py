"""Real-ESRGAN's generator (RRDBNet: residual-in-residual dense blocks), a single-image baseline.

It sees only the tone-mapped low-resolution colour, as a general image super-resolution method would, and
returns a display image. Published weights (scales 2 and 4) load from a local file (``weights``); other scales
run the network's native scale and resize to the frame. Without weights it must be trained on our frames
(then tagged so in MLflow); :attr:`needs_training` lets the entry points refuse to evaluate random weights.
``skip=True`` (not the published network; ``recipe.skip``, on in ``experiment=cpu``) adds the output to the bicubic
upsampling of the tone-mapped LR, so a network trained from scratch in minutes starts at bicubic.
``demodulated=True`` (not the published method either; ``variant=real_esrgan_demodulated``) feeds it log1p of the
demodulated LR irradiance instead and reads its output as log1p of the HR irradiance, which the module remodulates
with the HR BRDF as it does WDSS's: the same generic network, given the one thing G-buffers add to the colour.
"""

from __future__ import annotations

import os

import torch
import torch.nn.functional as F
from torch import Tensor, nn

from wdss.nets.base import SuperResolutionNet
from wdss.nets.blocks import from_log, scale_exit, to_log
from wdss.ops.tonemap import tonemap

__all__ = ["RRDBNet"]


class ResidualDenseBlock(nn.Module):
    def __init__(self, features: int, growth: int) -> None:
        super().__init__()
        self.conv1 = nn.Conv2d(features, growth, 3, 1, 1)
        self.conv2 = nn.Conv2d(features + growth, growth, 3, 1, 1)
        self.conv3 = nn.Conv2d(features + 2 * growth, growth, 3, 1, 1)
        self.conv4 = nn.Conv2d(features + 3 * growth, growth, 3, 1, 1)
        self.conv5 = nn.Conv2d(features + 4 * growth, features, 3, 1, 1)

    def forward(self, x: Tensor) -> Tensor:
        x1 = F.leaky_relu(self.conv1(x), 0.2)
        x2 = F.leaky_relu(self.conv2(torch.cat((x, x1), 1)), 0.2)
        x3 = F.leaky_relu(self.conv3(torch.cat((x, x1, x2), 1)), 0.2)
        x4 = F.leaky_relu(self.conv4(torch.cat((x, x1, x2, x3), 1)), 0.2)
        return x + 0.2 * self.conv5(torch.cat((x, x1, x2, x3, x4), 1))


class RRDB(nn.Module):
    def __init__(self, features: int, growth: int) -> None:
        super().__init__()
        self.rdb1 = ResidualDenseBlock(features, growth)
        self.rdb2 = ResidualDenseBlock(features, growth)
        self.rdb3 = ResidualDenseBlock(features, growth)

    def forward(self, x: Tensor) -> Tensor:
        return x + 0.2 * self.rdb3(self.rdb2(self.rdb1(x)))


class RRDBNet(SuperResolutionNet):
    """RRDBNet x4 (two nearest-upsample + conv stages); x2 by pixel-unshuffling the input first.

    Defaults are Real-ESRGAN's (23 blocks, 64 features, growth 32: ~16.7 M parameters). ``weights``: a local
    ``.pth`` of the published generator (``params_ema`` or ``params`` or a bare state dict).
    """

    transform = "none"
    loads_published_weights = True  # wdss.nets.base: a run tags which weights it reports

    def __init__(
        self,
        scale: int = 4,
        num_feat: int = 64,
        num_block: int = 23,
        num_grow_ch: int = 32,
        weights: str | None = None,
        tonemap_name: str = "hable",
        skip: bool = False,
        demodulated: bool = False,
    ) -> None:
        super().__init__()
        if scale not in (2, 4):
            raise ValueError(f"RRDBNet's native scale is 2 or 4 (others by resizing), got {scale}")
        if skip and weights:
            raise ValueError(
                "model.net.skip=true changes RRDBNet's output: published weights (model.net.weights) need skip=false"
            )
        if demodulated and weights:
            raise ValueError(
                "model.net.demodulated=true feeds RRDBNet the demodulated irradiance: published weights "
                "(model.net.weights) were trained on tone-mapped colour and need demodulated=false"
            )
        self.scale, self.tonemap_name, self.skip, self.demodulated = scale, tonemap_name, bool(skip), bool(demodulated)
        cin = 3 * (4 if scale == 2 else 1)
        self.conv_first = nn.Conv2d(cin, num_feat, 3, 1, 1)
        self.body = nn.Sequential(*[RRDB(num_feat, num_grow_ch) for _ in range(num_block)])
        self.conv_body = nn.Conv2d(num_feat, num_feat, 3, 1, 1)
        self.conv_up1 = nn.Conv2d(num_feat, num_feat, 3, 1, 1)
        self.conv_up2 = nn.Conv2d(num_feat, num_feat, 3, 1, 1)
        self.conv_hr = nn.Conv2d(num_feat, num_feat, 3, 1, 1)
        self.conv_last = nn.Conv2d(num_feat, 3, 3, 1, 1)
        if self.skip:
            scale_exit(self.conv_last)
        self.weights = weights
        if weights:
            if not os.path.isfile(weights):
                raise FileNotFoundError(f"model.net.weights={weights} is not a file (Real-ESRGAN's published .pth)")
            from wdss.checkpoint import load_weights

            state = load_weights(weights, "model.net.weights")
            state = state.get("params_ema", state.get("params", state))
            self.load_state_dict(state)

    @property
    def needs_training(self) -> bool:
        return not self.weights

    @property
    def inputs(self) -> tuple[str, ...]:
        return ("lr" if self.demodulated else "lr_color", "brdf")

    def forward(self, brdf: Tensor, lr_color: Tensor | None = None, lr: Tensor | None = None, **_: Tensor) -> dict:
        source = lr if self.demodulated else lr_color
        if source is None:
            raise ValueError(f"this RRDBNet (demodulated={self.demodulated}) needs the batch key {self.inputs[0]!r}")
        height, width = brdf.shape[-2:]
        lh, lw = source.shape[-2:]
        x = to_log(source) if self.demodulated else tonemap(source, self.tonemap_name)
        base = F.interpolate(x, size=(height, width), mode="bicubic", align_corners=False) if self.skip else None
        if self.scale == 2:  # x2 = the x4 body on the pixel-unshuffled input (padded to even sizes)
            x = F.pixel_unshuffle(F.pad(x, (0, lw % 2, 0, lh % 2), mode="replicate"), 2)
        feat = self.conv_first(x)
        feat = feat + self.conv_body(self.body(feat))
        feat = F.leaky_relu(self.conv_up1(F.interpolate(feat, scale_factor=2, mode="nearest")), 0.2)
        feat = F.leaky_relu(self.conv_up2(F.interpolate(feat, scale_factor=2, mode="nearest")), 0.2)
        out = self.conv_last(F.leaky_relu(self.conv_hr(feat), 0.2))[..., : lh * self.scale, : lw * self.scale]
        if out.shape[-2:] != (height, width):  # other scales: the native result resized to the frame
            out = F.interpolate(out, size=(height, width), mode="bicubic", align_corners=False, antialias=True)
        if base is not None:
            out = out + base
        if self.demodulated:  # log1p of irradiance
            return {"display": None, "irradiance": from_log(out), "coefficients": None}
        # Clamped for evaluation only: a clamp in training would zero the gradient of out-of-range pixels.
        return {"display": out if self.training else out.clamp(0.0, 1.0), "irradiance": None, "coefficients": None}
