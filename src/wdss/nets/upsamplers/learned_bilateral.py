"""Learned joint bilateral upsampling: the joint-bilateral kernel with a learned correction of every tap's weight.

Each high-resolution pixel takes a convex combination of its ``2 radius x 2 radius`` low-resolution neighbours
(:func:`wdss.nets.upsamplers.joint_bilateral.neighbourhood`), weighted by ``softmax(log w_jbu + c)``: ``w_jbu`` is
the fixed joint-bilateral weight (tent times range term) and ``c`` a logit predicted per pixel and tap by a small MLP of
1x1 convolutions from what tells the taps apart -- the scaled guide differences (albedo, depth, normal) and their
magnitudes, the pixel's offset from the tap, the tent weight, and how far the tap's log irradiance lies from the
joint-bilateral estimate (optionally also a few convolutional features of the G-buffer around the pixel; off by
default: on data/mini they fit the training scenes and generalise worse). The MLP's last layer starts at zero,
so the module starts as joint bilateral upsampling exactly and learns from there.

``tap_brdf`` (``recipe.tap_brdf``): the MLP also predicts an exponent ``b`` in [0, 1] per pixel and tap, from the
same features and the log ratio of the tap's BRDF factor to the pixel's, and the tap contributes
``irradiance_tap * (F_tap / F)^b`` instead of its irradiance: the weights stay a convex combination, the values
move between the demodulated estimate (0, the start) and the tap's own colour (1). On data/mini's renders a
colour-space filter beats the demodulated one at geometry edges, where colour is not the BRDF factor times a
smooth irradiance; the exponent lets the kernel choose per tap. The exponent is a clamp of the output, not a
sigmoid, so that the start is exact and its gradient flows there; an output pushed below 0 everywhere would stop
learning it (on data/mini every seed moved it up).

``never_raise`` (``recipe.kernel_never_raise``): the correction is capped at 0, so the kernel can lower a tap's
weight below the fixed kernel's, never raise it. ``raise_within_albedo`` (``recipe.kernel_raise_within_albedo``, on
by default; both off in checkpoints written before they existed, which load as they were trained): a raise
counts only as far as the tap's albedo matches the pixel's (it is multiplied by the fixed kernel's albedo range
term, ``exp(-|albedo difference / range|^2)``); lowering is free. Why: demodulation is exact only where diffuse and
specular light agree; on a checker of 0.26 and 0.02 blue the blue channel's specular share differs across the edges,
so the demodulated irradiance keeps them, and a kernel that learned to raise the weights of taps across albedo edges
(which the training scenes reward) mixed them: well below joint bilateral on that held-out scene. Capping every
raise fixed that scene but cost the seeds whose kernel learned to trust taps of its own surface; raising only within
one albedo keeps both (docs/results.md). The cap also starves the kernel: its correction starts at the cap, and
where the last layer's outputs all move above it no gradient reaches the MLP. The two options exclude each other.

Why: at CPU scale the WDSS network barely leaves its starting point in a few hundred steps, while this kernel
(625 parameters, 690 with ``tap_brdf``) learns a correction that generalises to unseen scenes within a hundred
(docs/results.md, "Where CPU models stand"). It is the residual base ``residual=learned_bilateral`` of the
network and a model of its own (``model=learned_bilateral``), so the two contributions are separate ablation rows.
"""

from __future__ import annotations

import torch
from torch import Tensor, nn

from wdss.nets.base import SuperResolutionNet
from wdss.nets.upsamplers.joint_bilateral import (
    Tap,
    check_ranges,
    joint_bilateral_upsample,
    neighbourhood,
    range_weight,
)

__all__ = ["LearnedBilateralUpsample"]

GBUFFER_CHANNELS = 11  # wdss.data.GBUFFER_STACK
# Scaled guide differences beyond this many range widths all mean "a different surface": clamped, so that the
# MLP sees bounded inputs (the fixed range weight, exp(-25), already excludes such a tap).
_DIFFERENCE_LIMIT = 5.0
# Learned logits are bounded: a tap's weight changes by at most e^8 either way, so the kernel stays a smooth
# reweighting of joint bilateral upsampling and never divides by a vanishing total.
_LOGIT_LIMIT = 8.0


class LearnedBilateralUpsample(SuperResolutionNet):
    """Joint bilateral upsampling of ``lr`` guided by ``gbuffer`` with learned per-tap weight corrections.

    ``hidden``: width of the per-tap MLP (two hidden 1x1 layers); ``context``: channels of the G-buffer context
    features (two 3x3 convolutions at full resolution; 0, the default: none). The sigmas and radius are those of
    the fixed kernel it starts from (:func:`~wdss.nets.upsamplers.joint_bilateral.joint_bilateral_upsample`).
    """

    def __init__(
        self,
        hidden: int = 16,
        context: int = 0,
        sigma_depth: float = 0.01,
        sigma_normal: float = 0.1,
        sigma_albedo: float = 0.1,
        radius: int = 2,
        tap_brdf: bool = False,
        never_raise: bool = False,
        raise_within_albedo: bool = False,
    ) -> None:
        # never_raise and raise_within_albedo default off: a checkpoint whose config predates them builds as trained
        super().__init__()
        self.tap_brdf, self.never_raise = bool(tap_brdf), bool(never_raise)
        self.raise_within_albedo = bool(raise_within_albedo)
        if self.never_raise and self.raise_within_albedo:
            raise ValueError("never_raise and raise_within_albedo exclude each other: choose one")
        if hidden < 1 or context < 0:
            raise ValueError(f"hidden must be >= 1 and context >= 0, got hidden={hidden}, context={context}")
        check_ranges(sigma_depth, sigma_normal, sigma_albedo, radius)
        self.ranges = dict(sigma_depth=sigma_depth, sigma_normal=sigma_normal, sigma_albedo=sigma_albedo, radius=radius)
        self.context = (
            nn.Sequential(
                nn.Conv2d(GBUFFER_CHANNELS, context, 3, padding=1), nn.ReLU(),
                nn.Conv2d(context, context, 3, padding=1), nn.ReLU(),
            )
            if context
            else None
        )  # fmt: skip
        # difference, |difference|, offset, tent, log deviation, context (and the log BRDF ratio with tap_brdf)
        features = 7 + 7 + 2 + 1 + 3 + context + (3 if self.tap_brdf else 0)
        outputs = 2 if self.tap_brdf else 1  # the logit correction (and the tap's BRDF exponent)
        self.mlp = nn.Sequential(
            nn.Conv2d(features, hidden, 1), nn.ReLU(), nn.Conv2d(hidden, hidden, 1), nn.ReLU(),
            nn.Conv2d(hidden, outputs, 1),
        )  # fmt: skip
        nn.init.zeros_(self.mlp[-1].weight)  # start exactly at joint bilateral upsampling
        nn.init.zeros_(self.mlp[-1].bias)
        self.transform = "none"  # as a model of its own: an image, no subbands
        self.name = "learned_bilateral"  # as a residual base (wdss.nets.base)

    @property
    def inputs(self) -> tuple[str, ...]:
        return self.upsample_inputs

    @property
    def upsample_inputs(self) -> tuple[str, ...]:
        """The batch keys :meth:`upsample` reads (the BRDF factors with ``tap_brdf`` only)."""
        return ("lr", "gbuffer", "lr_guide", "lr_jitter") + (("brdf", "lr_brdf") if self.tap_brdf else ())

    def upsample(
        self,
        lr: Tensor,
        gbuffer: Tensor,
        brdf: Tensor | None = None,
        lr_brdf: Tensor | None = None,
        lr_guide: Tensor | None = None,
        lr_jitter: Tensor | None = None,
    ) -> Tensor:
        """``lr`` (N, 3, h, w) non-negative irradiance to the grid of ``gbuffer`` (N, 11, H, W): (N, 3, H, W).

        With ``tap_brdf``, ``brdf`` (N, 3, H, W) is the HR BRDF factor the result is remodulated with and ``lr_brdf``
        (N, 3, h, w) the one ``lr`` was demodulated with; each tap's value is then ``irradiance * (F_tap / F)^b``,
        ``b`` in [0, 1] learned per pixel and tap (0 at the start): 0 keeps the demodulated estimate, 1 carries the
        tap's own colour (``irradiance * F_tap``) through unchanged, as a colour-space joint bilateral filter would
        (where ``F_tap / F`` lies within e^5 either way: the ratio is clamped there). ``lr_guide`` (N, 7, h, w): the
        G-buffer the LR was shaded with, ``lr_jitter`` (N, 2) where
        (:func:`wdss.nets.upsamplers.joint_bilateral.neighbourhood`).
        """
        if self.tap_brdf and (brdf is None or lr_brdf is None):
            raise ValueError("this learned bilateral kernel has tap_brdf=true: it needs the HR brdf and the lr_brdf")
        lr, gbuffer = lr.float().clamp_min(0), gbuffer.float()
        shape = (lr.shape[0], *gbuffer.shape[-2:])
        # Where each tap lies against the fixed estimate: outliers (fireflies, the other side of an edge) show here.
        # A pass of its own: keeping the 16 taps for one pass would hold ~1.7 GB at 1080p instead of one tap.
        fixed = joint_bilateral_upsample(lr, gbuffer, lr_guide=lr_guide, lr_jitter=lr_jitter, **self.ranges)
        reference = torch.log1p(fixed)
        context = [self.context(gbuffer[:, :GBUFFER_CHANNELS])] if self.context is not None else []
        source = [lr, torch.log1p(lr)]  # gathered together: the values and their logs (and the taps' log F)
        log_brdf = None
        if self.tap_brdf:
            log_brdf = torch.log(brdf.float().clamp_min(1e-4))
            source.append(torch.log(lr_brdf.float().clamp_min(1e-4)))  # F at the LR pixels, as lr was demodulated
        source = torch.cat(source, 1)
        logits, values = [], []
        for tap in neighbourhood(source, gbuffer, lr_guide=lr_guide, lr_jitter=lr_jitter, **self.ranges):
            out = self.mlp(self._features(tap, shape, reference, context, log_brdf))
            logits.append(self._logit(tap, out))
            values.append(self._value(tap, out, log_brdf))
        weights = torch.softmax(torch.stack(logits), 0)
        return (weights * torch.stack(values)).sum(0)

    def _features(
        self,
        tap: Tap,
        shape: tuple[int, int, int],
        reference: Tensor,
        context: list[Tensor],
        log_brdf: Tensor | None,
    ) -> Tensor:
        """The per-tap MLP's input (N, C, H, W): the tap's G-buffer difference, its offset and spatial weight, its
        log value against the fixed estimate ``reference``, the ``context`` features, and with ``tap_brdf`` its log
        BRDF factor against the pixel's (``shape``: N, H, W)."""
        n, height, width = shape
        row, col = tap.offset
        return torch.cat(
            [
                tap.difference.clamp(-_DIFFERENCE_LIMIT, _DIFFERENCE_LIMIT),
                tap.difference.abs().clamp_max(_DIFFERENCE_LIMIT),
                row[:, None, :, None].expand(n, 1, height, width),
                col[:, None, None, :].expand(n, 1, height, width),
                tap.spatial.expand(n, 1, height, width),
                tap.values[:, 3:6] - reference,
                *context,
                *(
                    [(tap.values[:, 6:9] - log_brdf).clamp(-_DIFFERENCE_LIMIT, _DIFFERENCE_LIMIT)]
                    if self.tap_brdf
                    else []
                ),
            ],
            1,
        )

    def _logit(self, tap: Tap, out: Tensor) -> Tensor:
        """The tap's log weight: the fixed kernel's, corrected by the MLP's first output ``out[:, :1]``."""
        correction = out[:, :1].clamp(-_LOGIT_LIMIT, 0.0 if self.never_raise else _LOGIT_LIMIT)
        if self.raise_within_albedo:  # a raise counts only as far as the tap's albedo matches the pixel's
            gate = torch.exp(-(tap.difference[:, :3] ** 2).sum(1, keepdim=True))
            correction = correction.clamp_max(0.0) + gate * correction.clamp_min(0.0)
        # Taps outside the tent (weight 0) stay out: -inf would make a NaN gradient, a large negative does not.
        base = torch.log(range_weight(tap).clamp_min(1e-30))
        return torch.where(tap.spatial > 0, base + correction, -1e4)

    def _value(self, tap: Tap, out: Tensor, log_brdf: Tensor | None) -> Tensor:
        """The tap's irradiance, with ``tap_brdf`` carried ``b`` (the MLP's second output) of the way to the tap's
        own colour."""
        value = tap.values[:, :3]
        if self.tap_brdf:  # clamp, not a sigmoid: the kernel starts exactly at b = 0, and its gradient flows there
            exponent = out[:, 1:2].clamp(0.0, 1.0)
            value = value * torch.exp(
                exponent * (tap.values[:, 6:9] - log_brdf).clamp(-_DIFFERENCE_LIMIT, _DIFFERENCE_LIMIT)
            )
        return value

    def forward(
        self,
        lr: Tensor,
        gbuffer: Tensor,
        brdf: Tensor | None = None,
        lr_brdf: Tensor | None = None,
        lr_guide: Tensor | None = None,
        lr_jitter: Tensor | None = None,
        **_: Tensor,
    ) -> dict:
        return {"irradiance": self.upsample(lr, gbuffer, brdf, lr_brdf, lr_guide, lr_jitter), "coefficients": None}
