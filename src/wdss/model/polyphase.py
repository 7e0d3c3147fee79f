"""The SWT head's full-resolution tail (exit convolution, then one level of SWT synthesis), computed on 2x2 cells.

The network ends with ``synthesis(exit(pixel_shuffle(merged, 2)))``: a 3x3 convolution of 12 full-resolution subband
maps, then the circular filter bank. :func:`swt_tail_on_cells` computes the same image from ``merged`` (the 48 channels
on the half-resolution grid) without going to full resolution until the end: every convolution is rewritten as one on
2x2 cells (its *polyphase* form), and only the 3-channel image is shuffled out. In an exported graph on onnxruntime's
CPU provider this avoids the full-resolution ``DepthToSpace`` of 12 channels and the reorders of its 12-channel
convolutions (SWT-db4 at 1080p 2x: -93 ms, its time / none's 1.117 -> 1.089); eager and torch.compile run the direct
form faster, so the network takes this one only when exported.

Cells. Channel ``c * 4 + 2 * py + px`` of a cell tensor is pixel ``(2 y + py - s, 2 x + px - s)`` of channel ``c``
(torch's ``pixel_shuffle`` order), where ``s`` is 0 on the standard grid and 1 on the *shifted* grid. The exit
convolution (3 taps) maps standard cells to shifted ones with 2 taps per axis instead of 3, the fewest multiply-adds a
polyphase form of it can have; the synthesis maps shifted cells back to standard ones. On the shifted grid the first
and the last cell each hold one pixel outside the frame; the circular extension the synthesis needs takes its
wrapped cell from the real halves of those two (:func:`_wrap_shifted`).
"""

from __future__ import annotations

import numpy as np
import torch
import torch.nn.functional as F
from torch import Tensor

from wdss.wavelets import _synthesis_step_h, _synthesis_step_w


def _selection(taps: int, pad: int, shift_in: int, shift_out: int, like: Tensor) -> tuple[Tensor, int]:
    """Along one axis, the correlation ``y[i] = sum_t w[t] x[i + t - pad]`` as one between cells: ``A[q, c, p, t]``
    is 1 where output phase ``q`` takes tap ``t`` from input phase ``p`` of the cell ``c + first`` cells away.
    Returns ``A`` and ``first`` (the offset of the first cell tap). Plain integers: a constant in a traced graph."""
    # Output pixel 2 m - shift_out + q reads input pixel 2 m - shift_out + q + t - pad = 2 (m + c) - shift_in + p.
    offsets = {(q, t): q + t - pad - shift_out + shift_in for q in range(2) for t in range(taps)}
    first = min(offsets.values()) // 2
    a = np.zeros((2, max(offsets.values()) // 2 - first + 1, 2, taps), dtype=np.float32)
    for (q, t), v in offsets.items():
        a[q, v // 2 - first, v % 2, t] = 1
    return torch.as_tensor(a, dtype=like.dtype, device=like.device), first


def polyphase_weight(
    weight: Tensor, pad: tuple[int, int], shift_in: tuple[int, int], shift_out: tuple[int, int]
) -> tuple[Tensor, tuple[int, int]]:
    """A correlation ``weight`` (O, I, kh, kw) with the given (top, left) padding, as a correlation between cell
    tensors (4 O, 4 I, ch, cw): returns that weight and the offset of its first cell tap per axis. Every entry is one
    entry of ``weight`` or zero, so the rewrite is exact."""
    o, i, kh, kw = weight.shape
    ay, fy = _selection(kh, pad[0], shift_in[0], shift_out[0], weight)
    ax, fx = _selection(kw, pad[1], shift_in[1], shift_out[1], weight)
    cells = torch.einsum("qapt,rbsu,oitu->oqripsab", ay, ax, weight)  # (o, qy, qx, i, py, px, cy, cx)
    return cells.reshape(4 * o, 4 * i, ay.shape[1], ax.shape[1]), (fy, fx)


def _wrap_shifted(x: Tensor, dim: int, before: int, after: int) -> Tensor:
    """The circular extension of shifted cells along ``dim`` (-2 rows, -1 columns), ``before`` cells before and
    ``after`` after. ``x`` has one cell more than the period: its first cell's phase 0 and its last cell's phase 1
    lie outside the frame, and the period's first cell joins the other two halves (the last pixel, then the first)."""
    n = x.shape[dim] - 1
    phases = x.unflatten(1, (-1, 2, 2))  # (N, C, py, px, h, w)
    phase_dim = 2 if dim == -2 else 3
    last, first = phases.narrow(dim, n, 1), phases.narrow(dim, 0, 1)
    joined = torch.cat([last.narrow(phase_dim, 0, 1), first.narrow(phase_dim, 1, 1)], dim=phase_dim).flatten(1, 3)
    inner = x.narrow(dim, 1, n - 1)
    period = [joined, inner]
    pieces = [inner.narrow(dim, n - 1 - before, before)] if before else []
    pieces += period + [joined] + ([inner.narrow(dim, 0, after - 1)] if after > 1 else [])
    return torch.cat(pieces, dim=dim)


def fits_cells(merged: Tensor, taps: int) -> bool:
    """Whether ``merged`` has enough cells for :func:`swt_tail_on_cells` with a ``taps``-tap filter: the circular
    extension wraps at most once (smaller frames take the direct form)."""
    return min(merged.shape[-2:]) >= taps // 4 + 3


def swt_tail_on_cells(merged: Tensor, exit_weight: Tensor, exit_bias: Tensor, rows: Tensor) -> Tensor:
    """``synthesis(conv2d(pixel_shuffle(merged, 2), exit_weight, exit_bias, padding=1))`` for a one-level SWT with
    filter ``rows`` (band-major subbands, circular), computed on cells. ``merged`` is (N, 4 C', h, w) with ``C' = 4 C``
    subband maps of ``C`` channels; returns (N, C, 2 h, 2 w)."""
    taps = rows.shape[-1]
    channels = exit_weight.shape[0] // 4
    exit_cells, _ = polyphase_weight(exit_weight, (1, 1), (0, 0), (1, 1))  # first cell tap -1 on both axes
    coefficients = F.conv2d(merged, exit_cells, exit_bias.repeat_interleave(4), padding=1)  # h + 1 by w + 1 cells
    half = 0.5 * rows
    # The H step's 2 groups (one per W band) stay 2 groups on cells: a cell's channels are grouped the same way.
    h_cells, (first, _) = polyphase_weight(_synthesis_step_h(half, channels, False), (taps // 2, 0), (1, 1), (0, 1))
    extended = _wrap_shifted(coefficients, -2, -first, h_cells.shape[-2] - 1 + first)
    rows_done = F.conv2d(extended, h_cells, groups=2)  # standard cells along H, still shifted along W
    w_cells, (_, first) = polyphase_weight(_synthesis_step_w(half, channels, False), (0, taps // 2), (0, 1), (0, 0))
    extended = _wrap_shifted(rows_done, -1, -first, w_cells.shape[-1] - 1 + first)
    return F.pixel_shuffle(F.conv2d(extended, w_cells), 2)
