"""wdss.wavelets against PyWavelets, the independent oracle.

Tolerances are relative to the largest magnitude of the reference: 1e-6 in float32, 1e-12 in float64.
"""

from __future__ import annotations

import re

import numpy as np
import pytest
import pywt
import torch
import torch.nn.functional as F

from wdss.wavelets import TRANSFORMS, WaveletTransform, analysis, coefficient_channels, synthesis

BASES = ("haar", "db4", "sym4")
DTYPES = (torch.float32, torch.float64)
RTOL = {torch.float32: 1e-6, torch.float64: 1e-12}
# Sizes PyWavelets accepts: even for DWT (periodization), multiples of 2^level for SWT; some are smaller
# than the db4/sym4 support (8 taps), so the periodic extension wraps more than once.
SIZES_L1 = ((2, 2), (4, 4), (6, 10), (8, 8), (16, 12), (30, 34))
SIZES_L2 = ((4, 4), (8, 12), (16, 16), (20, 36))


def assert_close(actual: torch.Tensor, expected: np.ndarray, rtol: float) -> None:
    actual_np = actual.detach().cpu().double().numpy()
    assert actual_np.shape == expected.shape
    scale = max(np.abs(expected).max(), 1e-30)
    error = np.abs(actual_np - expected).max() / scale
    assert error <= rtol, f"relative error {error:.3g} > {rtol:.1g}"


def image(shape: tuple[int, ...], dtype: torch.dtype, seed: int = 0) -> torch.Tensor:
    generator = torch.Generator().manual_seed(seed)
    return torch.rand(shape, generator=generator, dtype=torch.float64).to(dtype)


def pywt_dwt_layout(x: np.ndarray, wavelet: str, level: int) -> np.ndarray:
    """pywt.wavedec2 in wdss' band-major layout (finer levels space-to-depth)."""
    coeffs = pywt.wavedec2(x, wavelet, mode="periodization", level=level, axes=(-2, -1))
    parts = [coeffs[0]]
    for index, details in enumerate(coeffs[1:]):
        detail = np.concatenate(details, axis=1)
        factor = 2**index  # coeffs[1] is the coarsest detail level
        if factor > 1:
            detail = F.pixel_unshuffle(torch.from_numpy(detail), factor).numpy()
        parts.append(detail)
    return np.concatenate(parts, axis=1)


def pywt_swt_layout(x: np.ndarray, wavelet: str, level: int) -> np.ndarray:
    coeffs = pywt.swt2(x, wavelet, level=level, trim_approx=True, norm=False, axes=(-2, -1))
    return np.concatenate([coeffs[0], *(np.concatenate(d, axis=1) for d in coeffs[1:])], axis=1)


def pywt_reference(x: np.ndarray, transform: str, wavelet: str, level: int) -> np.ndarray:
    if transform == "dwt":
        return pywt_dwt_layout(x, wavelet, level)
    return pywt_swt_layout(x, wavelet, level)


CASES = [(lev, size) for lev, sizes in ((1, SIZES_L1), (2, SIZES_L2)) for size in sizes]


@pytest.mark.parametrize("dtype", DTYPES, ids=str)
@pytest.mark.parametrize("level,size", CASES, ids=lambda v: str(v))
@pytest.mark.parametrize("wavelet", BASES)
@pytest.mark.parametrize("transform", ("dwt", "swt"))
def test_analysis_equals_pywavelets(transform, wavelet, level, size, dtype):
    x = image((2, 3, *size), dtype)
    coeffs = analysis(x, transform=transform, wavelet=wavelet, level=level)
    assert coeffs.dtype == dtype
    expected = pywt_reference(x.double().numpy(), transform, wavelet, level)
    assert_close(coeffs, expected, RTOL[dtype])


@pytest.mark.parametrize("dtype", DTYPES, ids=str)
@pytest.mark.parametrize("level,size", CASES, ids=lambda v: str(v))
@pytest.mark.parametrize("wavelet", BASES)
@pytest.mark.parametrize("transform", ("dwt", "swt"))
def test_synthesis_inverts_analysis(transform, wavelet, level, size, dtype):
    x = image((2, 3, *size), dtype, seed=1)
    back = synthesis(
        analysis(x, transform=transform, wavelet=wavelet, level=level),
        transform=transform,
        wavelet=wavelet,
        level=level,
    )
    assert back.shape == x.shape and back.dtype == dtype
    assert_close(back, x.double().numpy(), RTOL[dtype])


@pytest.mark.parametrize("channels_last", (False, True), ids=("nchw", "channels_last"))
@pytest.mark.parametrize("level,size", CASES, ids=lambda v: str(v))
@pytest.mark.parametrize("wavelet", BASES)
@pytest.mark.parametrize("transform", ("dwt", "swt"))
def test_synthesis_of_any_coefficients_equals_pywavelets(transform, wavelet, level, size, channels_last):
    """On coefficients that no image produced, synthesis is PyWavelets' iswt2/waverec2 (the pseudo-inverse).

    1e-11 rather than 1e-12: PyWavelets' sym4 table is orthonormal to only ~5e-13, which its own inverse
    carries; wdss orthonormalises the filters (its round trip above is exact to 1e-12). Channels-last SWT
    subbands at least as large as the filter's span take the path without a padded copy.
    """
    c = 3
    shape = (2, coefficient_channels(transform, c, level), *(s >> (level if transform == "dwt" else 0) for s in size))
    coeffs = torch.randn(shape, generator=torch.Generator().manual_seed(2), dtype=torch.float64)
    ours = synthesis(
        coeffs.contiguous(memory_format=torch.channels_last) if channels_last else coeffs,
        transform=transform,
        wavelet=wavelet,
        level=level,
    )
    arr = coeffs.numpy()
    if transform == "swt":
        pieces = [arr[:, :c]] + [
            tuple(np.split(arr[:, c + 3 * c * i : c + 3 * c * (i + 1)], 3, axis=1)) for i in range(level)
        ]
        expected = pywt.iswt2(pieces, wavelet, axes=(-2, -1))
    else:
        pieces, start = [arr[:, :c]], c
        for index in range(level):
            factor = 2**index
            width = 3 * c * factor * factor
            detail = torch.from_numpy(arr[:, start : start + width])
            start += width
            detail = F.pixel_shuffle(detail, factor).numpy() if factor > 1 else detail.numpy()
            pieces.append(tuple(np.split(detail, 3, axis=1)))
        expected = pywt.waverec2(pieces, wavelet, mode="periodization", axes=(-2, -1))
    assert_close(ours, expected, 1e-11)


ODD_SIZES = ((1, 1), (3, 5), (5, 7), (9, 4), (7, 33))


@pytest.mark.parametrize("dtype", DTYPES, ids=str)
@pytest.mark.parametrize("size", ODD_SIZES, ids=str)
@pytest.mark.parametrize("wavelet", BASES)
@pytest.mark.parametrize("level", (1, 2))
def test_swt_any_size_is_exact_and_shift_equivariant(level, wavelet, size, dtype):
    x = image((2, 3, *size), dtype, seed=3)
    coeffs = analysis(x, transform="swt", wavelet=wavelet, level=level)
    assert coeffs.shape == (2, 3 * (1 + 3 * level), *size)
    assert_close(synthesis(coeffs, transform="swt", wavelet=wavelet, level=level), x.double().numpy(), RTOL[dtype])
    shift = (2 % size[0], 3 % size[1])
    shifted = analysis(torch.roll(x, shift, (-2, -1)), transform="swt", wavelet=wavelet, level=level)
    assert_close(shifted, torch.roll(coeffs, shift, (-2, -1)).double().numpy(), RTOL[dtype])


@pytest.mark.parametrize("size", ((3, 4), (4, 5), (6, 6)))
def test_dwt_odd_size_is_a_clear_error(size):
    x = torch.rand(1, 3, *size)
    level = 2 if size == (6, 6) else 1
    with pytest.raises(ValueError, match=rf"divisible by {2**level}, got {size[0]}x{size[1]}"):
        analysis(x, transform="dwt", wavelet="haar", level=level)


def test_none_is_the_identity_on_both_paths():
    x = torch.rand(2, 12, 5, 7)
    assert analysis(x, transform="none") is x
    assert synthesis(x, transform="none") is x
    assert coefficient_channels("none", 3) == 3


@pytest.mark.parametrize("channels", (1, 17, 20, 40))
@pytest.mark.parametrize("transform", ("dwt", "swt"))
def test_channel_chunks_keep_the_band_major_layout(transform, channels):
    """More channels than one convolution chunk (17: prime, 20 and 40: several chunks) give the same layout."""
    x = image((2, channels, 8, 12), torch.float64, seed=4)
    for level in (1, 2):
        coeffs = analysis(x, transform=transform, wavelet="db4", level=level)
        assert_close(coeffs, pywt_reference(x.numpy(), transform, "db4", level), 1e-12)
        back = synthesis(coeffs, transform=transform, wavelet="db4", level=level)
        assert_close(back, x.numpy(), 1e-12)


def test_band_layout_semantics():
    """LH (cH) responds to horizontal edges (variation along H), HL (cV) to vertical ones; LL of 1 is 2."""
    rows = torch.zeros(1, 1, 8, 8)
    rows[..., 4:, :] = 1.0  # a horizontal edge: varies along H only
    bands = analysis(rows, transform="swt", wavelet="haar")
    ll, lh, hl, hh = bands[0]
    assert lh.abs().max() > 0.5 and hl.abs().max() == 0 and hh.abs().max() == 0
    const = analysis(torch.ones(1, 1, 6, 6), transform="swt", wavelet="db4")
    assert torch.allclose(const[:, 0], torch.full((1, 6, 6), 2.0)) and const[:, 1:].abs().max() < 1e-6


@pytest.mark.parametrize("level", (1, 2))
@pytest.mark.parametrize("wavelet", ("haar", "db4"))
@pytest.mark.parametrize("transform", ("dwt", "swt"))
def test_gradients_flow_through_both_directions(transform, wavelet, level):
    size = (8, 8) if transform == "dwt" else (5, 6)
    x = torch.rand(1, 2, *size, dtype=torch.float64, requires_grad=True)
    assert torch.autograd.gradcheck(
        lambda t: analysis(t, transform=transform, wavelet=wavelet, level=level), (x,), fast_mode=True
    )
    c = analysis(x.detach(), transform=transform, wavelet=wavelet, level=level).clone().requires_grad_(True)
    assert torch.autograd.gradcheck(
        lambda t: synthesis(t, transform=transform, wavelet=wavelet, level=level), (c,), fast_mode=True
    )


@pytest.mark.parametrize("wavelet", ("haar", "db4"))
def test_channels_last_swt_synthesis_has_exact_gradients_eager_and_compiled(wavelet):
    """The path without a padded copy writes the wrapped ends into its convolution's output in place."""
    c = torch.rand(1, 8, 8, 9, dtype=torch.float64).contiguous(memory_format=torch.channels_last)
    c.requires_grad_(True)
    assert torch.autograd.gradcheck(lambda t: synthesis(t, transform="swt", wavelet=wavelet), (c,), fast_mode=True)
    compiled = torch.compile(lambda t: synthesis(t, transform="swt", wavelet=wavelet), backend="aot_eager")
    expected = synthesis(c.detach(), transform="swt", wavelet=wavelet, level=1)
    assert torch.allclose(compiled(c.detach()), expected, rtol=0, atol=1e-12)


def test_module_moves_its_filters_and_keeps_them_out_of_checkpoints():
    module = WaveletTransform("swt", "db4")
    assert module.filter_rows.dtype == torch.float32 and module.filter_rows.shape == (2, 8)
    assert "filter_rows" not in module.state_dict()
    module = module.double()
    assert module.filter_rows.dtype == torch.float64
    x = image((1, 3, 6, 10), torch.float64)
    expected = synthesis(analysis(x, transform="swt", wavelet="db4"), transform="swt", wavelet="db4")
    coeffs = module.analysis(x)
    assert coeffs.shape == (1, module.coefficient_channels(3), 6, 10)
    assert torch.allclose(module(coeffs), expected, atol=1e-12)
    assert "transform='swt'" in repr(module)


@pytest.mark.parametrize("transform", TRANSFORMS)
def test_module_round_trip_float32(transform):
    module = WaveletTransform(transform, "sym4")
    x = image((2, 3, 16, 16), torch.float32)
    assert_close(module(module.analysis(x)), x.double().numpy(), 1e-6)


@pytest.mark.parametrize(
    "call, message",
    [
        (lambda: analysis(torch.rand(1, 1, 4, 4), transform="fft"), "unknown wavelet transform 'fft'"),
        (lambda: analysis(torch.rand(1, 1, 4, 4), transform="swt", wavelet="nope"), "unknown wavelet basis 'nope'"),
        (lambda: analysis(torch.rand(1, 1, 4, 4), transform="swt", wavelet="bior2.2"), "not orthogonal"),
        (lambda: analysis(torch.rand(1, 1, 4, 4), transform="swt", level=0), "level must be an integer >= 1"),
        (lambda: analysis(torch.rand(4, 4), transform="swt"), r"4-D tensor \(N, C, H, W\)"),
        (lambda: synthesis(torch.rand(1, 5, 4, 4), transform="swt"), "multiple of 4 coefficient channels, got 5"),
        (lambda: synthesis(torch.rand(1, 12, 4, 4), transform="dwt", level=2), "multiple of 16"),
        (lambda: WaveletTransform("wavelet"), "unknown wavelet transform"),
    ],
)
def test_bad_arguments_are_clear_errors(call, message):
    with pytest.raises(ValueError, match=message):
        call()


def test_integer_input_is_rejected():
    with pytest.raises(TypeError, match="floating-point"):
        analysis(torch.ones(1, 1, 4, 4, dtype=torch.int64), transform="dwt")


@pytest.mark.parametrize("shape", ((1, 0, 4, 4), (1, 3, 0, 4), (1, 3, 4, 0)))
@pytest.mark.parametrize("transform", ("dwt", "swt"))
def test_no_channels_or_no_pixels_is_a_clear_error(transform, shape):
    message = r"needs C, H and W >= 1, got shape \(N, C, H, W\) = " + re.escape(str(shape))
    with pytest.raises(ValueError, match=message):
        analysis(torch.rand(shape), transform=transform)
    with pytest.raises(ValueError, match=message):
        WaveletTransform(transform).synthesis(torch.rand(shape))
    assert analysis(torch.rand(0, 3, 4, 4), transform=transform).shape[0] == 0  # an empty batch stays a no-op


@pytest.mark.parametrize("transform", ("dwt", "swt"))
def test_compiled_on_cpu_the_swt_synthesis_runs_eagerly_and_gives_the_same_image(transform):
    # torch.compile's code for the SWT filter bank is slower on CPU than eager's (bench inference): it is left out of
    # the compiled graphs there; the DWT's stays in. Either way the image is the eager one.
    torch._dynamo.reset()
    module = WaveletTransform(transform, "db4")
    coeffs = analysis(image((1, 3, 16, 16), torch.float32), transform=transform, wavelet="db4")
    graphs: list[torch.fx.GraphModule] = []

    def record(gm, example_inputs):
        graphs.append(gm)
        return gm.forward

    out = torch.compile(lambda c: module(c) * 2, backend=record)(coeffs)
    torch.testing.assert_close(out, module(coeffs) * 2)
    convolutions = [n for gm in graphs for n in gm.graph.nodes if "conv" in str(n.target)]
    assert graphs and (convolutions == [] if transform == "swt" else len(convolutions) >= 2)
