"""LR/2 and HR/2 grids sit where their pixels are, also for odd frame sizes (padded by one replicated pixel)."""

from __future__ import annotations

import math

import pytest
import torch

from wdss.nets.wdss.network import cell_grid, resample_to_cells

# (HR pixels, LR pixels) along one axis: odd LR (42 at 2x, 64 at 3x -> 21), odd HR, both odd, and even ones.
SIZES = [(42, 21), (64, 21), (43, 22), (43, 21), (41, 13), (42, 14), (40, 20), (48, 16)]


def hr_centres(hr: int) -> torch.Tensor:
    """HR/2 cell j covers HR pixels 2j, 2j+1: its centre as a fraction of the frame (1 for an odd frame's last)."""
    return (2 * torch.arange(math.ceil(hr / 2), dtype=torch.float64) + 1) / hr


def lr_centres(lr: int, cell: int) -> torch.Tensor:
    """LR cell i covers LR pixels cell*i .. cell*i + cell - 1, of width 1 / lr each."""
    return (torch.arange(math.ceil(lr / cell), dtype=torch.float64) + 0.5) * cell / lr


@pytest.mark.parametrize("lr_cell", [2, 1])
@pytest.mark.parametrize("hr, lr", SIZES)
def test_each_hr_cell_knows_its_true_offset_from_its_lr_cell(hr, lr, lr_cell):
    index, delta = cell_grid(hr, lr, torch.device("cpu"), torch.float64, lr_cell=lr_cell)
    centres = lr_centres(lr, lr_cell)
    assert index.shape == (math.ceil(hr / 2),) and int(index.min()) >= 0 and int(index.max()) < len(centres)
    assert delta.abs().max() <= 1 + 1e-9  # within (the edge of) the assigned cell: it is the nearest one
    half_cell = lr_cell / (2 * lr)  # delta is in half cells
    torch.testing.assert_close(centres[index] + delta * half_cell, hr_centres(hr), rtol=0, atol=1e-9)


@pytest.mark.parametrize("other", [0, 1], ids=["same", "other-parity"])  # the second axis: same size, or +1
@pytest.mark.parametrize("lr_cell", [2, 1])
@pytest.mark.parametrize("hr, lr", SIZES)
def test_fusion_resampling_passes_a_ramp_through_without_shift(hr, lr, lr_cell, other):
    """A linear irradiance ramp held at the true LR cell centres comes out at the true HR/2 cell centres."""
    hr_size, lr_size = (hr, hr + other), (lr, lr + other)
    rows, cols = lr_centres(lr_size[0], lr_cell), lr_centres(lr_size[1], lr_cell)
    ramp = (0.7 * rows[:, None] - 0.3 * cols[None, :] + 0.2).float()[None, None]
    out = resample_to_cells(ramp.expand(2, 3, -1, -1), hr_size, lr_size, lr_cell)
    # Beyond the outer LR cell centres the border value is held (as bilinear interpolation does).
    y = hr_centres(hr_size[0]).clamp(rows[0], rows[-1])
    x = hr_centres(hr_size[1]).clamp(cols[0], cols[-1])
    expected = (0.7 * y[:, None] - 0.3 * x[None, :] + 0.2).float()
    assert out.shape == (2, 3, *expected.shape)
    torch.testing.assert_close(out[1, 2], expected, rtol=0, atol=1e-5)
