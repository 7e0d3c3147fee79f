"""Image metrics on tone-mapped, remodulated images (docs/reference.md section 6): PSNR, SSIM, FLIP, LPIPS.

PSNR (peak 1) and SSIM (Gaussian window 11, sigma 1.5) come from torchmetrics, FLIP from NVIDIA's
``flip-evaluator`` (LDR on the tone-mapped images, HDR on linear colour), LPIPS-VGG from
:class:`LPIPS` when the user points it at local weight files: no package installable here ships the
ImageNet VGG weights, and LPIPS with a random backbone would be meaningless, so without them it is off.
"""

from __future__ import annotations

import os
from collections.abc import Sequence

import numpy as np
import torch
from torch import Tensor, nn
from torchmetrics.functional.image import structural_similarity_index_measure

from wdss.ops.tonemap import ToneMap

__all__ = ["LPIPS", "ImageMetrics", "flip_error", "psnr", "ssim"]


def psnr(output: Tensor, target: Tensor) -> Tensor:
    """Per-image PSNR (N,) of [0, 1] images; identical images give +inf (reported as such, never NaN)."""
    mse = ((output - target) ** 2).flatten(1).mean(1)
    return torch.where(mse > 0, -10.0 * torch.log10(mse.clamp_min(1e-30)), torch.full_like(mse, float("inf")))


def ssim(output: Tensor, target: Tensor) -> Tensor:
    """Per-image SSIM (N,) of [0, 1] images, Gaussian window 11, sigma 1.5."""
    return structural_similarity_index_measure(
        output, target, data_range=1.0, gaussian_kernel=True, sigma=1.5, kernel_size=11, reduction="none"
    )


def flip_error(output: Tensor, target: Tensor, dynamic_range: str) -> Tensor:
    """Per-image mean FLIP (N,): ``LDR`` for [0, 1] display images, ``HDR`` for linear radiance."""
    import flip_evaluator

    values = []
    for out, ref in zip(output.detach().float().cpu(), target.detach().float().cpu(), strict=True):
        ref_np = np.ascontiguousarray(ref.clamp_min(0).permute(1, 2, 0).numpy())
        out_np = np.ascontiguousarray(out.clamp_min(0).permute(1, 2, 0).numpy())
        if dynamic_range == "LDR":
            ref_np, out_np = ref_np.clip(0, 1), out_np.clip(0, 1)
        _, mean, _ = flip_evaluator.evaluate(ref_np, out_np, dynamic_range, applyMagma=False)
        values.append(float(mean))
    return torch.tensor(values)


class ImageMetrics(nn.Module):
    """Per-image metrics of remodulated linear colour, after tone mapping with ``tonemap_name`` at ``exposure``
    (see :class:`wdss.ops.tonemap.ToneMap`)."""

    def __init__(
        self,
        tonemap_name: str = "hable",
        flip: bool = True,
        lpips: nn.Module | None = None,
        exposure: float | str | None = None,
    ):
        super().__init__()
        self.tone = ToneMap(tonemap_name, exposure)
        self.flip = flip
        self.lpips = lpips

    @torch.no_grad()
    def forward(self, output: Tensor, target: Tensor, *, flip: bool = True) -> dict[str, Tensor]:
        """``flip=False`` skips FLIP for this call (it is slow on a CPU, and runs once per range)."""
        flip = flip and self.flip
        values = self._ldr(self.tone(output, target), self.tone(target, target), flip)
        if flip:
            values["flip_hdr"] = flip_error(output, target, "HDR")
        return {k: v.detach().cpu() for k, v in values.items()}

    @torch.no_grad()
    def display(self, output_ldr: Tensor, target: Tensor, *, flip: bool = True) -> dict[str, Tensor]:
        """Metrics of a model that outputs display images (no HDR FLIP: it has no linear output)."""
        values = self._ldr(output_ldr, self.tone(target, target), flip and self.flip)
        return {k: v.detach().cpu() for k, v in values.items()}

    def _ldr(self, out_ldr: Tensor, ref_ldr: Tensor, flip: bool) -> dict[str, Tensor]:
        values = {"psnr": psnr(out_ldr, ref_ldr), "ssim": ssim(out_ldr, ref_ldr)}
        if flip:
            values["flip"] = flip_error(out_ldr, ref_ldr, "LDR")
        if self.lpips is not None:
            values["lpips"] = self.lpips(out_ldr, ref_ldr).flatten().cpu()
        return values


# --------------------------------------------------------------------------------------------------------
# LPIPS-VGG with user-supplied weights
# --------------------------------------------------------------------------------------------------------

_VGG16 = (64, 64, "M", 128, 128, "M", 256, 256, 256, "M", 512, 512, 512, "M", 512, 512, 512)
_TAPS = (3, 8, 15, 22, 29)  # relu1_2, relu2_2, relu3_3, relu4_3, relu5_3 in torchvision's vgg16.features
_CHANNELS = (64, 128, 256, 512, 512)


class LPIPS(nn.Module):
    """LPIPS with a VGG16 backbone (Zhang et al. 2018), built without torchvision.

    ``backbone``: a torchvision ``vgg16`` state dict file (keys ``features.N.weight``); ``linear``: the
    LPIPS linear-layer file of the reference implementation (keys ``linN.model.1.weight``). Inputs are
    images in [0, 1]; the output is (N,).
    """

    def __init__(self, backbone: str | os.PathLike, linear: str | os.PathLike) -> None:
        super().__init__()
        for what, path in (("backbone", backbone), ("linear", linear)):
            if not path or not os.path.isfile(path):
                raise FileNotFoundError(
                    f"LPIPS {what} weights not found at {path!r}: LPIPS needs local weight files (torchvision's "
                    "vgg16 state dict and the LPIPS vgg linear layers); without them leave LPIPS off"
                )
        layers: list[nn.Module] = []
        cin = 3
        for v in _VGG16:
            if v == "M":
                layers.append(nn.MaxPool2d(2, 2))
            else:
                layers += [nn.Conv2d(cin, v, 3, padding=1), nn.ReLU(inplace=False)]
                cin = v
        self.features = nn.Sequential(*layers)
        self.lins = nn.ModuleList(nn.Conv2d(c, 1, 1, bias=False) for c in _CHANNELS)
        from wdss.checkpoint import load_weights

        state = load_weights(backbone, "loss.lpips.backbone")
        self.features.load_state_dict(
            {k.removeprefix("features."): v for k, v in state.items() if k.startswith("features.")}
        )
        lin_state = load_weights(linear, "loss.lpips.linear")
        for i, lin in enumerate(self.lins):
            lin.weight.data.copy_(lin_state[f"lin{i}.model.1.weight"])
        self.register_buffer("shift", torch.tensor([-0.030, -0.088, -0.188]).view(1, 3, 1, 1))
        self.register_buffer("scale", torch.tensor([0.458, 0.448, 0.450]).view(1, 3, 1, 1))
        self.requires_grad_(False)
        self.eval()

    def _taps(self, x: Tensor) -> Sequence[Tensor]:
        out = []
        for index, layer in enumerate(self.features):
            x = layer(x)
            if index in _TAPS:
                out.append(x)
        return out

    def forward(self, output: Tensor, target: Tensor) -> Tensor:
        a = self._taps(((output * 2 - 1) - self.shift) / self.scale)
        b = self._taps(((target * 2 - 1) - self.shift) / self.scale)
        total = 0.0
        for lin, fa, fb in zip(self.lins, a, b, strict=True):
            fa = fa / (fa.pow(2).sum(1, keepdim=True).sqrt() + 1e-10)
            fb = fb / (fb.pow(2).sum(1, keepdim=True).sqrt() + 1e-10)
            total = total + lin((fa - fb) ** 2).mean((2, 3))
        return total.flatten() if isinstance(total, Tensor) else torch.zeros(output.shape[0])
