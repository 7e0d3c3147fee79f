"""Convolutions rewritten on 2x2 cells, and the SWT tail inference graphs compute on them."""

from __future__ import annotations

import itertools

import numpy as np
import pytest
import torch
import torch.nn.functional as F

from tests.helpers import upsampler
from wdss.export import export_onnx, run_onnx
from wdss.nets.profile import dummy_inputs
from wdss.nets.wdss.network import WIDTHS, WDSSNet
from wdss.nets.wdss.polyphase import fits_cells, polyphase_weight, swt_tail_on_cells
from wdss.training.module import SuperResolutionModule
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


def direct_tail(
    merged: torch.Tensor, weight: torch.Tensor, bias: torch.Tensor, wavelet: WaveletTransform
) -> torch.Tensor:
    return wavelet(F.conv2d(F.pixel_shuffle(merged, 2), weight, bias, padding=1))


@pytest.mark.parametrize("basis", ["haar", "db2", "db4", "sym4"])
@pytest.mark.parametrize("cells", [(5, 7), (8, 12)])
@pytest.mark.parametrize("memory_format", [torch.contiguous_format, torch.channels_last])
def test_the_swt_tail_on_cells_is_the_direct_tail(basis, cells, memory_format):
    """synthesis(exit(pixel_shuffle(merged))) with circular boundaries, including the seams where it wraps."""
    torch.manual_seed(1)
    merged = torch.randn(2, 48, *cells, dtype=torch.float64).contiguous(memory_format=memory_format)
    weight, bias = torch.randn(12, 12, 3, 3, dtype=torch.float64), torch.randn(12, dtype=torch.float64)
    wavelet = WaveletTransform("swt", basis).double()
    direct = direct_tail(merged, weight, bias, wavelet)
    on_cells = swt_tail_on_cells(merged, weight, bias, wavelet.filter_rows)
    assert on_cells.shape == direct.shape == (2, 3, 2 * cells[0], 2 * cells[1])
    assert (on_cells - direct).abs().max() <= 1e-12 * direct.abs().max()


@pytest.mark.parametrize("basis", ["haar", "db2", "db4", "db8"])
def test_the_tail_on_cells_holds_on_the_smallest_frame_it_takes(basis):
    """At the fewest cells fits_cells allows, the seams at the two ends of each axis meet."""
    wavelet = WaveletTransform("swt", basis).double()
    taps = wavelet.filter_rows.shape[-1]
    torch.manual_seed(2)
    merged = torch.randn(1, 48, taps // 2 + 1, taps // 2 + 2, dtype=torch.float64)
    assert fits_cells(merged, taps) and not fits_cells(merged[..., :-1, :], taps)
    weight, bias = torch.randn(12, 12, 3, 3, dtype=torch.float64), torch.randn(12, dtype=torch.float64)
    direct = direct_tail(merged, weight, bias, wavelet)
    assert (
        swt_tail_on_cells(merged, weight, bias, wavelet.filter_rows) - direct
    ).abs().max() <= 1e-12 * direct.abs().max()


def test_the_tail_on_cells_has_exact_gradients():
    """The seams are written in place into the convolutions' outputs: autograd must see through those writes."""
    torch.manual_seed(3)
    rows = WaveletTransform("swt", "db2").double().filter_rows
    merged = torch.randn(1, 16, 4, 5, dtype=torch.float64, requires_grad=True)
    weight = torch.randn(4, 4, 3, 3, dtype=torch.float64, requires_grad=True)
    bias = torch.randn(4, dtype=torch.float64, requires_grad=True)
    assert torch.autograd.gradcheck(lambda m, w, b: swt_tail_on_cells(m, w, b, rows), (merged, weight, bias))


def tiny_swt_net() -> WDSSNet:
    torch.manual_seed(0)
    return WDSSNet("swt", "db4", upsampler=upsampler("bilinear"), exit_init=1.0, **WIDTHS["tiny"]).eval()


def test_a_channels_last_network_without_subbands_computes_its_tail_on_cells(tail_calls):
    net = tiny_swt_net()
    inputs = dummy_inputs(net, 32, 48, 2.0)
    with torch.no_grad():
        expected = net(**inputs)["irradiance"]
        nchw = net(**inputs, subbands=False)  # NCHW cells: the direct form, which is faster there
        assert not tail_calls
        net = net.to(memory_format=torch.channels_last)
        with_subbands = net(**inputs)
        assert not tail_calls and with_subbands["coefficients"] is not None
        image_only = net(**inputs, subbands=False)
    assert len(tail_calls) == 1 and image_only["coefficients"] is None
    for out in (nchw, with_subbands, image_only):
        assert (out["irradiance"] - expected).abs().max() <= 1e-5 * expected.abs().max()


@pytest.mark.parametrize("size,takes_cells", [((32, 48), True), ((8, 12), False)])
def test_an_exported_swt_network_computes_its_tail_on_cells_where_the_frame_allows(
    size, takes_cells, tail_calls, tmp_path
):
    net = tiny_swt_net()
    path = tmp_path / "swt.onnx"
    graph, inputs, reference = export_onnx(SuperResolutionModule(net), path, height=size[0], width=size[1], scale=2.0)
    assert bool(tail_calls) == takes_cells
    color = run_onnx(path, {k: v.numpy() for k, v in inputs.items()})["color"]
    assert np.abs(color - reference.numpy()).max() <= 1e-5 * np.abs(reference.numpy()).max()
