"""The SWT head's full-resolution tail (exit convolution, then one level of SWT synthesis), computed on 2x2 cells.

The network ends with ``synthesis(exit(pixel_shuffle(merged, 2)))``: a 3x3 convolution of 12 full-resolution subband
maps, then the circular filter bank. :func:`swt_tail_on_cells` computes the same image from ``merged`` (the 48 channels
on the half-resolution grid) without going to full resolution until the end: every convolution is rewritten as one on
2x2 cells (its *polyphase* form), the exit convolution and the synthesis' H step (both linear) become one convolution,
and only the 3-channel image is moved to pixels. The network takes this form when no subbands are asked for and the
cells are channels-last, and in exported graphs. On channels-last cells it is faster than the direct form
(docs/performance.md); on NCHW cells oneDNN's reorders of its convolutions take that gain back.

Cells. Channel ``c * 4 + 2 * py + px`` of a cell tensor is pixel ``(2 y + py - s, 2 x + px - s)`` of channel ``c``
(torch's ``pixel_shuffle`` order), where ``s`` is 0 on the standard grid and 1 on the *shifted* grid. The exit
convolution (3 taps) maps standard cells to shifted ones with 2 taps per axis instead of 3, the fewest multiply-adds a
polyphase form of it can have; the synthesis maps shifted cells back to standard ones. On the shifted grid the first
and the last cell each hold one pixel outside the frame. Each circular step runs as a zero-padded convolution, and the
few outputs whose window reaches the ends are recomputed from the two ends joined (:func:`_with_seam`), whose wrapped
cell takes the real halves of the first and the last cell.
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


def _dense(weight: Tensor, groups: int) -> Tensor:
    """A grouped convolution's weight (O, I / groups, kh, kw) as the dense (O, I, kh, kw) one (zeros across groups)."""
    per_out, per_in = weight.shape[0] // groups, weight.shape[1]
    blocks = [
        F.pad(weight[g * per_out : (g + 1) * per_out], (0, 0, 0, 0, g * per_in, (groups - 1 - g) * per_in))
        for g in range(groups)
    ]
    return torch.cat(blocks)


def _compose_rows(second: Tensor, first: Tensor) -> Tensor:
    """The correlation ``second`` (O, M, k2, 1) applied after ``first`` (M, I, k1, kw): one (O, I, k1 + k2 - 1, kw)."""
    k1 = first.shape[-2]
    terms = [
        F.pad(
            torch.einsum("om,miw->oiw", second[:, :, t, 0], first[:, :, s]).unsqueeze(2),
            (0, 0, t + s, k1 - 1 - s + second.shape[-2] - 1 - t),
        )
        for t in range(second.shape[-2])
        for s in range(k1)
    ]
    return torch.stack(terms).sum(0)


def _correlate(
    x: Tensor, weight: Tensor, bias: Tensor | None, pads: tuple[tuple[int, int], tuple[int, int]], groups: int = 1
) -> Tensor:
    """``conv2d`` of ``x`` zero-padded by ``pads`` ((top, bottom), (left, right)), which may be asymmetric: the
    convolution pads symmetrically by the larger side (zero taps in front of the weight where the front is smaller)
    and the surplus outputs at the end are cut (a view; no padded copy of ``x``)."""
    padding, front, size = [], [], []
    for axis, (before, after) in enumerate(pads):
        padding.append(max(before, after))
        front.append(max(after - before, 0))
        size.append(x.shape[2 + axis] + before + after - weight.shape[2 + axis] + 1)
    if any(front):
        weight = F.pad(weight, (front[1], 0, front[0], 0))
    out = F.conv2d(x, weight, bias, padding=tuple(padding), groups=groups)
    return out[..., : size[0], : size[1]]


def _joined(first_cell: Tensor, last_cell: Tensor, dim: int) -> Tensor:
    """The period's first cell on a shifted grid along ``dim``: the last cell's phase 0 (the frame's last pixel), then
    the first cell's phase 1 (its first pixel); the other two halves lie outside the frame."""
    phase = 2 if dim == -2 else 3
    last = last_cell.unflatten(1, (-1, 2, 2)).narrow(phase, 0, 1)
    first = first_cell.unflatten(1, (-1, 2, 2)).narrow(phase, 1, 1)
    return torch.cat([last, first], dim=phase).flatten(1, 3)


def _with_seam(out: Tensor, head: Tensor, tail: Tensor, weight: Tensor, dim: int, first: int, groups: int) -> Tensor:
    """``out``, the circular correlation along ``dim`` of a shifted grid (``n + 1`` cells, period ``n``) computed as a
    zero-padded one, with the outputs whose window reaches the grid's two ends or wraps around recomputed from the
    joined ends: ``head`` holds shifted cells ``0 .. K - 1`` and ``tail`` cells ``n - K + 1 .. n`` (``K`` taps)."""
    taps = weight.shape[dim]
    joined = _joined(head.narrow(dim, 0, 1), tail.narrow(dim, taps - 1, 1), dim)
    ends = torch.cat([tail.narrow(dim, 0, taps - 1), joined, head.narrow(dim, 1, taps - 1)], dim=dim)
    seam = F.conv2d(ends, weight, groups=groups)  # outputs n - K + 1 - first .. n - 1, then 0 .. -first
    at_end, at_start = taps - 1 + first, 1 - first
    n = out.shape[dim]
    if torch.compiler.is_exporting():  # a graph gets the functional form
        middle = out.narrow(dim, at_start, n - at_end - at_start)
        return torch.cat([seam.narrow(dim, at_end, at_start), middle, seam.narrow(dim, 0, at_end)], dim=dim)
    out.narrow(dim, n - at_end, at_end).copy_(seam.narrow(dim, 0, at_end))
    out.narrow(dim, 0, at_start).copy_(seam.narrow(dim, at_end, at_start))
    return out


def fits_cells(merged: Tensor, taps: int) -> bool:
    """Whether ``merged`` has enough cells for :func:`swt_tail_on_cells` with a ``taps``-tap filter: each end of the
    frame holds a whole filter window of the synthesis on cells (smaller frames take the direct form)."""
    return min(merged.shape[-2:]) >= taps // 2 + 1


def _phase_major(weight: Tensor) -> Tensor:
    """A cell weight's output channels reordered from (channel, row phase, column phase) to (phases, channel)."""
    return weight.unflatten(0, (-1, 4)).transpose(0, 1).flatten(0, 1)


def _cells_to_image(cells: Tensor) -> Tensor:
    """(N, 4 C, h, w) cells with phase-major channels -> (N, C, 2 h, 2 w) in channels-last memory. From channels-last
    cells each output row segment is a copy of 2 C consecutive values, much faster than ``pixel_shuffle``."""
    n, c, h, w = cells.shape
    pixels = cells.permute(0, 2, 3, 1).reshape(n, h, w, 2, 2, c // 4).transpose(2, 3).reshape(n, 2 * h, 2 * w, c // 4)
    return pixels.permute(0, 3, 1, 2)


def swt_tail_on_cells(merged: Tensor, exit_weight: Tensor, exit_bias: Tensor, rows: Tensor) -> Tensor:
    """``synthesis(conv2d(pixel_shuffle(merged, 2), exit_weight, exit_bias, padding=1))`` for a one-level SWT with
    filter ``rows`` (band-major subbands, circular), computed on cells. ``merged`` is (N, 4 C', h, w) with ``C' = 4 C``
    subband maps of ``C`` channels; returns (N, C, 2 h, 2 w)."""
    if torch.compiler.is_compiling() and not torch.compiler.is_exporting():
        return _eager_tail(merged, exit_weight, exit_bias, rows)  # see there
    taps = rows.shape[-1]
    channels = exit_weight.shape[0] // 4
    height, width = merged.shape[-2:]
    exit_cells, _ = polyphase_weight(exit_weight, (1, 1), (0, 0), (1, 1))  # standard -> shifted cells: taps -1, 0
    exit_bias = exit_bias.repeat_interleave(4)
    half = 0.5 * rows
    h_cells, (first_h, _) = polyphase_weight(_synthesis_step_h(half, channels, False), (taps // 2, 0), (1, 1), (0, 1))
    w_cells, (_, first_w) = polyphase_weight(_synthesis_step_w(half, channels, False), (0, taps // 2), (0, 1), (0, 0))
    exporting = torch.compiler.is_exporting()
    if not exporting:
        w_cells = _phase_major(w_cells)
    # The exit convolution and the H step are both linear: one convolution of merged does both. Its zero padding
    # differs from the exit's only where the H step's window reaches the ends, which the seam recomputes.
    h_taps = h_cells.shape[-2]
    h_dense = _dense(h_cells, 2)
    both = _compose_rows(h_dense, exit_cells)
    both_bias = torch.einsum("omt,m->o", h_dense[..., 0], exit_bias)
    rows_done = _correlate(merged, both, both_bias, ((1 - first_h, h_taps - 1 + first_h), (1, 1)))
    head = F.conv2d(merged.narrow(-2, 0, h_taps), exit_cells, exit_bias, padding=1).narrow(-2, 0, h_taps)
    tail = F.conv2d(merged.narrow(-2, height - h_taps, h_taps), exit_cells, exit_bias, padding=1).narrow(-2, 1, h_taps)
    rows_done = _with_seam(rows_done, head, tail, h_cells, -2, first_h, groups=2)  # standard along H, shifted along W
    w_taps = w_cells.shape[-1]
    cells = _correlate(rows_done, w_cells, None, ((0, 0), (-first_w, w_taps - 2 + first_w)))
    head, tail = rows_done.narrow(-1, 0, w_taps), rows_done.narrow(-1, width + 1 - w_taps, w_taps)
    cells = _with_seam(cells, head, tail, w_cells, -1, first_w, groups=1)
    return F.pixel_shuffle(cells, 2) if exporting else _cells_to_image(cells)


@torch.compiler.disable
def _eager_tail(merged: Tensor, exit_weight: Tensor, exit_bias: Tensor, rows: Tensor) -> Tensor:
    # torch.compile runs the tail eagerly. Compiled, Inductor turns the seam writes into copies of the whole
    # convolution output and fuses the last one, the move to pixels and the remodulation after it into one loop over
    # NCHW pixels that gathers every value, which alone takes about as long as the whole tail run eagerly.
    return swt_tail_on_cells(merged, exit_weight, exit_bias, rows)
