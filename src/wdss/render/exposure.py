"""Pre-exposure of rendered radiance: one factor per sequence, as an engine's pre-exposure does.

Cycles writes radiance in scene units; what those units look like depends on the HDRI, the sun and the
emitters, and on ``data/mini`` the metric's tone map (Hable, exposure 10, white 11.2: it reaches 1.0 at linear
1.12) saturated a different share of each sequence's values, much of some. The renderer scales each sequence by
one factor, chosen from quick probes of its first, middle and last frames, so that its median luminance is that of
real engine frames (DFASR's Unreal sample: pre-tonemap median 0.19, tone-mapped median 0.47, 0.1 % saturated) --
unless that would saturate more than 1 % of the probes, in which case the bright end decides, within 1.5 stops.
The factor is recorded in ``sequence.json`` (``exposure``) and applied to every frame and every resolution
alike, so motion, history and demodulation stay consistent. Pixels of exactly zero radiance (the empty black
background of a scene file lit only by its own lights) count neither towards the median nor towards the share
of saturated values: a frame that is 95 % black background would otherwise let a fifth of its lit values
saturate.
"""

from __future__ import annotations

import numpy as np

from wdss.ops.tonemap import MIDDLE_GREY, luminance  # the median aimed at: Hable maps 0.18 to 0.46

__all__ = ["MAX_DARKENING", "SATURATED_SHARE", "SATURATION", "auto_exposure"]

SATURATION = 1.0  # linear value near which the metric's tone curve saturates (0.974 at 1.0; 1.0 at 1.12)
SATURATED_SHARE = 0.01  # at most this share of colour values may lie above SATURATION after exposure...
MAX_DARKENING = 0.35  # ...unless meeting that would darken the median below 0.35 x middle grey (1.5 stops)


def auto_exposure(color: np.ndarray, *, middle_grey: float = MIDDLE_GREY, saturated_share: float = SATURATED_SHARE):
    """The factor that brings a frame's median luminance to ``middle_grey``, lowered when more than
    ``saturated_share`` of its colour values would then exceed :data:`SATURATION`.

    ``color``: ``(3, H, W)`` linear radiance (non-finite values are ignored; black pixels count neither towards
    the median nor towards the saturated share). Returns a positive float.
    """
    color = np.nan_to_num(np.asarray(color, dtype=np.float64), nan=0.0, posinf=0.0, neginf=0.0).clip(0.0, None)
    brightness = luminance(color)
    lit = brightness > 0.0
    if not lit.any():  # an all-black frame: leave the radiance as rendered
        return 1.0
    exposure = middle_grey / float(np.median(brightness[lit]))
    bright = float(np.quantile(color[:, lit], 1.0 - saturated_share))
    if bright * exposure > SATURATION:
        # The bright end may lower the exposure by at most MAX_DARKENING: beyond that a large emitter or the sun
        # would leave the rest of the frame in the toe of the curve, where the metric sees nothing either.
        exposure = max(SATURATION / bright, exposure * MAX_DARKENING)
    return float(exposure)
