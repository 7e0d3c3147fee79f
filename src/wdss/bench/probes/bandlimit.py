"""``bench bandlimit``: what an output without detail above the LR grid's Nyquist frequency can score at best."""

from __future__ import annotations

from collections.abc import Sequence

import torch
from rich.table import Table


def band_limited(image: torch.Tensor, scale: float) -> torch.Tensor:
    """The orthogonal projection of ``image`` (..., H, W) onto the images the LR grid of ``scale`` can hold
    (:func:`wdss.ops.sampling.lr_size`, ``h x w``): its orthonormal 2-D DCT-II with every coefficient at row index
    >= ``h`` or column index >= ``w`` set to zero. Of all such images it is the nearest in squared error (Parseval),
    so its PSNR against ``image`` bounds any upsampler whose output has no content above the LR grid's frequencies;
    the DCT's even extension keeps the frame's borders from leaking in as a periodic FFT's wrap-around would."""
    from scipy.fft import dctn, idctn

    from wdss.ops.sampling import lr_size

    array = image.detach().double().cpu().numpy()
    coefficients = dctn(array, axes=(-2, -1), norm="ortho")
    height, width = lr_size(*array.shape[-2:], scale)
    coefficients[..., height:, :] = 0.0
    coefficients[..., :, width:] = 0.0
    return torch.from_numpy(idctn(coefficients, axes=(-2, -1), norm="ortho")).to(image)


def bench_bandlimit(
    root: str,
    names: Sequence[str] | None,
    scales: Sequence[float],
    tonemap_name: str = "hable",
    exposure=None,
    skip_first: bool = False,
) -> Table:
    """Per sequence and scale, the mean over frames of the PSNR of the tone-mapped HR target against its
    :func:`band_limited` projection, in the metric's display space: the most a method can score from LR colour alone
    without predicting detail the LR grid cannot hold. Every frame by default, as the data module tests a model that
    reads no previous frame; ``skip_first``: without the first, as it tests one that does."""
    from wdss.data.layouts import discover_sequences
    from wdss.ops.tonemap import ToneMap
    from wdss.training.metrics import psnr

    tone = ToneMap(tonemap_name, exposure)
    table = Table(title=f"bandlimit: PSNR (dB) of the target against its projection on the LR grid, {tonemap_name}")
    table.add_column("sequence")
    table.add_column("frames", justify="right")
    for scale in scales:
        table.add_column(f"{scale:g}x", justify="right")
    for sequence in discover_sequences(root, names):
        frames = sorted(sequence.frames)[1:] if skip_first else sorted(sequence.frames)
        totals = [0.0 for _ in scales]
        for frame in frames:
            target = torch.from_numpy(sequence.read(frame, sequence.hr, ["color"])["color"])[None]
            shown = tone(target, target)
            for i, scale in enumerate(scales):
                totals[i] += float(psnr(band_limited(shown, scale).clamp(0, 1), shown)[0])
        table.add_row(sequence.name, str(len(frames)), *(f"{t / len(frames):.2f}" for t in totals))
    return table
