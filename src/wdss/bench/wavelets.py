"""``bench wavelets``: wdss's DWT/SWT analysis + synthesis against ptwt's."""

from __future__ import annotations

from collections.abc import Sequence

import torch
from rich.table import Table

from wdss.bench.timing import median_ms

BASES = ("haar", "db4", "sym4")


def _ptwt_swt2_roundtrip(x: torch.Tensor, wavelet: str) -> torch.Tensor:
    """A level-1 2-D SWT composed from ptwt's 1-D ``swt``/``iswt``: along W, then along H per branch."""
    import ptwt

    low_w, high_w = ptwt.swt(x, wavelet, level=1, axis=-1)
    bands = [band for branch in (low_w, high_w) for band in ptwt.swt(branch, wavelet, level=1, axis=-2)]
    low = ptwt.iswt(bands[:2], wavelet, axis=-2)
    high = ptwt.iswt(bands[2:], wavelet, axis=-2)
    return ptwt.iswt([low, high], wavelet, axis=-1)


def _ptwt_dwt2_roundtrip(x: torch.Tensor, wavelet: str) -> torch.Tensor:
    import ptwt

    return ptwt.waverec2(ptwt.wavedec2(x, wavelet, mode="periodic", level=1), wavelet)


def bench_wavelets(shape: Sequence[int], repeats: int, device: str, bases: Sequence[str] = BASES) -> Table:
    from wdss.wavelets import WaveletTransform

    x = torch.rand(*shape, device=device)
    table = Table(title=f"wavelet analysis + synthesis, {tuple(shape)} float32 on {device}, median of {repeats}")
    for column in ("transform", "basis", "wdss ms", "ptwt ms", "ptwt / wdss"):
        table.add_column(column, justify="right" if "ms" in column or "/" in column else "left")
    with torch.inference_mode():
        for transform, reference in (("dwt", _ptwt_dwt2_roundtrip), ("swt", _ptwt_swt2_roundtrip)):
            for basis in bases:
                module = WaveletTransform(transform, basis).to(device)
                ours = median_ms(lambda m=module: m.synthesis(m.analysis(x)), repeats=repeats)
                theirs = median_ms(lambda b=basis, r=reference: r(x, b), repeats=repeats)
                table.add_row(transform, basis, f"{ours:.1f}", f"{theirs:.1f}", f"{theirs / ours:.2f}x")
    return table
