"""Image-space baselines, evaluated through the same path as the networks (irradiance out, remodulated).

``bilinear`` and ``bicubic`` upsample the low-resolution colour; ``bilinear_demodulated`` upsamples the
demodulated irradiance and remodulates it with the high-resolution BRDF, which restores texture detail
from the G-buffer for free. Upsampling aligns cell centres (``align_corners=False``), as the data does, and
places a jittered LR frame's pixels where they were shaded (``lr_jitter``). The same module is also a residual base
of the WDSS network (``residual=bilinear``: :meth:`Upsample.upsample`).
"""

from __future__ import annotations

from torch import Tensor

from wdss.nets.base import SuperResolutionNet
from wdss.ops.sampling import upsample

__all__ = ["Upsample"]


class Upsample(SuperResolutionNet):
    """A parameter-free baseline: ``mode`` is ``bilinear`` or ``bicubic``; ``demodulated`` upsamples irradiance."""

    def __init__(self, mode: str = "bilinear", demodulated: bool = False) -> None:
        super().__init__()
        if mode not in ("bilinear", "bicubic"):
            raise ValueError(f"baseline mode must be 'bilinear' or 'bicubic', got {mode!r}")
        self.mode, self.demodulated = mode, demodulated
        self.transform = "none"
        self.name = mode  # as a residual base (wdss.nets.base)

    @property
    def inputs(self) -> tuple[str, ...]:
        return ("lr", "lr_jitter") if self.demodulated else ("lr_color", "brdf", "lr_jitter")

    @property
    def upsample_inputs(self) -> tuple[str, ...]:
        """The batch keys :meth:`upsample` reads."""
        return ("lr", "lr_jitter")

    def upsample(
        self,
        lr: Tensor,
        gbuffer: Tensor,
        brdf: Tensor | None = None,
        lr_brdf: Tensor | None = None,
        lr_guide: Tensor | None = None,
        lr_jitter: Tensor | None = None,
    ) -> Tensor:
        """``lr`` (N, C, h, w) upsampled to the grid of ``gbuffer`` in float32, as a residual base (the residual
        upsampler's signature, wdss.nets.base; only the grid's size and the jitter are read)."""
        return upsample(lr.float(), gbuffer.shape[-2:], self.mode, lr_jitter)

    def forward(
        self,
        brdf: Tensor,
        lr: Tensor | None = None,
        lr_color: Tensor | None = None,
        lr_jitter: Tensor | None = None,
        **_: Tensor,
    ) -> dict:
        size = brdf.shape[-2:]
        source = lr if self.demodulated else lr_color
        up = upsample(source, size, self.mode, lr_jitter).clamp_min(0.0)
        # Colour baselines return colour / F so that the shared remodulation gives their colour back exactly.
        return {"irradiance": up if self.demodulated else up / brdf, "coefficients": None}
