"""Convolutions rewritten on 2x2 cells, and the SWT tail an exported graph computes on them."""

from __future__ import annotations

import itertools

import numpy as np
import pytest
import torch
import torch.nn.functional as F

import wdss.model.network as network
from wdss.export import export_onnx, run_onnx
from wdss.model.module import SuperResolutionModule
from wdss.model.network import WIDTHS, WDSSNet
from wdss.model.polyphase import polyphase_weight, swt_tail_on_cells
from wdss.wavelets import WaveletTransform


def to_cells(x: torch.Tensor, shift: tuple[int, int]) -> torch.Tensor:
    """Cells of a pixel tensor on the standard (0) or shifted (1) grid per axis: outside pixels are zero."""
    return F.pixel_unshuffle(F.pad(x, (shift[1], shift[1], shift[0], shift[0])), 2)


@pytest.mark.parametrize("shift_in,shift_out", list(itertools.product([(0, 0), (1, 1), (1, 0), (0, 1)], repeat=2)))
def test_a_convolution_rewritten_on_cells_gives_the_same_pixels(shift_in, shift_out):
    torch.manual_seed(0)
    weight = torch.randn(2, 3, 3, 5, dtype=torch.float64)
    pad = (1, 3)  # (top, left): asymmetric along W
    x = torch.randn(2, 3, 10, 14, dtype=torch.float64)
    pixels = F.conv2d(F.pad(x, (pad[1], 5 - 1 - pad[1], pad[0], 3 - 1 - pad[0])), weight)  # the oracle, zero padded

    cells, (first_y, first_x) = polyphase_weight(weight, pad, shift_in, shift_out)
    inputs = to_cells(x, shift_in)
    # Zero cells around the input so that every output cell of the shifted or standard grid is computed.
    after_y = shift_out[0] - shift_in[0] + first_y + cells.shape[-2] - 1
    after_x = shift_out[1] - shift_in[1] + first_x + cells.shape[-1] - 1
    out = F.conv2d(F.pad(inputs, (-first_x, after_x, -first_y, after_y)), cells)
    assert out.shape[-2:] == (5 + shift_out[0], 7 + shift_out[1])
    image = F.pixel_shuffle(out, 2)[..., shift_out[0] : shift_out[0] + 10, shift_out[1] : shift_out[1] + 14]
    assert torch.allclose(image, pixels, rtol=0, atol=1e-12)


@pytest.mark.parametrize("basis", ["haar", "db2", "db4", "sym4"])
@pytest.mark.parametrize("cells", [(5, 7), (8, 12)])
def test_the_swt_tail_on_cells_is_the_direct_tail(basis, cells):
    """synthesis(exit(pixel_shuffle(merged))) with circular boundaries, including the seams where it wraps."""
    torch.manual_seed(1)
    merged = torch.randn(2, 48, *cells, dtype=torch.float64)
    weight, bias = torch.randn(12, 12, 3, 3, dtype=torch.float64), torch.randn(12, dtype=torch.float64)
    wavelet = WaveletTransform("swt", basis).double()
    direct = wavelet(F.conv2d(F.pixel_shuffle(merged, 2), weight, bias, padding=1))
    on_cells = swt_tail_on_cells(merged, weight, bias, wavelet.filter_rows)
    assert on_cells.shape == direct.shape == (2, 3, 2 * cells[0], 2 * cells[1])
    assert (on_cells - direct).abs().max() <= 1e-12 * direct.abs().max()


@pytest.mark.parametrize("size,takes_cells", [((32, 48), True), ((8, 12), False)])
def test_an_exported_swt_network_computes_its_tail_on_cells_where_the_frame_allows(
    size, takes_cells, monkeypatch, tmp_path
):
    calls = []

    def spy(*args):
        calls.append(args[0].shape)
        return swt_tail_on_cells(*args)

    monkeypatch.setattr(network, "swt_tail_on_cells", spy)
    torch.manual_seed(0)
    net = WDSSNet("swt", "db4", residual="bilinear", exit_init=1.0, **WIDTHS["tiny"]).eval()
    path = tmp_path / "swt.onnx"
    graph, inputs, reference = export_onnx(SuperResolutionModule(net), path, height=size[0], width=size[1], scale=2.0)
    assert bool(calls) == takes_cells
    color = run_onnx(path, {k: v.numpy() for k, v in inputs.items()})["color"]
    assert np.abs(color - reference.numpy()).max() <= 1e-5 * np.abs(reference.numpy()).max()
