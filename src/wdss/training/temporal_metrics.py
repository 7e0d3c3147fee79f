"""Temporal stability of test sequences in tone-mapped space: the warping error and the temporal PSNR.

A model that wins PSNR per frame but flickers is worse in a game. For consecutive frames t-1, t of a sequence,
with W the backward warp by frame t's motion vectors (:func:`wdss.ops.warp.warp_backward`), y the tone-mapped
prediction and g the tone-mapped target (the same :class:`~wdss.ops.tonemap.ToneMap` as the other metrics):

* ``twe``: the mean of ``|y_t - W(y_{t-1})|`` over valid pixels and channels; ``twe_target`` the same of g (what
  the ground truth itself changes, plus the warp's resampling error); ``twe_ratio = twe / twe_target``: 1 is as
  stable as the ground truth, above is flicker the target does not have, below is smoother than the truth (blur);
* ``tpsnr``: the PSNR (peak 1) between the frame differences ``y_t - W(y_{t-1})`` and ``g_t - W(g_{t-1})`` over
  valid pixels: whether the prediction changes as the target does.

Valid pixels: the warp's source lies inside the previous frame (all four bilinear taps), and the previous
G-buffer, warped alike, shows the same surface: the channels of :func:`~wdss.ops.warp.temporal_mask` within
:data:`THRESHOLDS`, depth relative to the current depth (per-frame depth normalisation shifts absolute depth when
the farthest visible point changes), mean albedo difference at most 0.3 and ``n . n' >= 0.5``. So disocclusions,
the silhouettes of moving objects and the background (no surface, no normal), which no warp predicts, are left
out. The thresholds are looser than the spatial mask's (0.1, 0.9): bilinearly warped bump-mapped normals and sharp
textures differ by more than that on the same surface, so those thresholds would leave out much of every frame.

The sums are pooled over all frame pairs of a sequence (every valid pixel weighs the same); :meth:`compute`
returns the means over sequences.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import torch
from torch import Tensor

from wdss.data.batch import GBUFFER_STACK
from wdss.data.layouts import BUFFERS
from wdss.ops.warp import temporal_mask, warp_backward
from wdss.training.metrics import psnr

__all__ = ["THRESHOLDS", "TemporalStability", "gbuffer_parts", "valid_pixels"]

# Largest disagreement with the warped previous frame that still counts as the same surface: depth relative to the
# current depth, mean absolute albedo, and (1 - n . n') / 2 (0.25: n . n' >= 0.5).
THRESHOLDS = {"depth": 0.05, "albedo": 0.3, "normal": 0.25}
_COVERED = 1.0 - 1e-4  # warped ones below this: some bilinear tap fell outside the previous frame


def gbuffer_parts(gbuffer: Tensor) -> dict[str, Tensor]:
    """``depth``, ``normal`` and ``base_color`` of a stacked ``(N, 11, H, W)`` G-buffer (``GBUFFER_STACK``)."""
    parts = dict(zip(GBUFFER_STACK, gbuffer.split([BUFFERS[name] for name in GBUFFER_STACK], dim=1), strict=True))
    return {name: parts[name] for name in ("depth", "normal", "base_color")}


def valid_pixels(
    motion: Tensor, current: dict[str, Tensor], previous: dict[str, Tensor], thresholds: dict[str, float] = THRESHOLDS
) -> Tensor:
    """``(N, 1, H, W)`` bool: where frame t's pixel has a trustworthy history in frame t-1 (module docstring)."""
    names = ("depth", "normal", "base_color")
    ones = torch.ones_like(previous["depth"])
    stacked = warp_backward(torch.cat([ones, *(previous[name] for name in names)], dim=1), motion)
    coverage, *warped = stacked.split([1, 1, 3, 3], dim=1)
    mask = temporal_mask(current, dict(zip(names, warped, strict=True)))
    return (
        (coverage >= _COVERED)
        & (mask[:, :1] <= thresholds["depth"] * current["depth"])
        & (mask[:, 1:4].mean(1, keepdim=True) <= thresholds["albedo"])
        & (mask[:, 4:] <= thresholds["normal"])
    )


@dataclass
class _Sums:
    """One sequence's pooled sums over its frame pairs (float64 Python numbers)."""

    error: float = 0.0  # sum of |y_t - W(y_{t-1})| over valid pixels and channels
    target_error: float = 0.0  # the same of the target
    squared: float = 0.0  # sum of squared differences between the two frame differences
    count: int = 0  # valid pixel-channels
    frames: list[tuple[int, float, float, float]] = field(default_factory=list)  # frame, psnr, twe, twe_target


class TemporalStability:
    """The temporal metrics of one test scale, from frames that arrive in order, sequence after sequence.

    :meth:`update` takes one frame at a time; a frame pairs with the previous one when that was frame - 1 of the
    same sequence (a gap or a new sequence starts afresh).
    """

    def __init__(self, thresholds: dict[str, float] | None = None) -> None:
        self.thresholds = dict(THRESHOLDS if thresholds is None else thresholds)
        self.sequences: dict[str, _Sums] = {}
        self._previous: tuple[str, int, Tensor, Tensor, dict[str, Tensor]] | None = None

    @torch.no_grad()
    def update(
        self, sequence: str, frame: int, prediction: Tensor, target: Tensor, motion: Tensor, gbuffer: Tensor
    ) -> None:
        """One frame: tone-mapped ``prediction`` and ``target`` ``(1, 3, H, W)`` in [0, 1], its ``motion``
        ``(1, 2, H, W)`` and its stacked G-buffer ``(1, 11, H, W)``."""
        prediction, target = prediction.detach().float(), target.detach().float()
        current = {k: v.float() for k, v in gbuffer_parts(gbuffer).items()}
        sums = self.sequences.setdefault(sequence, _Sums())
        twe = twe_target = math.nan
        previous = self._previous
        if previous is not None and previous[:2] == (sequence, frame - 1):
            valid = valid_pixels(motion.float(), current, previous[4], self.thresholds)
            warped = warp_backward(torch.cat([previous[2], previous[3]], dim=1), motion.float())
            change, target_change = prediction - warped[:, :3], target - warped[:, 3:]
            weight = valid.to(change.dtype).expand_as(change)
            count = int(weight.sum())
            if count:
                error = float((change.abs() * weight).sum())
                target_error = float((target_change.abs() * weight).sum())
                sums.error += error
                sums.target_error += target_error
                sums.squared += float((((change - target_change) ** 2) * weight).sum())
                sums.count += count
                twe, twe_target = error / count, target_error / count
        sums.frames.append((frame, float(psnr(prediction, target)[0]), twe, twe_target))
        self._previous = (sequence, frame, prediction, target, current)

    def add(self, sequences: dict[str, _Sums]) -> None:
        """Pool the sums of another share of the frames (a DDP rank's block of the sequences) into these."""
        for name, other in sequences.items():
            sums = self.sequences.setdefault(name, _Sums())
            sums.error += other.error
            sums.target_error += other.target_error
            sums.squared += other.squared
            sums.count += other.count
            sums.frames = sorted(sums.frames + other.frames)

    def per_sequence(self) -> dict[str, dict[str, float]]:
        """``twe``, ``twe_target``, ``twe_ratio`` and ``tpsnr`` of each sequence that had a valid frame pair."""
        out = {}
        for name, sums in self.sequences.items():
            if not sums.count:
                continue
            twe, twe_target = sums.error / sums.count, sums.target_error / sums.count
            mse = sums.squared / sums.count
            out[name] = {
                "twe": twe,
                "twe_target": twe_target,
                # A target that does not change at all (a static, noiseless scene): any change is flicker.
                "twe_ratio": twe / twe_target if twe_target > 0 else (1.0 if twe == 0 else math.inf),
                "tpsnr": -10.0 * math.log10(mse) if mse > 0 else math.inf,
            }
        return out

    def compute(self) -> dict[str, float]:
        """Each metric's mean over sequences (of the finite values; +inf when none is, e.g. the target's tpsnr)."""
        per_sequence = list(self.per_sequence().values())
        out = {}
        for name in ("twe", "twe_target", "twe_ratio", "tpsnr"):
            values = [values[name] for values in per_sequence]
            finite = [v for v in values if math.isfinite(v)]
            if values:
                out[name] = sum(finite) / len(finite) if finite else math.inf
        return out

    def frames(self, sequence: str) -> list[tuple[int, float, float, float]]:
        """``(frame, psnr, twe, twe_target)`` of every frame of ``sequence`` in order (NaN twe without a pair)."""
        return list(self.sequences[sequence].frames)
