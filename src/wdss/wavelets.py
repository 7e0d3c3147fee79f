"""Exact 2-D wavelet analysis and synthesis in torch: DWT, SWT and the identity.

Every transform maps an image batch ``x`` of shape ``(N, C, H, W)`` to a coefficient tensor and back, with
a circular (periodic) boundary and the filter banks of PyWavelets. Only orthogonal bases are accepted
(``haar``, ``db1..db38``, ``sym2..sym20``, ``coif1..coif17``): for them the synthesis is the exact inverse.

Coefficient layout (band-major, the one layout of wdss)
-------------------------------------------------------
Level 1 is ``[LL, LH, HL, HH] x C``: channel ``b * C + c`` holds band ``b`` of input channel ``c``, with the
bands in PyWavelets' order ``(cA, cH, cV, cD)``. ``LH``/``cH`` is high-pass along H (rows) and low-pass
along W; ``HL``/``cV`` is low-pass along H and high-pass along W.

* ``dwt``: ``(N, 4C, H/2, W/2)``, equal to ``pywt.dwt2(x, wavelet, mode="periodization")``.
* ``swt``: ``(N, 4C, H, W)``, equal to ``pywt.swt2(x, wavelet, level=1, trim_approx=True, norm=False)``.
* ``none``: the identity, so that model code has one shape of call for every transform.

Level ``L > 1`` keeps the same pattern, coarsest level first, exactly in the order of PyWavelets'
``wavedec2`` / ``swt2(..., trim_approx=True)`` lists ``[cA_L, (cH_L, cV_L, cD_L), ..., (cH_1, cV_1, cD_1)]``:

* ``swt``: ``(N, (1 + 3L) C, H, W)`` = ``[LL_L, LH_L, HL_L, HH_L, LH_{L-1}, HL_{L-1}, HH_{L-1}, ..., HH_1]``,
  each group of C channels.
* ``dwt``: ``(N, 4^L C, H/2^L, W/2^L)``; the finer detail bands of level ``l`` (size ``H/2^l``) are stored
  space-to-depth, ``pixel_unshuffle(band, 2^(L-l))``, so every level lives on the coarsest grid. Within a
  level the channels are ``[LH, HL, HH]`` x C x ``r^2`` phases (torch's pixel_unshuffle order).

Sizes: SWT works for every size, odd and smaller than the filter included (PyWavelets itself accepts only
multiples of ``2^L``; where it does, the results agree). DWT needs ``H`` and ``W`` divisible by ``2^L``.

Implementation: separable and polyphase convolutions, all channels folded into the batch, so a transform is
a handful of convolutions whatever N and C are. The SWT synthesis is the frame's pseudo-inverse
(``1/2`` times the adjoint per axis), which is the exact inverse on analysis outputs and equals
``pywt.iswt2`` on any coefficients; the DWT synthesis is the adjoint of the (orthogonal) analysis.
"""

from __future__ import annotations

import functools
from typing import Literal

import numpy as np
import pywt
import torch
import torch.nn.functional as F
from torch import Tensor, nn

__all__ = [
    "TRANSFORMS",
    "Transform",
    "WaveletTransform",
    "analysis",
    "coefficient_channels",
    "synthesis",
]

Transform = Literal["none", "dwt", "swt"]
TRANSFORMS: tuple[str, ...] = ("none", "dwt", "swt")


# --------------------------------------------------------------------------------------------------------
# Filter banks (numpy, float64, cached per basis)
# --------------------------------------------------------------------------------------------------------


@functools.cache
def _filters(wavelet: str) -> tuple[np.ndarray, np.ndarray]:
    """The decomposition low- and high-pass filters of an orthogonal PyWavelets basis."""
    try:
        w = pywt.Wavelet(wavelet)
    except ValueError as err:
        raise ValueError(f"unknown wavelet basis {wavelet!r}: use a PyWavelets name such as 'haar', 'db4'") from err
    if not w.orthogonal:
        raise ValueError(
            f"wavelet basis {wavelet!r} is not orthogonal: wdss needs an orthogonal basis (haar, dbN, symN, coifN)"
        )
    lo = _orthonormalise(np.asarray(w.dec_lo, dtype=np.float64))
    taps = len(lo)
    # PyWavelets' quadrature-mirror rule: dec_hi[n] = (-1)^(n+1) dec_lo[F-1-n].
    hi = np.array([(-1) ** (n + 1) * lo[taps - 1 - n] for n in range(taps)])
    return lo, hi


def _orthonormalise(lo: np.ndarray) -> np.ndarray:
    """Project a low-pass filter onto the orthonormality constraints ``sum_n h[n] h[n+2k] = delta_k``.

    Some of PyWavelets' tabulated filters (sym4: 5e-13, sym8: 2e-13) are orthonormal only to about 12 digits,
    which caps float64 reconstruction at ~1e-12. Two minimum-norm Gauss-Newton steps make them orthonormal
    to machine precision while moving each tap by less than that table error.
    """
    taps = len(lo)
    h = lo.copy()
    for _ in range(2):
        residual = np.array([h[: taps - 2 * k] @ h[2 * k :] - (k == 0) for k in range(taps // 2)])
        jacobian = np.zeros((taps // 2, taps))
        for k in range(taps // 2):
            jacobian[k, : taps - 2 * k] += h[2 * k :]
            jacobian[k, 2 * k :] += h[: taps - 2 * k]
        h = h - np.linalg.lstsq(jacobian, residual, rcond=None)[0]
    return h


@functools.cache
def _filter_rows(wavelet: str) -> np.ndarray:
    """The two decomposition filters as rows ``(2, F)``: ``[lo, hi]``."""
    return np.stack(_filters(wavelet))


def _analysis_pads(taps: int, dilation: int) -> tuple[int, int]:
    """Circular padding that makes a correlation with the flipped filter reproduce PyWavelets' phase.

    PyWavelets' periodization computes ``y[o] = sum_j f[j] x[(s o + E/2 - j) mod N]`` for an (upsampled)
    filter of length ``E = F * dilation`` and step ``s``; as a correlation with the flipped filter that is a
    left pad of ``(F/2 - 1) * dilation`` and a right pad of ``F/2 * dilation``, for ``s`` = 1 and 2 alike.
    """
    return (taps // 2 - 1) * dilation, taps // 2 * dilation


# --------------------------------------------------------------------------------------------------------
# Circular padding into a channels-last buffer
# --------------------------------------------------------------------------------------------------------


def _circular_pad(x: Tensor, top: int, bottom: int, left: int, right: int) -> Tensor:
    """Periodic extension of the last two dimensions, returned channels-last.

    The filter-bank convolutions below run much faster on channels-last tensors on CPU (oneDNN), so the one
    copy a pad costs also does the layout change. Pads larger than the image wrap around more than once.
    """
    n, c, height, width = x.shape
    if max(top, bottom) > height or max(left, right) > width:
        rows = torch.arange(-top, height + bottom, device=x.device) % height
        cols = torch.arange(-left, width + right, device=x.device) % width
        wrapped = x.index_select(-2, rows).index_select(-1, cols)
        return wrapped.contiguous(memory_format=torch.channels_last)
    if torch.compiler.is_exporting():
        # Out-of-place slices: an exporter folds the in-place writes below into a frame-sized constant (ONNX).
        x = torch.cat([x[..., height - top :, :], x, x[..., :bottom, :]], dim=-2)
        return torch.cat([x[..., width - left :], x, x[..., :right]], dim=-1)
    out = torch.empty(
        (n, c, height + top + bottom, width + left + right),
        dtype=x.dtype,
        device=x.device,
        memory_format=torch.channels_last,
    )
    rows = slice(top, top + height)
    out[..., rows, left : left + width] = x
    out[..., :top, left : left + width] = x[..., height - top :, :]
    out[..., top + height :, left : left + width] = x[..., :bottom, :]
    out[..., :left] = out[..., width : width + left]
    out[..., left + width :] = out[..., left : left + right]
    return out


# --------------------------------------------------------------------------------------------------------
# One level of the separable filter bank on (N, C, H, W), band-major without any channel shuffle
# --------------------------------------------------------------------------------------------------------
#
# Both steps are convolutions whose weights are block-diagonal over channels, laid out so that the output
# channel order *is* the band-major order: the W step maps c -> (hW, c), the H step (2 groups, one per hW)
# maps (hW, c) -> (hW, hH, c), and band index 2 hW + hH is [LL, LH, HL, HH]. Dense block-diagonal weights
# cost C times the multiply-adds of depthwise ones, but on CPU these convolutions are memory-bound and the
# dense form avoids a permutation copy of the 4x larger coefficient tensor; channels are therefore processed
# in chunks of at most _CHUNK (folded into the batch), and only a tensor of more channels pays one shuffle.

_CHUNK = 16


def _chunk(channels: int) -> int:
    return max(d for d in range(1, min(channels, _CHUNK) + 1) if channels % d == 0)


def _step_w(rows: Tensor, channels: int) -> Tensor:
    """Analysis weight along W: ``(2C, C, 1, F)`` with ``w[hW*C + c, c] = rows[hW]``."""
    eye = torch.eye(channels, dtype=rows.dtype, device=rows.device)
    return torch.einsum("bk,ij->bijk", rows, eye).reshape(2 * channels, channels, 1, -1)


def _step_h(rows: Tensor, channels: int) -> Tensor:
    """Analysis weight along H, 2 groups: ``(4C, C, F, 1)`` with ``w[(2 hW + hH) C + c, c] = rows[hH]``."""
    eye = torch.eye(channels, dtype=rows.dtype, device=rows.device)
    one = torch.einsum("bk,ij->bijk", rows, eye).reshape(2 * channels, channels, -1, 1)
    return torch.cat([one, one])


def _analysis_level(x: Tensor, rows: Tensor, *, stride: int, dilation: int) -> Tensor:
    """(N, C, H, W) -> (N, 4C, H/stride, W/stride), band-major."""
    c = x.shape[1]
    taps = rows.shape[-1]
    flipped = rows.flip(-1)  # correlation with the flipped filter is PyWavelets' convolution
    left, right = _analysis_pads(taps, dilation)
    padded = _circular_pad(x, left, right, left, right)
    along_w = F.conv2d(padded, _step_w(flipped, c), stride=(1, stride), dilation=(1, dilation))
    return F.conv2d(along_w, _step_h(flipped, c), stride=(stride, 1), dilation=(dilation, 1), groups=2)


def _synthesis_step_h(rows: Tensor, channels: int, transposed: bool) -> Tensor:
    # The adjoint of the H step: (hW, hH, c) -> (hW, c), 2 groups.
    weight = _step_h(rows, channels)  # (4C, C, F, 1): [out=(hW, hH, c), in=c]
    if transposed:  # conv_transpose2d weight is (in, out / groups, ...), which is the analysis layout
        return weight
    # As a correlation: (2C out, 2C in / 2 groups) = per group (C, 2C).
    return weight.reshape(2, 2 * channels, channels, -1, 1).transpose(1, 2).reshape(2 * channels, 2 * channels, -1, 1)


def _synthesis_step_w(rows: Tensor, channels: int, transposed: bool) -> Tensor:
    weight = _step_w(rows, channels)  # (2C, C, 1, F): [out=(hW, c), in=c]
    return weight if transposed else weight.transpose(0, 1).contiguous()


def _circular_correlation(x: Tensor, weight: Tensor, dim: int, before: int, dilation: int, groups: int) -> Tensor:
    """The correlation along ``dim`` (-2 rows, -1 columns) of ``x`` extended periodically, ``before`` samples in
    front, without copying ``x`` into a padded buffer: a zero-padded convolution, whose outputs that reach across
    the ends are then replaced by the correlation of the two ends joined (``x`` spans at least the filter)."""
    taps = weight.shape[dim]
    span = (taps - 1) * dilation
    after = span - before
    reach = max(before, after)  # symmetric zero padding; zero taps make up the difference
    extra = ((reach - before) // dilation, (reach - after) // dilation)
    if dim == -1:
        conv = functools.partial(F.conv2d, dilation=(1, dilation), groups=groups)
        out = conv(x, F.pad(weight, extra), padding=(0, reach))
    else:
        conv = functools.partial(F.conv2d, dilation=(dilation, 1), groups=groups)
        out = conv(x, F.pad(weight, (0, 0, *extra)), padding=(reach, 0))
    n = x.shape[dim]
    # ends[j] = x[(n - span + j) mod n], so seam[j] is output (j - after) mod n: the last `after`, then the first.
    seam = conv(torch.cat([x.narrow(dim, n - span, span), x.narrow(dim, 0, span)], dim=dim), weight)
    out.narrow(dim, n - after, after).copy_(seam.narrow(dim, 0, after))
    out.narrow(dim, 0, before).copy_(seam.narrow(dim, after, before))
    return out


def _swt_synthesis_level(coeffs: Tensor, rows: Tensor, *, dilation: int) -> Tensor:
    """(N, 4C, H, W) band-major -> (N, C, H, W): half the adjoint per axis (the frame's pseudo-inverse)."""
    c = coeffs.shape[1] // 4
    taps = rows.shape[-1]
    left, right = _analysis_pads(taps, dilation)
    half = 0.5 * rows
    along_h, along_w = _synthesis_step_h(half, c, False), _synthesis_step_w(half, c, False)
    # The adjoint of a correlation with the flipped filter correlates with the filter itself, pads swapped.
    if (
        coeffs.is_contiguous(memory_format=torch.channels_last)
        and min(coeffs.shape[-2:]) >= left + right
        and not torch.compiler.is_exporting()
    ):
        # Already in the convolutions' fast layout (the network's subbands are): no padded copy.
        rows_done = _circular_correlation(coeffs, along_h, -2, right, dilation, groups=2)
        return _circular_correlation(rows_done, along_w, -1, right, dilation, groups=1)
    padded = _circular_pad(coeffs, right, left, right, left)
    rows_done = F.conv2d(padded, along_h, dilation=(dilation, 1), groups=2)
    return F.conv2d(rows_done, along_w, dilation=(1, dilation))


def _dwt_synthesis_level(coeffs: Tensor, rows: Tensor) -> Tensor:
    """(N, 4C, h, w) band-major -> (N, C, 2h, 2w): the adjoint of the orthogonal analysis.

    Transposed convolutions of the periodically extended coefficients: extending by ``F // 4`` on each side
    supplies every wrapped contribution, and the crop keeps the ``2h`` (``2w``) samples that received all.
    """
    c = coeffs.shape[1] // 4
    taps = rows.shape[-1]
    flipped = rows.flip(-1)
    ext = taps // 4
    left, _ = _analysis_pads(taps, 1)
    padded = _circular_pad(coeffs, ext, ext, ext, ext)
    along_h = F.conv_transpose2d(padded, _synthesis_step_h(flipped, c, True), stride=(2, 1), groups=2)
    full = F.conv_transpose2d(along_h, _synthesis_step_w(flipped, c, True), stride=(1, 2))
    h, w = coeffs.shape[-2:]
    start = 2 * ext + left
    return full[..., start : start + 2 * h, start : start + 2 * w]


# --------------------------------------------------------------------------------------------------------
# Channel chunks and the multi-level drivers on (N, C, H, W)
# --------------------------------------------------------------------------------------------------------


def _merge_chunks(part: Tensor, n: int, groups: int) -> Tensor:
    """(N*q, groups*m, h, w), band-major per chunk -> (N, groups*q*m, h, w), band-major over all channels."""
    nq, channels, h, w = part.shape
    if nq == n:
        return part
    return part.reshape(n, nq // n, groups, channels // groups, h, w).transpose(1, 2).reshape(n, -1, h, w)


def _split_chunks(part: Tensor, q: int, groups: int) -> Tensor:
    """The inverse of :func:`_merge_chunks`."""
    n, channels, h, w = part.shape
    if q == 1:
        return part
    return part.reshape(n, groups, q, channels // groups // q, h, w).transpose(1, 2).reshape(n * q, -1, h, w)


def _analysis(x: Tensor, rows: Tensor, transform: str, level: int) -> Tensor:
    _check_not_empty(x, "wavelet analysis")
    n, c, h, w = x.shape
    if transform == "dwt" and (h % 2**level or w % 2**level):
        raise ValueError(
            f"DWT of level {level} needs height and width divisible by {2**level}, got {h}x{w}; "
            "crop or pad the frame, or use the SWT, which takes any size"
        )
    chunk = _chunk(c)
    approx = x.reshape(n * (c // chunk), chunk, h, w)
    parts: list[tuple[Tensor, int]] = []  # (part, band groups), finest level first
    for lev in range(1, level + 1):
        if transform == "swt":
            bands = _analysis_level(approx, rows, stride=1, dilation=2 ** (lev - 1))
        else:
            bands = _analysis_level(approx, rows, stride=2, dilation=1)
        if level == 1:
            return _merge_chunks(bands, n, 4)
        approx, detail = bands[:, :chunk], bands[:, chunk:]
        if transform == "dwt" and lev < level:  # finer DWT levels go space-to-depth onto the coarsest grid
            detail = F.pixel_unshuffle(detail, 2 ** (level - lev))
        parts.append((detail, 3))
    parts.append((approx, 1))
    return torch.cat([_merge_chunks(part, n, groups) for part, groups in reversed(parts)], dim=1)


def _synthesis(coeffs: Tensor, rows: Tensor, transform: str, level: int) -> Tensor:
    _check_not_empty(coeffs, "wavelet synthesis")
    n, total = coeffs.shape[:2]
    c = total // coefficient_channels(transform, 1, level)
    if c * coefficient_channels(transform, 1, level) != total:
        raise ValueError(
            f"{transform} synthesis of level {level} needs a multiple of "
            f"{coefficient_channels(transform, 1, level)} coefficient channels, got {total}"
        )
    chunk = _chunk(c)
    q = c // chunk
    if level == 1:
        approx = _synthesis_level(_split_chunks(coeffs, q, 4), rows, transform, 1)
        return approx.reshape(n, c, *approx.shape[-2:])
    approx = _split_chunks(coeffs[:, :c], q, 1)
    start = c
    for lev in range(level, 0, -1):
        factor = 2 ** (level - lev) if transform == "dwt" else 1
        width = 3 * c * factor * factor
        detail = _split_chunks(coeffs[:, start : start + width], q, 3)
        start += width
        if factor > 1:
            detail = F.pixel_shuffle(detail, factor)
        approx = _synthesis_level(torch.cat([approx, detail], dim=1), rows, transform, lev)
    return approx.reshape(n, c, *approx.shape[-2:])


def _synthesis_level(bands: Tensor, rows: Tensor, transform: str, lev: int) -> Tensor:
    if transform == "swt":
        return _swt_synthesis_level(bands, rows, dilation=2 ** (lev - 1))
    return _dwt_synthesis_level(bands, rows)


def coefficient_channels(transform: str, channels: int, level: int = 1) -> int:
    """How many coefficient channels ``analysis`` returns for ``channels`` image channels."""
    _check_transform(transform)
    _check_level(level)
    return {"none": channels, "swt": (1 + 3 * level) * channels, "dwt": 4**level * channels}[transform]


def _check_transform(transform: str) -> None:
    if transform not in TRANSFORMS:
        raise ValueError(f"unknown wavelet transform {transform!r}: expected one of {', '.join(TRANSFORMS)}")


def _check_input(x: Tensor, what: str) -> None:
    if x.ndim != 4:
        raise ValueError(f"{what} expects a 4-D tensor (N, C, H, W), got shape {tuple(x.shape)}")
    if not x.is_floating_point():
        raise TypeError(f"{what} expects a floating-point tensor, got {x.dtype}")


def _check_not_empty(x: Tensor, what: str) -> None:
    # An empty batch (N = 0) is a valid no-op; no channels or no pixels is a caller's mistake, which the
    # convolutions would only report as an empty max() or a ZeroDivisionError.
    n, c, h, w = x.shape
    if c == 0 or h == 0 or w == 0:
        raise ValueError(f"{what} needs C, H and W >= 1, got shape (N, C, H, W) = {tuple(x.shape)}")


def _check_level(level: int) -> None:
    if not isinstance(level, int) or isinstance(level, bool) or level < 1:
        raise ValueError(f"wavelet level must be an integer >= 1, got {level!r}")


# --------------------------------------------------------------------------------------------------------
# Public API
# --------------------------------------------------------------------------------------------------------


def analysis(x: Tensor, *, transform: str, wavelet: str = "haar", level: int = 1) -> Tensor:
    """Wavelet analysis of ``x`` (N, C, H, W), band-major; see the module docstring for layouts.

    ``transform="dwt"`` equals ``pywt.dwt2``/``wavedec2`` with ``mode="periodization"``;
    ``transform="swt"`` equals ``pywt.swt2(..., trim_approx=True, norm=False)``; ``"none"`` returns ``x``.
    The result is channels-last in memory, the fast layout of these convolutions.
    """
    _check_transform(transform)
    _check_input(x, "wavelet analysis")
    if transform == "none":
        return x
    _check_level(level)
    return _analysis(x, _rows(wavelet, x), transform, level)


def synthesis(coeffs: Tensor, *, transform: str, wavelet: str = "haar", level: int = 1) -> Tensor:
    """Wavelet synthesis: the exact inverse of :func:`analysis`, equal to ``pywt.iswt2``/``waverec2``."""
    _check_transform(transform)
    _check_input(coeffs, "wavelet synthesis")
    if transform == "none":
        return coeffs
    _check_level(level)
    return _synthesis(coeffs, _rows(wavelet, coeffs), transform, level)


def _compiling_for_run() -> bool:
    """Whether torch.compile (not an exporter) is tracing."""
    return torch.compiler.is_compiling() and not torch.compiler.is_exporting()


@torch.compiler.disable
def _eager_synthesis(module: WaveletTransform, coeffs: Tensor) -> Tensor:
    return module.synthesis(coeffs)


def _rows(wavelet: str, like: Tensor) -> Tensor:
    return torch.as_tensor(_filter_rows(wavelet), dtype=like.dtype, device=like.device)


class WaveletTransform(nn.Module):
    """One transform x basis x level as a module, for networks: ``forward`` is the synthesis.

    The filter bank is a buffer, so ``.to(device)``/``.double()`` move it with the model. It is not
    persistent: it follows from ``(transform, wavelet)``, which the run's config stores, so a checkpoint
    holds only learned weights.
    """

    filter_rows: Tensor

    def __init__(self, transform: str = "swt", wavelet: str = "haar", level: int = 1) -> None:
        super().__init__()
        _check_transform(transform)
        _check_level(level)
        self.transform = transform
        self.wavelet = wavelet
        self.level = level
        rows = _filter_rows(wavelet) if transform != "none" else np.zeros((2, 0))
        self.register_buffer("filter_rows", torch.as_tensor(rows, dtype=torch.float32), persistent=False)

    def coefficient_channels(self, channels: int) -> int:
        return coefficient_channels(self.transform, channels, self.level)

    def analysis(self, x: Tensor) -> Tensor:
        _check_input(x, "wavelet analysis")
        if self.transform == "none":
            return x
        return _analysis(x, self.filter_rows.to(x.dtype), self.transform, self.level)

    def synthesis(self, coeffs: Tensor) -> Tensor:
        _check_input(coeffs, "wavelet synthesis")
        if self.transform == "none":
            return coeffs
        return _synthesis(coeffs, self.filter_rows.to(coeffs.dtype), self.transform, self.level)

    def forward(self, coeffs: Tensor) -> Tensor:
        if self.transform == "swt" and coeffs.device.type == "cpu" and _compiling_for_run():
            # torch.compile's code for this filter bank on CPU is slower than eager's channels-last convolutions,
            # so a compiled network runs it eagerly. An exported graph (ONNX) still holds the whole synthesis.
            return _eager_synthesis(self, coeffs)
        return self.synthesis(coeffs)

    def extra_repr(self) -> str:
        return f"transform={self.transform!r}, wavelet={self.wavelet!r}, level={self.level}"
