"""The renderer's per-sequence pre-exposure (wdss.render.exposure), against direct numpy computations."""

from __future__ import annotations

import numpy as np

from wdss.ops.tonemap import MIDDLE_GREY, luminance
from wdss.render.exposure import MAX_DARKENING, SATURATION, auto_exposure


def test_median_luminance_goes_to_middle_grey():
    rng = np.random.default_rng(0)
    color = rng.uniform(0.5, 1.5, (3, 32, 48)) * 4.0  # an over-exposed frame without a bright tail
    exposure = auto_exposure(color)
    assert abs(np.median(luminance(color * exposure)) - MIDDLE_GREY) < 1e-9


def test_a_bright_tail_lowers_the_exposure_until_at_most_one_percent_saturates():
    rng = np.random.default_rng(1)
    color = rng.uniform(0.5, 1.5, (3, 40, 50))
    color[:, :8] = 8.0  # sky or emitters: 16 % of the frame
    exposure = auto_exposure(color)
    assert exposure < MIDDLE_GREY / np.median(luminance(color))
    assert np.mean(color * exposure > SATURATION * (1 + 1e-9)) <= 0.01 + 1e-9


def test_a_large_emitter_darkens_by_at_most_one_and_a_half_stops():
    rng = np.random.default_rng(2)
    color = rng.uniform(0.5, 1.5, (3, 40, 50))
    color[:, :8] = 2000.0  # far too bright to keep: the rest of the frame would go black
    grey = MIDDLE_GREY / np.median(luminance(color))
    assert np.isclose(auto_exposure(color), MAX_DARKENING * grey)


def test_black_and_non_finite_frames():
    assert auto_exposure(np.zeros((3, 4, 4))) == 1.0
    color = np.full((3, 4, 4), 0.9)
    color[0, 0, 0] = np.nan
    color[1, 0, 0] = np.inf
    assert np.isfinite(auto_exposure(color)) and auto_exposure(color) > 0


def test_a_black_background_does_not_count_towards_the_median():
    """A scene file lit only by its own lights has an empty black background (no world)."""
    rng = np.random.default_rng(3)
    color = rng.uniform(0.5, 1.5, (3, 40, 50)) * 0.02
    color[:, :30] = 0.0  # 60 % of the frame
    exposure = auto_exposure(color)
    assert abs(np.median(luminance(color[:, 30:] * exposure)) - MIDDLE_GREY) < 1e-9


def test_a_black_background_does_not_dilute_the_saturated_share():
    """A small object on an empty background: at most 1 % of the *lit* values may saturate, not 1 % of a frame
    that is mostly zeros (here 10 % of the lit values are an emitter 10x brighter than the rest)."""
    color = np.zeros((3, 100, 100))
    color[:, :5] = 0.02  # 5 % of the frame is lit...
    color[:, :5, :10] = 0.2  # ...and a tenth of that glows
    lit = color[:, luminance(color) > 0]
    exposure = auto_exposure(color)
    assert exposure < MIDDLE_GREY / 0.02
    assert np.mean(lit * exposure > SATURATION * (1 + 1e-9)) <= 0.01 + 1e-9
