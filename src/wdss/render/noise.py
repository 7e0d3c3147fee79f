"""The targets' own noise: how far above every method's PSNR the rendered ground truth lets a score go.

Each high-resolution frame is rendered again as the dataset rendered it (samples, denoiser, pixel filter), with
another Cycles seed, and compared with the stored target after the metrics' tone map (Hable at exposure 10). With
independent noise of equal variance in both, their mean squared difference is twice the target's noise variance,
so a perfect method -- the noise-free frame -- would score ``PSNR(target, re-render) + 10 log10(2)`` against these
targets: the ceiling of every PSNR measured on them. A sequence records it in its ``sequence.json`` (``noise``).
"""

from __future__ import annotations

import math
import time
from collections.abc import Sequence as Frames
from pathlib import Path
from typing import Any

import numpy as np
import torch

__all__ = ["NOISE_SEED_STRIDE", "measure_noise"]

# The re-render's Cycles seed is the dataset's plus this times the noise seed (a prime: no seed of another sequence).
NOISE_SEED_STRIDE = 7919
HOW = "PSNR(target, re-render with another Cycles seed) + 10 log10 2, Hable at exposure 10"


def measure_noise(scene: Any, folder: str | Path, exposure: float, frames: Frames[int], noise_seed: int = 1) -> dict:
    """Re-render ``frames`` of the sequence in ``folder`` with ``scene`` (a :class:`wdss.render.blender.BlenderScene`
    or a scene file's, set up as the dataset rendered it) and return its ``noise`` record: ``ceiling_psnr_db``,
    ``mse`` (tone-mapped, target vs re-render), ``frames``, ``noise_seed``, ``seconds_per_frame`` and how it was
    measured. The scene's Cycles seed is restored afterwards."""
    from wdss.data.layouts import Sequence
    from wdss.ops.tonemap import hable

    sequence = Sequence(Path(folder))
    chosen = [int(f) for f in frames if f in sequence.frames]
    if not chosen:
        raise ValueError(f"{folder}: none of frames {list(frames)} is rendered (it has {sequence.frames})")
    cycles = scene.scene.cycles
    seed = cycles.seed
    cycles.seed = seed + NOISE_SEED_STRIDE * noise_seed  # still animated per frame, as the dataset's
    errors, start = [], time.perf_counter()
    try:
        for frame in chosen:
            target = torch.from_numpy(sequence.read(frame, sequence.hr, ["color"])["color"])[None]
            height, width = target.shape[-2:]
            again = torch.from_numpy(scene.render(frame, width, height)["Combined"][None, :3] * exposure)
            errors.append(float(((hable(again) - hable(target)) ** 2).mean()))
    finally:
        cycles.seed = seed
    mse = float(np.mean(errors))
    psnr = -10 * math.log10(max(mse, 1e-12))
    return {
        "ceiling_psnr_db": round(psnr + 10 * math.log10(2.0), 3),
        "mse": mse,
        "frames": chosen,
        "noise_seed": noise_seed,
        "seconds_per_frame": round((time.perf_counter() - start) / len(chosen), 3),
        "how": HOW,
    }
