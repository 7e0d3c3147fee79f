"""Temporal stability metrics (wdss.training.temporal_metrics) on synthetic sequences and against numpy."""

from __future__ import annotations

import math

import numpy as np
import pytest
import torch

from wdss.training.temporal_metrics import THRESHOLDS, TemporalStability

H, W, FRAMES = 40, 56, 6
PAN = (1.3, -0.6)  # motion vectors (x right, y up): the scene moves 1.3 px right and 0.6 px down per frame


def texture(x: np.ndarray, y: np.ndarray, phase: float = 0.0) -> np.ndarray:
    """A smooth static scene (3, ...) in [0.1, 0.9], sampled anywhere."""
    channels = [
        0.5 + 0.2 * np.sin(0.31 * x + 0.17 * y + phase + c) + 0.2 * np.cos(0.23 * y - 0.11 * x + 2 * c)
        for c in range(3)
    ]
    return np.stack(channels).astype(np.float32)


def pan_frame(t: int, phase: float = 0.0) -> torch.Tensor:
    """Frame t of the static scene under the camera pan: pixel (x, y) shows the scene at (x - 1.3 t, y - 0.6 t)."""
    ys, xs = np.mgrid[0:H, 0:W].astype(np.float64)
    return torch.from_numpy(texture(xs - PAN[0] * t, ys + PAN[1] * t, phase))[None]


def flat_gbuffer() -> torch.Tensor:
    """A plane facing the camera: depth 0.5, normal +z, grey albedo (the GBUFFER_STACK channel order)."""
    g = torch.zeros(1, 11, H, W)
    g[:, 0:3], g[:, 3], g[:, 6] = 0.5, 0.5, 1.0
    return g


def measure(frames: list[torch.Tensor], targets: list[torch.Tensor], motion: torch.Tensor | None = None) -> dict:
    metric = TemporalStability()
    motion = torch.tensor(PAN).view(1, 2, 1, 1).expand(1, 2, H, W) if motion is None else motion
    for t, (frame, target) in enumerate(zip(frames, targets, strict=True)):
        metric.update("pan", t, frame, target, motion, flat_gbuffer())
    return metric.compute()


def test_the_target_under_a_camera_pan_is_its_own_reference():
    targets = [pan_frame(t) for t in range(FRAMES)]
    values = measure(targets, targets)
    assert values["twe_ratio"] == 1.0 and values["tpsnr"] == math.inf
    assert 0 < values["twe_target"] < 0.01  # only the bilinear warp's resampling error of a smooth scene


def test_a_prediction_that_moves_exactly_with_the_camera_is_as_stable_as_the_target():
    """Every frame an exact (analytic) translation of one image that is not the target: wrong per frame (low
    PSNR), yet as stable as the ground truth."""
    targets = [pan_frame(t) for t in range(FRAMES)]
    shifted = [pan_frame(t, phase=1.0) for t in range(FRAMES)]
    assert float((shifted[0] - targets[0]).abs().mean()) > 0.1
    values = measure(shifted, targets)
    assert values["twe_ratio"] == pytest.approx(1.0, abs=0.05)
    assert values["tpsnr"] > 40


def test_per_frame_noise_raises_the_ratio_and_lowers_the_temporal_psnr():
    generator = torch.Generator().manual_seed(0)
    targets = [pan_frame(t) for t in range(FRAMES)]
    ratios, tpsnrs = [], []
    for sigma in (0.0, 0.005, 0.02):
        noisy = [(t + sigma * torch.randn(t.shape, generator=generator)).clamp(0, 1) for t in targets]
        values = measure(noisy, targets)
        ratios.append(values["twe_ratio"])
        tpsnrs.append(values["tpsnr"])
    assert ratios[0] == 1.0 < 1.5 < ratios[1] < ratios[2] and ratios[2] > 4
    assert tpsnrs[0] == math.inf > tpsnrs[1] > tpsnrs[2]


# ------------------------------------------------------------------------------------------ numpy reference


def np_warp(previous: np.ndarray, motion: np.ndarray) -> np.ndarray:
    """Bilinear backward warp (C, H, W) with zeros outside, written out tap by tap."""
    c, h, w = previous.shape
    out = np.zeros_like(previous, dtype=np.float64)
    for y in range(h):
        for x in range(w):
            sx, sy = x - motion[0, y, x], y + motion[1, y, x]
            x0, y0 = math.floor(sx), math.floor(sy)
            for yy, xx, weight in (
                (y0, x0, (1 - (sx - x0)) * (1 - (sy - y0))),
                (y0, x0 + 1, (sx - x0) * (1 - (sy - y0))),
                (y0 + 1, x0, (1 - (sx - x0)) * (sy - y0)),
                (y0 + 1, x0 + 1, (sx - x0) * (sy - y0)),
            ):
                if 0 <= yy < h and 0 <= xx < w:
                    out[:, y, x] += weight * previous[:, yy, xx]
    return out


def np_valid(motion: np.ndarray, current: np.ndarray, previous: np.ndarray) -> np.ndarray:
    """(H, W) bool: all four taps inside, and depth, albedo and normals of the warped previous G-buffer agree."""
    h, w = motion.shape[1:]
    ys, xs = np.mgrid[0:h, 0:w]
    sx, sy = xs - motion[0], ys + motion[1]
    inside = (np.floor(sx) >= 0) & (np.floor(sx) + 1 <= w - 1) & (np.floor(sy) >= 0) & (np.floor(sy) + 1 <= h - 1)
    inside |= (sx == np.floor(sx)) & (sy == np.floor(sy)) & (sx >= 0) & (sx <= w - 1) & (sy >= 0) & (sy <= h - 1)
    warped = np_warp(previous, motion)

    def unit(n: np.ndarray) -> np.ndarray:
        length = np.sqrt((n**2).sum(0))
        return np.where(length > 1e-6, n / np.maximum(length, 1e-6), 0.0)

    depth = np.abs(current[3] - warped[3]) <= THRESHOLDS["depth"] * current[3]
    albedo = np.abs(current[0:3] - warped[0:3]).mean(0) <= THRESHOLDS["albedo"]
    normal = (1 - (unit(current[4:7]) * unit(warped[4:7])).sum(0)) / 2 <= THRESHOLDS["normal"]
    return inside & depth & albedo & normal


def test_metrics_agree_with_a_direct_numpy_computation():
    rng = np.random.default_rng(0)
    frames = 4
    preds = rng.random((frames, 3, 12, 16)).astype(np.float32)
    targets = rng.random((frames, 3, 12, 16)).astype(np.float32)
    motion = rng.uniform(-2.5, 2.5, (frames, 2, 12, 16)).astype(np.float32)
    motion[:, :, :3, :3] = 0.0  # exact grid positions too
    gbuffers = np.zeros((frames, 11, 12, 16), np.float32)
    gbuffers[:, 0:3] = 0.4
    gbuffers[:, 3] = 0.5
    gbuffers[:, 4:7] = [[[0.0]], [[0.0]], [[1.0]]]
    gbuffers[2:, 3, 6:, 8:] = 0.9  # a disocclusion: a nearer object from frame 2 on
    gbuffers[1, 0:3, :4, 10:] = 0.95  # an albedo change
    gbuffers[3, 4:7, 8:, :5] = [[[1.0]], [[0.0]], [[0.0]]]  # a normal flip
    metric = TemporalStability()
    for t in range(frames):
        metric.update(
            "seq",
            t,
            *(torch.from_numpy(a[t : t + 1]) for a in (preds, targets, motion, gbuffers)),
        )
    got = metric.compute()

    error = target_error = squared = count = 0.0
    for t in range(1, frames):
        valid = np_valid(motion[t], gbuffers[t], gbuffers[t - 1])
        change = preds[t] - np_warp(preds[t - 1], motion[t])
        target_change = targets[t] - np_warp(targets[t - 1], motion[t])
        error += np.abs(change)[:, valid].sum()
        target_error += np.abs(target_change)[:, valid].sum()
        squared += ((change - target_change) ** 2)[:, valid].sum()
        count += 3 * valid.sum()
    assert 0.2 < count / (3 * 3 * 12 * 16) < 0.9  # the masks and the frame edge leave some pixels out, not all
    expected = {
        "twe": error / count,
        "twe_target": target_error / count,
        "twe_ratio": error / target_error,
        "tpsnr": -10 * math.log10(squared / count),
    }
    assert got == pytest.approx(expected, rel=1e-5)


def test_only_consecutive_frames_of_one_sequence_pair_and_sequences_average():
    metric = TemporalStability()
    still = flat_gbuffer()
    zero = torch.zeros(1, 2, H, W)
    target = pan_frame(0)
    for sequence, frame, offset in (("a", 1, 0.0), ("a", 2, 0.1), ("a", 4, 0.5), ("b", 5, 0.5), ("b", 6, 0.2)):
        metric.update(sequence, frame, (target + offset).clamp(0, 1), target, zero, still)
    per_sequence = metric.per_sequence()
    # a: only 1 -> 2 pairs (4 follows a gap), b: 5 -> 6; a still target barely changes, so any change is flicker.
    assert per_sequence["a"]["twe"] == pytest.approx(float((target + 0.1).clamp(0, 1).sub(target).abs().mean()))
    b_change = (target + 0.5).clamp(0, 1) - (target + 0.2).clamp(0, 1)
    assert per_sequence["b"]["twe"] == pytest.approx(float(b_change.abs().mean()))
    assert per_sequence["a"]["twe_target"] < 1e-6 and per_sequence["a"]["twe_ratio"] > 1e4
    values = metric.compute()
    assert values["twe"] == pytest.approx((per_sequence["a"]["twe"] + per_sequence["b"]["twe"]) / 2)
    frames = metric.frames("a")
    assert [f[0] for f in frames] == [1, 2, 4] and math.isnan(frames[0][2]) and math.isnan(frames[2][2])
