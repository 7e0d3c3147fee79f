"""Joint bilateral upsampling of the demodulated irradiance, guided by the high-resolution G-buffer.

A classical, parameter-free baseline (after Kopf et al., "Joint bilateral upsampling", 2007): every
high-resolution pixel takes a weighted mean of the ``2 radius x 2 radius`` low-resolution pixels around its
position in low-resolution coordinates (``u = (x + 0.5) w / W - 0.5``, cell centres aligned as in
:mod:`wdss.ops.sampling`, less the frame's ``lr_jitter`` where its LR pixels were shaded off their centres). The
weight is a separable tent ``max(0, 1 - |u - j| / radius)`` per axis times a range term comparing the pixel's
depth, normal and albedo with those of the low-resolution pixel: the G-buffer the LR colour was shaded with
(``lr_guide``, the batch key of that name: a native LR frame's own G-buffer), or, without one, the high-resolution
G-buffer point-sampled as point-sampled data samples its LR frames:

    exp(-dz^2 / (2 sigma_depth^2) - (1 - n.n') / sigma_normal - |da|^2 / (2 sigma_albedo^2))

The normal term is computed as ``|n - n'|^2 / 2``, which equals ``1 - n.n'`` for unit normals and is also 0
between identical non-unit normals (zero normals of empty pixels), so identical guides always weigh 1.
Where no neighbour is similar the range terms vanish; a tiny floor :data:`FALLBACK_WEIGHT` added to every
range weight then makes the result the spatial (tent) interpolation instead of 0/0, smoothly, so the
function stays differentiable and NaN-free. Range exponents are capped at 30 (a weight of 1e-13, far below
the floor; exp() of large arguments is slow). Neighbours outside the frame repeat the border pixel.
"""

from __future__ import annotations

import math
from collections.abc import Iterator
from typing import NamedTuple

import torch
from torch import Tensor

from wdss.nets.base import SuperResolutionNet
from wdss.ops.sampling import centred, point_sample

__all__ = [
    "FALLBACK_WEIGHT",
    "JointBilateralUpsample",
    "Tap",
    "check_ranges",
    "joint_bilateral_upsample",
    "neighbourhood",
    "range_weight",
]

# Added to every range weight: negligible next to a similar neighbour (weight ~1), decisive when none is.
FALLBACK_WEIGHT = 1e-6
# Range exponents beyond this give weights far below the floor; capping them keeps exp() off its slow path.
_MAX_EXPONENT = 30.0


def _taps(
    hr: int, lr: int, radius: int, device: torch.device, dtype: torch.dtype, jitter: Tensor | None = None
) -> list[tuple[Tensor, Tensor, Tensor]]:
    """Per tap offset along one axis: the clamped LR index, the tent weight of every HR position, and the HR
    position's offset from the tap's sample in LR pixels (``u - j - jitter``, before clamping), weight and offset in
    ``dtype``, each ``(1, hr)``, or ``(N, hr)`` for a per-sample ``jitter`` (N,): LR pixel ``j`` shaded at
    ``j + jitter`` (its centre at 0).

    At the centres (no jitter, the only case an exported graph holds) the positions are exact integer arithmetic:
    ``u = ((2x + 1) lr - hr) / (2 hr)``, its floor an integer division and its fraction one rounding, so that floor()
    never flips at exact cell boundaries, with no float64 in an exported graph (which many engines lack)."""
    compute = torch.promote_types(dtype, torch.float32)  # float16 and bfloat16 positions are rounded once, at the end
    if jitter is None:
        # (2x + 1) lr - hr >= -hr: shifted by one period (2 hr) to a non-negative numerator, so that integer
        # division is the floor on every backend (truncation and floor agree there).
        numerator = (2 * torch.arange(hr, device=device) + 1) * lr + hr
        quotient = numerator // (2 * hr)
        base = (quotient - 1)[None]
        # u - floor(u), in [0, 1): the remainder from the quotient (the exporter cannot take % by a symbolic size)
        fraction = ((numerator - quotient * (2 * hr)).to(compute) / (2 * hr))[None]
    else:
        # float64 positions: floor() must not flip at exact cell boundaries for any size (torch only: a graph
        # takes no jitter).
        u = (torch.arange(hr, device=device, dtype=torch.float64) + 0.5) * (lr / hr) - 0.5
        u = u[None] - jitter.to(device, torch.float64)[:, None]
        floor = torch.floor(u)
        base, fraction = floor.long(), (u - floor).to(compute)
    taps = []
    for k in range(1 - radius, radius + 1):
        offset = fraction - k  # u - j for the tap j = floor(u) + k
        weight = (1.0 - offset.abs() / radius).clamp_min(0.0)
        taps.append(((base + k).clamp(0, lr - 1), weight.to(dtype), offset.to(dtype)))
    return taps


def _gather(source: Tensor, dim: int, index: Tensor) -> Tensor:
    """``source`` indexed along ``dim`` (2: rows, 3: columns) by ``index`` (1, n) shared or (N, n) per sample."""
    if index.shape[0] == 1:  # one index for the batch: whole rows or columns copied, the cheap path
        return source.index_select(dim, index[0])
    n, c, h, w = source.shape
    shape = (n, c, index.shape[1], w) if dim == 2 else (n, c, h, index.shape[1])
    view = index[:, None, :, None] if dim == 2 else index[:, None, None, :]
    return source.gather(dim, view.expand(shape))


def check_ranges(sigma_depth: float, sigma_normal: float, sigma_albedo: float, radius: int) -> None:
    """Refuse a kernel that cannot be built: a radius that is not a positive integer, a sigma that is not positive."""
    if int(radius) != radius or radius < 1:
        raise ValueError(f"radius must be a positive integer, got {radius}")
    if min(sigma_depth, sigma_normal, sigma_albedo) <= 0:
        raise ValueError("sigma_depth, sigma_normal and sigma_albedo must be positive")


class Tap(NamedTuple):
    """One LR neighbour of every HR pixel: its values, where it lies and how its guide differs."""

    values: Tensor  # (N, C, H, W): the neighbour's LR values
    spatial: Tensor  # (N or 1, 1, H, W): the tent weight
    offset: tuple[Tensor, Tensor]  # (N or 1, H), (N or 1, W): the pixel's offset from the neighbour's sample in LR
    # pixels (rows, cols)
    difference: Tensor  # (N, 7, H, W): HR guide minus the neighbour's, scaled by the ranges (albedo, depth, normal)


def neighbourhood(
    lr: Tensor,
    gbuffer: Tensor,
    *,
    lr_guide: Tensor | None = None,
    lr_jitter: Tensor | None = None,
    sigma_depth: float = 0.01,
    sigma_normal: float = 0.1,
    sigma_albedo: float = 0.1,
    radius: int = 2,
) -> Iterator[Tap]:
    """The ``2 radius x 2 radius`` LR neighbours of every HR pixel of ``gbuffer``'s grid, one :class:`Tap` each.

    The guide differences are scaled so that a range term is a plain squared distance: ``exp(-|difference|^2)``
    is the module docstring's range weight. ``lr_guide`` (N, 7, h, w): the LR pixels' albedo, depth and normal
    (:func:`wdss.data.preprocess.lr_guide`); ``None``: ``gbuffer``'s first 7 channels point-sampled. ``lr_jitter``
    (N, 2): where each sample's LR pixels were shaded, from their centres (x, y in LR pixels; the batch key), which
    moves the taps and their tent weights; ``None`` or all zero: at the centres.
    """
    check_ranges(sigma_depth, sigma_normal, sigma_albedo, radius)
    if lr.shape[0] != gbuffer.shape[0] or gbuffer.shape[1] < 7:
        raise ValueError(f"lr {tuple(lr.shape)} and gbuffer {tuple(gbuffer.shape)} do not form a batch")
    radius = int(radius)
    (h, w), (height, width) = lr.shape[-2:], gbuffer.shape[-2:]
    guide = gbuffer[:, :7].to(lr.dtype)
    if lr_guide is None:
        lr_guide = point_sample(guide, (h, w))
    elif lr_guide.shape[0] != lr.shape[0] or lr_guide.shape[1] != 7 or lr_guide.shape[-2:] != lr.shape[-2:]:
        raise ValueError(f"lr_guide {tuple(lr_guide.shape)} is not the (N, 7, h, w) guide of lr {tuple(lr.shape)}")
    lr_guide = lr_guide.to(lr.dtype)
    scales = torch.tensor(
        [1 / (math.sqrt(2) * sigma_albedo)] * 3
        + [1 / (math.sqrt(2) * sigma_depth)]
        + [1 / math.sqrt(2 * sigma_normal)] * 3,
        dtype=lr.dtype,
        device=lr.device,
    ).view(1, 7, 1, 1)
    guide, lr_guide = guide * scales, lr_guide * scales
    source = torch.cat([lr, lr_guide], dim=1)  # gathered together: one index op per tap
    channels = lr.shape[1]
    if lr_jitter is not None and lr_jitter.shape != (lr.shape[0], 2):
        raise ValueError(f"lr_jitter {tuple(lr_jitter.shape)} is not the (N, 2) jitter of lr {tuple(lr.shape)}")
    if centred(lr_jitter):
        lr_jitter = None  # every sample at its pixel centre: one set of taps for the batch
    x, y = (None, None) if lr_jitter is None else (lr_jitter[:, 0], lr_jitter[:, 1])
    rows = _taps(height, h, radius, lr.device, lr.dtype, y)
    cols = _taps(width, w, radius, lr.device, lr.dtype, x)
    # Columns first, on the LR rows: the per-tap row gathers then copy whole contiguous rows, the cheap axis.
    for col_index, col_weight, col_offset in cols:
        source_cols = _gather(source, 3, col_index)
        for row_index, row_weight, row_offset in rows:
            neighbour = _gather(source_cols, 2, row_index)
            yield Tap(
                values=neighbour[:, :channels],
                spatial=row_weight[:, None, :, None] * col_weight[:, None, None, :],
                offset=(row_offset, col_offset),
                difference=guide - neighbour[:, channels:],
            )


def range_weight(tap: Tap) -> Tensor:
    """The joint-bilateral weight of a tap (tent times range term plus the fallback floor), (N, 1, H, W)."""
    distance = (tap.difference * tap.difference).sum(1, keepdim=True).clamp_max(_MAX_EXPONENT)
    return tap.spatial * (torch.exp(-distance) + FALLBACK_WEIGHT)


def joint_bilateral_upsample(
    lr: Tensor,
    gbuffer: Tensor,
    *,
    lr_guide: Tensor | None = None,
    lr_jitter: Tensor | None = None,
    sigma_depth: float = 0.01,
    sigma_normal: float = 0.1,
    sigma_albedo: float = 0.1,
    radius: int = 2,
) -> Tensor:
    """Upsample ``lr`` (N, C, h, w) to the grid of ``gbuffer`` (N, 11, H, W), guided by its depth, normal, albedo
    against ``lr_guide``'s, the LR pixels shaded where ``lr_jitter`` says (see :func:`neighbourhood`).

    See the module docstring for the weights. Returns (N, C, H, W) in ``lr``'s dtype; a convex combination of
    ``lr`` values, so non-negative input stays non-negative.
    """
    height, width = gbuffer.shape[-2:]
    total = lr.new_zeros(lr.shape[0], 1, height, width)
    accumulated = lr.new_zeros(lr.shape[0], lr.shape[1], height, width)
    taps = neighbourhood(
        lr,
        gbuffer,
        lr_guide=lr_guide,
        lr_jitter=lr_jitter,
        sigma_depth=sigma_depth,
        sigma_normal=sigma_normal,
        sigma_albedo=sigma_albedo,
        radius=radius,
    )
    for tap in taps:
        weight = range_weight(tap)
        accumulated = accumulated + weight * tap.values
        total = total + weight
    # The spatial weights of the taps sum to radius^2 > 0, so total >= FALLBACK_WEIGHT * radius^2.
    return accumulated / total


class JointBilateralUpsample(SuperResolutionNet):
    """Parameter-free baseline: :func:`joint_bilateral_upsample` of the demodulated LR irradiance, remodulated with
    the HR BRDF factor (``demodulated``), or of the LR colour itself (``demodulated=False``: the taps' colours,
    each remodulated by its own BRDF factor, as a colour-space joint bilateral filter)."""

    def __init__(
        self,
        sigma_depth: float = 0.01,
        sigma_normal: float = 0.1,
        sigma_albedo: float = 0.1,
        radius: int = 2,
        demodulated: bool = True,
    ) -> None:
        super().__init__()
        check_ranges(sigma_depth, sigma_normal, sigma_albedo, radius)
        self.sigma_depth, self.sigma_normal, self.sigma_albedo = sigma_depth, sigma_normal, sigma_albedo
        self.radius = int(radius)
        self.demodulated = bool(demodulated)
        self.transform = "none"
        self.name = "joint_bilateral"  # as a residual base (wdss.nets.base)

    @property
    def inputs(self) -> tuple[str, ...]:
        keys = ("lr", "gbuffer") if self.demodulated else ("lr_color", "gbuffer", "brdf")
        return (*keys, "lr_guide", "lr_jitter")

    @property
    def upsample_inputs(self) -> tuple[str, ...]:
        """The batch keys :meth:`upsample` reads."""
        return ("lr", "gbuffer", "lr_guide", "lr_jitter")

    def upsample(
        self,
        lr: Tensor,
        gbuffer: Tensor,
        brdf: Tensor | None = None,
        lr_brdf: Tensor | None = None,
        lr_guide: Tensor | None = None,
        lr_jitter: Tensor | None = None,
    ) -> Tensor:
        """:func:`joint_bilateral_upsample` of ``lr`` (N, C, h, w) in float32 with this module's ranges, as a residual
        base (the residual upsampler's signature, wdss.nets.base; the BRDF factors are not read)."""
        return joint_bilateral_upsample(
            lr.float(),
            gbuffer.float(),
            lr_guide=lr_guide,
            lr_jitter=lr_jitter,
            sigma_depth=self.sigma_depth,
            sigma_normal=self.sigma_normal,
            sigma_albedo=self.sigma_albedo,
            radius=self.radius,
        )

    def forward(
        self,
        lr: Tensor | None = None,
        gbuffer: Tensor | None = None,
        lr_color: Tensor | None = None,
        brdf: Tensor | None = None,
        lr_guide: Tensor | None = None,
        lr_jitter: Tensor | None = None,
        **_: Tensor,
    ) -> dict:
        if gbuffer is None or (self.demodulated and lr is None):
            raise ValueError("joint bilateral upsampling needs the gbuffer and (demodulated) lr")
        if not self.demodulated and (lr_color is None or brdf is None):
            raise ValueError("joint bilateral upsampling with demodulated=false needs lr_color and the HR brdf")
        upsampled = joint_bilateral_upsample(
            lr if self.demodulated else lr_color,
            gbuffer,
            lr_guide=lr_guide,
            lr_jitter=lr_jitter,
            sigma_depth=self.sigma_depth,
            sigma_normal=self.sigma_normal,
            sigma_albedo=self.sigma_albedo,
            radius=self.radius,
        )
        # The module remodulates with the HR F: the colour estimate divided by it comes back out unchanged.
        irradiance = upsampled if self.demodulated else upsampled / brdf
        return {"irradiance": irradiance, "coefficients": None}
