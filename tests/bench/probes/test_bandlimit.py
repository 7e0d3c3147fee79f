"""wdss.bench.probes.bandlimit: the projection onto what the LR grid holds, and the bound it puts on the fixture."""

from __future__ import annotations

import pytest

from tests.bench.tables import table_rows
from wdss.bench.cli import main
from wdss.bench.probes.bandlimit import band_limited


def _dct_matrix(n: int):
    """The orthonormal DCT-II matrix from its formula (an oracle independent of scipy.fft)."""
    import numpy as np

    k, i = np.meshgrid(np.arange(n), np.arange(n), indexing="ij")
    matrix = np.sqrt(2.0 / n) * np.cos(np.pi * (2 * i + 1) * k / (2 * n))
    matrix[0] /= np.sqrt(2.0)
    return matrix


@pytest.mark.parametrize("scale", [2.0, 2.5, 3.0, 4.0])
def test_band_limited_is_the_orthogonal_projection_onto_the_lr_grids_cosines(scale):
    import numpy as np
    import torch

    rng = np.random.default_rng(0)
    image = rng.random((2, 3, 18, 24))
    rows, cols = _dct_matrix(18), _dct_matrix(24)
    height, width = {2.0: (9, 12), 2.5: (7, 10), 3.0: (6, 8), 4.0: (4, 6)}[scale]  # round(18 / s), round(24 / s)
    keep_rows = np.diag((np.arange(18) < height).astype(float))
    keep_cols = np.diag((np.arange(24) < width).astype(float))
    expected = rows.T @ keep_rows @ rows @ image @ cols.T @ keep_cols @ cols
    projected = band_limited(torch.from_numpy(image), scale).numpy()
    np.testing.assert_allclose(projected, expected, atol=1e-12)
    np.testing.assert_allclose(band_limited(torch.from_numpy(projected), scale).numpy(), projected, atol=1e-12)
    residual = image - projected  # orthogonal to everything the LR grid holds
    assert abs(float((residual * projected).sum())) < 1e-9
    low = rows.T @ keep_rows @ rng.random((18, 24)) @ keep_cols @ cols  # an image the LR grid holds exactly
    np.testing.assert_allclose(band_limited(torch.from_numpy(low), scale).numpy(), low, atol=1e-12)


def test_bandlimit_bound_falls_with_the_scale_on_the_fixture(capsys):
    from wdss.paths import PROJECT_ROOT

    main(["bandlimit", str(PROJECT_ROOT / "tests" / "fixtures" / "rendered"), "--scales", "2", "3", "4"])
    [row] = [cells for (name, _), cells in table_rows(capsys.readouterr().out).items() if name == "fixture_000"]
    bound_2x, bound_3x, bound_4x = map(float, row)
    assert 10.0 < bound_4x <= bound_3x <= bound_2x < 60.0  # nested subspaces: a coarser grid holds less
