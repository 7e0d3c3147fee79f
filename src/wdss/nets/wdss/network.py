"""The WDSS network (docs/reference.md section 2): extractors -> fusion + Fourier INR -> subbands -> synthesis.

A pure ``nn.Module``. Inputs are the batch tensors of :mod:`wdss.data` (``lr``, ``gbuffer``,
``spatial_mask``, ``history``, ``temporal_mask``, ``scale``); the output is high-resolution irradiance
(clamped at 0) and, for wavelet heads, the predicted coefficients (band-major ``[LL, LH, HL, HH] x RGB``).

Grids: every input is ``pixel_unshuffle``d by 2, so features live on half-resolution grids: the LR/2 grid
of ``h/2 x w/2`` cells and the HR/2 grid of ``H/2 x W/2`` cells, both spanning the frame (cell centres in
``[-1, 1]``, LIIF's convention, matching :mod:`wdss.ops.sampling`). Each HR/2 cell takes the amplitude of
its nearest LR/2 cell and knows its offset ``delta`` from that cell's centre, in LR/2 cells (``|delta| <=
1``). Odd frame sizes are padded to even (replicating the border) and cropped back; the grids are placed by
the real pixel counts, so an odd frame's last cell (its last pixel and the padding) sits half outside the
frame and the LR/2 and HR/2 grids stay registered (:func:`cell_grid`, :func:`resample_to_cells`).
"""

from __future__ import annotations

import math
from collections.abc import Sequence

import torch
import torch.nn.functional as F
from torch import Tensor, nn

from wdss.nets.base import SuperResolutionNet
from wdss.nets.blocks import DoubleResidual, GatedConv, RIRBlock, conv3x3, from_log, to_log
from wdss.nets.wdss.heads import Head, SharedINR
from wdss.nets.wdss.polyphase import fits_cells, swt_tail_on_cells
from wdss.wavelets import WaveletTransform

__all__ = ["OUTPUT_SPACES", "WIDTHS", "WDSSNet"]

# What the head's coefficients (or image, for transform=none) represent: irradiance (the paper) or log1p of it.
OUTPUT_SPACES = ("linear", "log")
# A width preset for tests and stability checks (the presets runs use are the size configs, conf/size/*.yaml:
# wdss.config.sizes reads them).
WIDTHS: dict[str, dict] = {
    "tiny": dict(
        lr_widths=(8, 8, 8, 8),
        gbuffer_width=8,
        temporal_widths=(8, 4),
        fusion_widths=(8,),
        inr_width=8,
        mlp_width=8,
        mlp_depth=1,
        multi_inr_width=4,
    ),
}
GBUFFER_CHANNELS = 11  # wdss.data.GBUFFER_STACK
RGB = 3


def _pad(x: Tensor, pad: tuple[int, int, int, int]) -> Tensor:
    """Replicate-pad an odd frame to even; an even one is returned as is (F.pad would copy it)."""
    return F.pad(x, pad, mode="replicate") if any(pad) else x


def shuffle_channels_last(x: Tensor) -> Tensor:
    """``pixel_shuffle(x, 2)``, returned channels-last: the same values, one copy.

    Written as a permutation of the cells, because torch.compile's CPU code for it is much faster than for
    ``pixel_shuffle`` of a channels-last tensor (the add before it fused in; docs/performance.md); eager takes the
    same time either way. An exported graph keeps ``pixel_shuffle``: one
    ``DepthToSpace`` node, which engines know.
    """
    if torch.compiler.is_exporting():
        return F.pixel_shuffle(x.contiguous(memory_format=torch.channels_last), 2)
    n, c, h, w = x.shape
    cells = x.permute(0, 2, 3, 1).reshape(n, h, w, c // 4, 2, 2)  # (N, h, w, C, row phase, column phase)
    pixels = cells.permute(0, 1, 4, 2, 5, 3).reshape(n, 2 * h, 2 * w, c // 4)
    return pixels.permute(0, 3, 1, 2)


def _mlp(cin: int, width: int, depth: int, cout: int, final_relu: bool) -> nn.Sequential:
    layers: list[nn.Module] = []
    for i in range(depth):
        layers += [nn.Conv2d(cin if i == 0 else width, width, 1), nn.ReLU()]
    layers.append(nn.Conv2d(width if depth else cin, cout, 1))
    if final_relu:
        layers.append(nn.ReLU())
    return nn.Sequential(*layers)


class LRExtractor(nn.Module):
    """3x3 convolutions with ReLU on the unshuffled LR irradiance; output split fusion / INR amplitude."""

    def __init__(self, widths: Sequence[int], cin: int = 4 * RGB) -> None:
        super().__init__()
        chans = [cin, *widths]
        self.body = nn.Sequential(
            *[m for a, b in zip(chans, chans[1:], strict=False) for m in (conv3x3(a, b), nn.ReLU())]
        )
        self.split = widths[-1] // 2

    def forward(self, x: Tensor) -> tuple[Tensor, Tensor]:
        y = self.body(x)
        return y[:, : self.split], y[:, self.split :]


class GBufferExtractor(nn.Module):
    """DFASR's encoder: conv + block, then two dilated convs + blocks; output split fusion / INR frequency."""

    def __init__(self, cin: int, width: int, block: str = "double_residual") -> None:
        super().__init__()
        if block not in ("double_residual", "rir"):
            raise ValueError(f"model.gbuffer_block must be 'double_residual' or 'rir', got {block!r}")
        make = DoubleResidual if block == "double_residual" else RIRBlock
        self.body = nn.Sequential(
            conv3x3(cin, width), nn.ReLU(), make(width),
            conv3x3(width, width, dilation=2), nn.ReLU(), make(width),
            conv3x3(width, width, dilation=2), nn.ReLU(), make(width),
        )  # fmt: skip
        self.split = width // 2

    def forward(self, x: Tensor) -> tuple[Tensor, Tensor]:
        y = self.body(x)
        return y[:, : self.split], y[:, self.split :]


class TemporalExtractor(nn.Module):
    """Lightweight gated convolutions with ReLU between, on the unshuffled (history, temporal mask)."""

    def __init__(self, cin: int, widths: Sequence[int]) -> None:
        super().__init__()
        chans = [cin, *widths]
        self.layers = nn.ModuleList(GatedConv(a, b) for a, b in zip(chans, chans[1:], strict=False))

    def forward(self, x: Tensor) -> Tensor:
        for i, layer in enumerate(self.layers):
            x = layer(x)
            if i < len(self.layers) - 1:
                x = F.relu(x)
        return x


def _cell_positions(hr_pixels: int, lr_pixels: int, lr_cell: int, device: torch.device) -> tuple[Tensor, int]:
    """The centres of the HR/2 cells (HR pixels ``2j, 2j + 1``) along one axis of a frame of ``hr_pixels``, in LR
    cells of ``lr_cell`` LR pixels from the frame's start (LR cell ``i`` spans ``[i, i + 1]``), as an exact
    fraction: integer numerators (one per cell) over the returned denominator. Cell ``j``'s centre lies at
    ``(2j + 1) / hr_pixels`` of the frame; with an odd count the last cell is the last pixel and its padding: its
    centre is the frame's edge (a grid of ``ceil(n / 2)`` cells spans ``(n + 1) / n`` of the frame, not all of it).
    Integers, so that floors never flip at exact cell boundaries and an exported graph holds no float64 (which many
    engines lack)."""
    return (2 * torch.arange(math.ceil(hr_pixels / 2), device=device) + 1) * lr_pixels, lr_cell * hr_pixels


def cell_grid(
    hr_pixels: int, lr_pixels: int, device: torch.device, dtype: torch.dtype, lr_cell: int = 2
) -> tuple[Tensor, Tensor]:
    """Along one axis of an HR frame of ``hr_pixels`` and its LR frame of ``lr_pixels`` (real pixel counts): the
    index of each HR/2 cell's nearest LR cell and the offset from that cell's centre (in half cells, LIIF's
    ``[-1, 1]``). An LR cell is ``lr_cell`` LR pixels: 2 on the LR/2 grid, 1 on DFASR's full LR grid."""
    position, denominator = _cell_positions(hr_pixels, lr_pixels, lr_cell, device)
    cells = math.ceil(lr_pixels / lr_cell)  # LR cells across the frame (the last one padded for an odd frame)
    index = (position // denominator).clamp(0, cells - 1)  # position >= 0: integer division is the floor
    # 2 (position - index) - 1 half cells from the centre: an exact integer numerator, rounded once
    offset = (2 * (position - index * denominator) - denominator).to(torch.promote_types(dtype, torch.float32))
    return index, (offset / denominator).to(dtype)


def resample_to_cells(x: Tensor, hr_size: Sequence[int], lr_size: Sequence[int], lr_cell: int = 2) -> Tensor:
    """Bilinear samples of LR-cell features ``x`` at the HR/2 cell centres, both grids placed by the frames'
    real pixel counts (``hr_size``, ``lr_size``) as in :func:`cell_grid`; beyond the outer cell centres, the
    border value."""
    padded = any(n % 2 for n in hr_size) or (lr_cell == 2 and any(n % 2 for n in lr_size))
    if not padded:  # both grids span the frame exactly: F.interpolate places them alike
        half = tuple(n // 2 for n in hr_size)
        return F.interpolate(x, size=half, mode="bilinear", align_corners=False)
    for axis, hr_pixels, lr_pixels in ((-2, hr_size[0], lr_size[0]), (-1, hr_size[1], lr_size[1])):
        n = x.shape[axis]
        position, denominator = _cell_positions(hr_pixels, lr_pixels, lr_cell, device=x.device)
        # Each HR/2 centre in LR-cell index units (cell i centred at i), clamped: edge replication. Twice the
        # numerator, less half a cell: (2 position - denominator) / (2 denominator), exact.
        at = (2 * position - denominator).clamp(0, 2 * denominator * (n - 1))
        low = at // (2 * denominator)
        high = (low + 1).clamp_max(n - 1)
        t = (at - low * 2 * denominator).to(torch.promote_types(x.dtype, torch.float32)) / (2 * denominator)
        t = t.to(x.dtype).view([-1] + [1] * (-axis - 1))
        x = x.index_select(axis, low) * (1 - t) + x.index_select(axis, high) * t
    return x


class FourierINR(nn.Module):
    """Fourier-mapped implicit representation evaluated at every HR/2 cell.

    Amplitude from LR features (nearest LR/2 cell), frequencies from G-buffer features (``pairs`` 2-vectors),
    phase from ``1/s``; ``feature = A * [cos(pi theta), sin(pi theta)]`` with ``theta = F . delta + P``,
    then 1x1 MLP(s) and a 3x3 exit convolution.
    """

    def __init__(
        self,
        lr_channels: int,
        gb_channels: int,
        width: int,
        mlp_width: int,
        mlp_depth: int,
        out_channels: int,
        groups: int = 1,
        group_width: int = 32,
        final_relu: bool = True,
        phase_bias: bool = True,
    ) -> None:
        super().__init__()
        if width % 2:
            raise ValueError(f"model.inr_width must be even (cos and sin halves), got {width}")
        self.pairs = width // 2
        self.amplitude = conv3x3(lr_channels, width)
        self.frequency = conv3x3(gb_channels, 2 * self.pairs)
        self.phase = nn.Linear(1, self.pairs, bias=phase_bias)
        if out_channels % groups:
            raise ValueError(f"INR output {out_channels} does not split into {groups} subbands")
        if groups == 1:
            self.mlps = nn.ModuleList([_mlp(width, mlp_width, mlp_depth, out_channels, final_relu)])
        else:  # one MLP per subband, sharing the Fourier mapping
            self.mlps = nn.ModuleList(
                _mlp(width, group_width, mlp_depth, out_channels // groups, final_relu) for _ in range(groups)
            )
        self.exit = conv3x3(out_channels, out_channels)

    def forward(
        self,
        lr_feature: Tensor,
        gb_feature: Tensor,
        scale: Tensor,
        hr_size: Sequence[int] | None = None,
        lr_size: Sequence[int] | None = None,
        lr_cell: int = 2,
        lr_jitter: Tensor | None = None,
    ) -> Tensor:
        """``hr_size``, ``lr_size``: the frames' real pixel counts (default: the grids span them exactly);
        ``lr_cell``: LR pixels per cell of ``lr_feature`` (see :func:`cell_grid`); ``lr_jitter`` (N, 2): where the LR
        pixels were shaded (x, y in LR pixels), which moves the cells' centres the offsets are taken from."""
        n, _, hh, wh = gb_feature.shape
        hl, wl = lr_feature.shape[-2:]
        hr_size = hr_size or (2 * hh, 2 * wh)
        lr_size = lr_size or (lr_cell * hl, lr_cell * wl)
        rows, dy = cell_grid(hr_size[0], lr_size[0], gb_feature.device, gb_feature.dtype, lr_cell)
        cols, dx = cell_grid(hr_size[1], lr_size[1], gb_feature.device, gb_feature.dtype, lr_cell)
        amplitude = self.amplitude(lr_feature).index_select(-2, rows).index_select(-1, cols)
        frequency = self.frequency(gb_feature).view(n, self.pairs, 2, hh, wh)
        phase = self.phase((1.0 / scale).view(n, 1).to(gb_feature.dtype)).view(n, self.pairs, 1, 1)
        dy, dx = dy.view(1, 1, hh, 1), dx.view(1, 1, 1, wh)
        if lr_jitter is not None:  # an offset unit is one LR pixel / (lr_cell / 2): a cell is 2 units wide
            jitter = lr_jitter.to(dy.dtype).view(n, 2, 1, 1) * (2.0 / lr_cell)
            dy, dx = dy - jitter[:, 1:2], dx - jitter[:, 0:1]
        theta = frequency[:, :, 0] * dy + frequency[:, :, 1] * dx + phase
        feature = amplitude * torch.cat([torch.cos(math.pi * theta), torch.sin(math.pi * theta)], dim=1)
        out = self.mlps[0](feature) if len(self.mlps) == 1 else torch.cat([mlp(feature) for mlp in self.mlps], dim=1)
        return self.exit(out)


class Refinement(nn.Module):
    """A correction at full resolution after the synthesis (``refine_width > 0``, an option beside the paper's
    design): 3x3 convolutions on log1p of the synthesised image, the G-buffers and the spatial mask, whose output is
    added to the image in the head's output space. Its last layer starts at zero, so the network starts as it would
    without it; unlike the head's exit behind half-resolution cells, that layer sees full-resolution features and
    the loss's gradient from the first step."""

    def __init__(self, cin: int, width: int, depth: int = 3) -> None:
        super().__init__()
        if width < 1 or depth < 2:
            raise ValueError(f"model.refine_width must be >= 1 and model.refine_depth >= 2, got {width}, {depth}")
        chans = [cin] + [width] * (depth - 1) + [RGB]
        layers: list[nn.Module] = [
            m for a, b in zip(chans, chans[1:], strict=False) for m in (conv3x3(a, b), nn.ReLU())
        ]
        self.body = nn.Sequential(*layers[:-1])
        nn.init.zeros_(self.body[-1].weight)
        nn.init.zeros_(self.body[-1].bias)

    def forward(self, log_image: Tensor, guide: Tensor) -> Tensor:
        """The correction, from ``log_image`` (log1p irradiance, RGB) and ``guide`` (G-buffers and spatial mask)."""
        return self.body(torch.cat([log_image, guide], 1))


def _checked_choices(
    transform: str,
    basis: str,
    head: Head | None,
    wavelet: WaveletTransform | None,
    output_space: str,
    upsampler: nn.Module | None,
    residual_input: bool,
) -> tuple[str, str, Head]:
    """The network's choices checked, in the order a config is read: its transform and basis (from ``wavelet`` when
    the transform group built one) and its head (the paper's :class:`SharedINR` when None)."""
    if output_space not in OUTPUT_SPACES:
        raise ValueError(f"model.output_space must be one of {', '.join(OUTPUT_SPACES)}, got {output_space!r}")
    if upsampler is not None and not isinstance(upsampler, nn.Module):
        raise ValueError(
            f"model.net.upsampler must be a residual upsampler (conf/residual/*.yaml) or None, got {upsampler!r}"
        )
    if residual_input and upsampler is None:
        raise ValueError(
            "model.net.residual_input (recipe.residual_input) needs a residual upsampler "
            "(residual=bilinear, joint_bilateral or learned_bilateral)"
        )
    if wavelet is not None:  # a configured transform module (conf/transform/*.yaml) names both
        if wavelet.level != 1:
            raise ValueError(f"the network heads use one wavelet level, got level={wavelet.level}")
        transform, basis = wavelet.transform, wavelet.wavelet
    head = SharedINR() if head is None else head
    if not isinstance(head, Head):
        raise ValueError(f"model.net.head must be a head of wdss.nets.wdss.heads (conf/head/*.yaml), got {head!r}")
    if head.needs_subbands and transform == "none":
        raise ValueError(
            f"head={head.name} needs wavelet subbands, but transform=none has none: use transform=dwt or swt"
        )
    return transform, basis, head


class WDSSNet(SuperResolutionNet):
    """The WDSS super-resolution network for one transform x basis x head x temporal choice.

    ``transform``: ``none | dwt | swt``; ``basis``: an orthogonal PyWavelets basis; ``head``: a
    :class:`~wdss.nets.wdss.heads.Head` (default :class:`~wdss.nets.wdss.heads.SharedINR`, the paper's), which gives
    the fusion branch's and the INR's widths and merges their outputs; ``temporal``: whether the temporal branch
    exists. Widths default to the paper's (~0.57 M parameters with the SWT head). A ``wavelet`` module (as the
    ``transform`` config group builds it) replaces ``transform`` and ``basis``. ``upsampler``: a residual upsampler
    (wdss.nets.base; the ``residual`` config group builds one) whose upsampling of the LR irradiance the head's
    prediction is added to, or None (the paper): nothing.
    """

    def __init__(
        self,
        transform: str = "swt",
        basis: str = "haar",
        head: Head | None = None,
        temporal: bool = True,
        *,
        lr_widths: Sequence[int] = (32, 48, 48, 64),
        gbuffer_width: int = 64,
        gbuffer_block: str = "double_residual",
        temporal_widths: Sequence[int] = (32, 32, 16),
        fusion_widths: Sequence[int] = (64, 48),
        inr_width: int = 64,
        mlp_width: int = 64,
        mlp_depth: int = 3,
        multi_inr_width: int = 32,
        final_relu: bool = True,
        input_log: bool = True,
        wavelet: WaveletTransform | None = None,
        lr_unshuffle: bool = True,
        gbuffer_channels: Sequence[int] | None = None,
        fusion_final_relu: bool = False,
        phase_bias: bool = True,
        output_space: str = "linear",
        upsampler: nn.Module | None = None,
        exit_init: float = 0.0,
        residual_input: bool = False,
        refine_width: int = 0,
        refine_depth: int = 3,
    ) -> None:
        super().__init__()
        transform, basis, head = _checked_choices(
            transform, basis, head, wavelet, output_space, upsampler, residual_input
        )
        self.output_space = output_space
        # Registered first, as the network always built its learned kernel: the same state_dict order.
        self.upsampler = upsampler
        # The G-buffer branch also sees the upsampled irradiance the head corrects: the correction depends on where
        # that upsampling errs, which the network cannot see from the LR and G-buffers alone.
        self.residual_input = bool(residual_input)
        self.transform, self.basis, self.head, self.temporal = transform, basis, head, temporal
        self.input_log = input_log
        self.wavelet = WaveletTransform(transform, basis)
        # Channels on the HR/2 grid before the head: SWT subbands are full resolution (4 phases each).
        self.coeff_channels = 4 * RGB  # none: RGB x 4 phases; dwt: 4 bands x RGB
        self.half_channels = 4 * 4 * RGB if transform == "swt" else 4 * RGB
        # DFASR's differences from WDSS are options: an LR branch on the full LR grid (no unshuffle), a subset of
        # the G-buffer stack (indices into wdss.data.GBUFFER_STACK channels), a ReLU after the fusion output, and
        # a phase without bias.
        self.lr_unshuffle = lr_unshuffle
        self.gbuffer_channels = list(gbuffer_channels) if gbuffer_channels is not None else None
        n_gbuffer = len(self.gbuffer_channels) if self.gbuffer_channels is not None else GBUFFER_CHANNELS
        # The modules in the order they were always created: the same parameters for the same seed.
        self.lr = LRExtractor(lr_widths, cin=4 * RGB if lr_unshuffle else RGB)
        gbuffer_in = n_gbuffer + 1 + (RGB if self.residual_input else 0)
        self.gbuffer = GBufferExtractor(4 * gbuffer_in, gbuffer_width, gbuffer_block)
        self.temporal_branch = TemporalExtractor(4 * (RGB + 5), temporal_widths) if temporal else None
        fusion_in = self.lr.split + self.gbuffer.split + (temporal_widths[-1] if temporal else 0)
        self._build_head(fusion_in, fusion_widths, fusion_final_relu)
        self.inr = FourierINR(
            lr_widths[-1] - self.lr.split, gbuffer_width - self.gbuffer.split, inr_width, mlp_width, mlp_depth,
            self.head.widths(self.half_channels)[1], self.head.inr_groups, multi_inr_width, final_relu, phase_bias,
        )  # fmt: skip
        self._build_exit(exit_init)
        self.refine = Refinement(RGB + n_gbuffer + 1, refine_width, refine_depth) if refine_width else None

    def _build_head(self, fusion_in: int, fusion_widths: Sequence[int], final_relu: bool) -> None:
        """The fusion branch: 3x3 convolutions from the extractors' features to the head's fusion output."""
        fusion_out = self.head.widths(self.half_channels)[0]
        chans = [fusion_in, *fusion_widths]
        layers: list[nn.Module] = [
            m for a, b in zip(chans, chans[1:], strict=False) for m in (conv3x3(a, b), nn.ReLU())
        ]
        self.fusion = nn.Sequential(*layers, conv3x3(chans[-1], fusion_out), *([nn.ReLU()] if final_relu else []))

    def _build_exit(self, exit_init: float) -> None:
        """The exit convolution: on RGB at H (none), on the DWT bands at H/2, on the SWT subbands at H."""
        exit_channels = RGB if self.transform == "none" else self.coeff_channels
        self.exit = conv3x3(exit_channels, exit_channels)
        if self.upsampler is not None:
            # exit_init 0: the network starts exactly as its upsampler (its correction is zero); > 0 scales the
            # default initialisation instead: a zero exit passes no gradient to the layers before it, which then
            # stay at their random initialisation for long, as the exit's own weights grow only slowly.
            with torch.no_grad():
                self.exit.weight.mul_(exit_init)
                self.exit.bias.mul_(exit_init)

    @property
    def residual(self) -> str:
        """The residual upsampler's name, ``none`` without one."""
        return "none" if self.upsampler is None else self.upsampler.name

    @property
    def inputs(self) -> tuple[str, ...]:
        """The batch keys this network consumes (the data side reads exactly what these need): its own, then those
        of its residual upsampler that it does not read itself, and ``lr_jitter`` (the INR's offsets)."""
        keys = ("lr", "gbuffer", "spatial_mask") + (("history", "temporal_mask") if self.temporal else ())
        upsampler = self.upsampler.upsample_inputs if self.upsampler is not None else ()
        return tuple(dict.fromkeys((*keys, *upsampler, "lr_jitter")))

    def _to_input(self, x: Tensor) -> Tensor:
        return to_log(x) if self.input_log else x

    def forward(
        self,
        lr: Tensor,
        gbuffer: Tensor,
        spatial_mask: Tensor,
        scale: Tensor,
        history: Tensor | None = None,
        temporal_mask: Tensor | None = None,
        brdf: Tensor | None = None,
        lr_brdf: Tensor | None = None,
        lr_guide: Tensor | None = None,
        lr_jitter: Tensor | None = None,
        *,
        subbands: bool = True,
    ) -> dict[str, Tensor | None]:
        """``subbands``: also return the predicted wavelet coefficients (``coefficients``; the wavelet loss and the
        subband panels read them). An inference graph that needs only the image passes False: the SWT head of a
        channels-last network then computes its tail on half-resolution cells (:mod:`wdss.nets.wdss.polyphase`) and
        returns no coefficients, as exported graphs always do."""
        height, width = gbuffer.shape[-2:]
        pad_hr = (0, width % 2, 0, height % 2)
        pad_lr = (0, lr.shape[-1] % 2, 0, lr.shape[-2] % 2)
        lr_cell = 2 if self.lr_unshuffle else 1  # LR pixels per cell of the LR features
        lr_in = self._to_input(lr)
        if self.lr_unshuffle:
            lr_in = F.pixel_unshuffle(_pad(lr_in, pad_lr), 2)
        guide = gbuffer  # the whole stack: a joint-bilateral residual base reads depth, normal and albedo
        if self.gbuffer_channels is not None:
            gbuffer = gbuffer[:, self.gbuffer_channels]
        upsampled = self._upsample(lr, guide, brdf, lr_brdf, lr_guide, lr_jitter)
        gb_stack = [gbuffer, spatial_mask] + ([self._to_input(upsampled)] if self.residual_input else [])
        gb_in = F.pixel_unshuffle(_pad(torch.cat(gb_stack, 1), pad_hr), 2)
        lr_fusion, lr_inr = self.lr(lr_in)
        gb_fusion, gb_inr = self.gbuffer(gb_in)
        parts = [resample_to_cells(lr_fusion, (height, width), lr.shape[-2:], lr_cell), gb_fusion]
        if self.temporal_branch is not None:
            if history is None or temporal_mask is None:
                raise ValueError("this network has a temporal branch: it needs history and temporal_mask")
            t_in = torch.cat([self._to_input(history), temporal_mask], 1)
            parts.append(self.temporal_branch(F.pixel_unshuffle(_pad(t_in, pad_hr), 2)))
        fusion = self.fusion(torch.cat(parts, 1))
        inr = self.inr(lr_inr, gb_inr, scale, (height, width), lr.shape[-2:], lr_cell, lr_jitter)
        merged = self.head.merge(fusion, inr)
        base = None if upsampled is None else _pad(self._to_space(upsampled), pad_hr)
        coefficients: Tensor | None
        if self.transform == "none":
            image = self.exit(F.pixel_shuffle(merged, 2)).float()
            if base is not None:
                image = image + base
            coefficients = None
        elif (
            self.transform == "swt"
            and (
                torch.compiler.is_exporting()
                or (not subbands and merged.is_contiguous(memory_format=torch.channels_last))
            )
            and fits_cells(merged, self.wavelet.filter_rows.shape[-1])
        ):
            # Without the subbands, on channels-last cells and in exported graphs, the tail runs on the half-resolution
            # cells (wdss.nets.wdss.polyphase), which is faster there. Synthesis undoes analysis, so a residual base is
            # added to the image, not to the subbands. float32 under mixed precision, as the direct synthesis below.
            with torch.autocast(merged.device.type, enabled=False):
                image = swt_tail_on_cells(
                    merged.float(), self.exit.weight.float(), self.exit.bias.float(), self.wavelet.filter_rows.float()
                )
            if base is not None:
                image = image + base
            coefficients = None
        else:
            if self.transform == "swt":
                # Channels-last from here on: on CPU the exit convolution of 12 full-resolution channels, the shuffle
                # and the synthesis' convolutions all run faster in it, and the synthesis needs no padded copy.
                merged = shuffle_channels_last(merged)
            coefficients = self.exit(merged).float()
            # The synthesis stays float32 under mixed precision: it sums large subbands that nearly cancel.
            with torch.autocast(coefficients.device.type, enabled=False):
                if base is not None:  # the residual lives in the coefficient domain: the wavelet loss sees it whole
                    coefficients = coefficients + self.wavelet.analysis(base)
                image = self.wavelet(coefficients)  # forward() is the synthesis; a submodule for FLOP counts
        image = image[..., :height, :width]
        if self.refine is not None:  # after the synthesis: the subbands (and the wavelet loss) are those before it
            log_image = image if self.output_space == "log" else to_log(image.clamp_min(0.0))
            image = image + self.refine(log_image, torch.cat([gbuffer, spatial_mask], 1))
        if coefficients is not None and self.transform == "swt":
            coefficients = coefficients[..., :height, :width]
        return {"irradiance": self._from_space(image), "coefficients": coefficients}

    # ------------------------------------------------------------------------------------------ output space

    def _to_space(self, irradiance: Tensor) -> Tensor:
        return to_log(irradiance.float()) if self.output_space == "log" else irradiance.float()

    def _from_space(self, image: Tensor) -> Tensor:
        if self.output_space == "log":
            return from_log(image)
        return image.clamp_min(0.0)

    def _upsample(
        self,
        lr: Tensor,
        gbuffer: Tensor,
        brdf: Tensor | None = None,
        lr_brdf: Tensor | None = None,
        lr_guide: Tensor | None = None,
        lr_jitter: Tensor | None = None,
    ) -> Tensor | None:
        """The upsampled LR irradiance the head adds to (linear, HR size), or None without a residual."""
        if self.upsampler is None:
            return None
        return self.upsampler.upsample(lr, gbuffer, brdf, lr_brdf, lr_guide, lr_jitter)

    def target_coefficients(self, irradiance: Tensor) -> Tensor | None:
        """The analysis of a target irradiance ``(N, 3, H, W)`` in the space and layout of the predicted
        coefficients (padded to even and cropped back as the head does), for the wavelet loss term."""
        if self.transform == "none":
            return None
        height, width = irradiance.shape[-2:]
        padded = _pad(self._to_space(irradiance), (0, width % 2, 0, height % 2))
        coefficients = self.wavelet.analysis(padded)
        return coefficients[..., :height, :width] if self.transform == "swt" else coefficients
