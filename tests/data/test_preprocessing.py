"""Preprocessing against analytic answers: BRDF, warping, masks, tone maps, LR sampling and flips."""

from __future__ import annotations

import numpy as np
import pytest
import torch

from wdss.data import (
    demodulate,
    extranet_brdf,
    flip,
    ggx_lut,
    hable,
    lr_size,
    point_sample,
    reinhard,
    remodulate,
    safe_brdf,
    spatial_mask,
    split_sum_brdf,
    srgb,
    temporal_mask,
    tonemap,
    warp_backward,
)
from wdss.ops.tonemap import gamma

# ---------------------------------------------------------------------------------------------- BRDF


def test_extranet_brdf_formula():
    base, metallic, specular = torch.tensor(0.3), torch.tensor(0.25), torch.tensor(0.5)
    assert torch.isclose(extranet_brdf(base, metallic, specular), torch.tensor(0.3 + 0.75 * 0.08 * 0.5))


def test_demodulation_round_trip_keeps_zero_and_tiny_brdf_pixels():
    color = torch.tensor([[[[2.0, 5.0, 1e-6, 7.0, 3.0]]]]).expand(1, 3, 1, 5).clone()
    raw = torch.tensor([[[[0.5, 0.0, 1e-8, 1e4, float("nan")]]]]).expand(1, 3, 1, 5)
    brdf = safe_brdf(raw, knee=0.0)  # the hard switch
    assert brdf[0, 0, 0].tolist() == [0.5, 1.0, 1.0, 1e4, 1.0]
    irradiance = demodulate(color, brdf)
    assert torch.isfinite(irradiance).all()
    # F = 0, tiny and NaN pass through untouched (sky, emitters); others are divided.
    assert irradiance[0, 0, 0].tolist() == pytest.approx([4.0, 5.0, 1e-6, 7e-4, 3.0])
    torch.testing.assert_close(remodulate(irradiance, brdf), color, rtol=1e-6, atol=0)


def test_brdf_knee_is_continuous_passes_zero_through_and_keeps_bright_albedo():
    f = torch.linspace(0, 1, 100001, dtype=torch.float64).view(1, 1, 1, -1)
    safe = safe_brdf(f, knee=0.02)
    assert float(safe[..., 0]) == 1.0  # F = 0 (sky, black albedo) passes through as before
    assert float(safe.min()) > 0.04  # never a division by a tiny factor
    assert float(safe.diff(dim=-1).abs().max()) < 1e-3  # steps of 1e-5 in F: no jump anywhere
    bright = f > 0.08
    torch.testing.assert_close(safe[bright], f[bright], atol=1e-4, rtol=0)  # demodulation proper where F is large
    # The hard switch (knee 0) jumps from 1 to 1e-4 at its threshold: the factor a silhouette pixel was divided by.
    hard = safe_brdf(torch.tensor([1e-4, 1.0001e-4], dtype=torch.float64), knee=0.0)
    assert hard.tolist() == [1.0, 1.0001e-4]
    odd = safe_brdf(torch.tensor([float("nan"), float("inf"), -0.5]), knee=0.1)
    assert odd.tolist() == [1.0, 1.0, 1.0]
    with pytest.raises(ValueError, match="knee"):
        safe_brdf(f, knee=-0.1)


def test_brdf_knee_round_trip_is_exact():
    color = torch.rand(1, 3, 8, 8, dtype=torch.float64) * 10
    raw = torch.rand(1, 3, 8, 8, dtype=torch.float64) ** 4  # many dark pixels
    brdf = safe_brdf(raw, knee=0.02)
    torch.testing.assert_close(remodulate(demodulate(color, brdf), brdf), color)


def test_brdf_knee_keeps_an_anti_aliased_silhouette_against_the_sky_in_range():
    """A row of an anti-aliased render: sky (F = 0, radiance 2) meets a lit grey object (F = 0.5, irradiance 1); the
    edge pixel is the pixel filter's mix of both in colour and in albedo alike. Upsampled by two in demodulated space
    (linear interpolation), the hard switch divides the edge pixel's colour by its small F and spreads the result
    over the object: its error is many times the knee's."""
    coverage = torch.tensor([0.0, 0.0, 0.0, 0.03, 1.0, 1.0, 1.0, 1.0], dtype=torch.float64)  # object coverage per LR px
    albedo = 0.5 * coverage
    color = 2.0 * (1 - coverage) + 0.5 * coverage
    hr_coverage = coverage.repeat_interleave(2)
    hr_albedo, hr_color = 0.5 * hr_coverage, 2.0 * (1 - hr_coverage) + 0.5 * hr_coverage

    def upsampled(knee: float) -> torch.Tensor:
        lr_f = safe_brdf(albedo.view(1, 1, 1, -1), knee=knee)
        irradiance = demodulate(color.view(1, 1, 1, -1), lr_f)
        up = torch.nn.functional.interpolate(irradiance, scale_factor=(1, 2), mode="bilinear", align_corners=False)
        return up * safe_brdf(hr_albedo.view(1, 1, 1, -1), knee=knee)

    error = {knee: float((upsampled(knee) - hr_color).abs().max()) for knee in (0.0, 0.02)}
    assert error[0.0] > 5 * error[0.02]
    assert error[0.02] < 1.0


def test_split_sum_table_is_physical():
    lut = ggx_lut()[0]
    scale, bias = lut
    assert lut.shape == (2, 32, 32)
    assert (scale >= 0).all() and (bias >= 0).all()
    assert float((scale + bias).max()) <= 1.01  # directional albedo of a GGX surface never exceeds 1
    assert float(scale[0, -1]) == pytest.approx(1.0, abs=1e-3) and float(bias[0, -1]) < 1e-3  # smooth, head-on
    assert float(bias[0, 0]) > 0.9  # smooth at grazing: Fresnel goes to 1
    assert float((scale + bias)[-1].mean()) < float((scale + bias)[0].mean())  # rough surfaces lose energy


def test_split_sum_brdf_of_a_smooth_dielectric_head_on():
    one = torch.ones(1, 1, 2, 2)
    f = split_sum_brdf(0.5 * one.expand(1, 3, 2, 2), 0 * one, 0.5 * one, 0 * one, one)
    torch.testing.assert_close(f, torch.full((1, 3, 2, 2), 0.5 + 0.04), atol=2e-3, rtol=0)


# ---------------------------------------------------------------------------------------------- warping


def test_warp_reproduces_a_known_translation():
    """Content moving right by 3 and down by 2 pixels: mv = (3, -2) in the y-up convention."""
    previous = torch.rand(2, 4, 20, 30, dtype=torch.float64)
    current = torch.zeros_like(previous)
    current[..., 2:, 3:] = previous[..., :-2, :-3]
    motion = torch.tensor([3.0, -2.0], dtype=torch.float64).view(1, 2, 1, 1).expand(2, 2, 20, 30)
    warped = warp_backward(previous, motion)
    torch.testing.assert_close(warped, current)  # zeros where the history came from outside


def test_warp_sub_pixel_shift_is_bilinear():
    previous = torch.arange(10.0).view(1, 1, 1, 10).expand(1, 1, 4, 10).contiguous()
    motion = torch.zeros(1, 2, 4, 10)
    motion[:, 0] = 0.25
    warped = warp_backward(previous, motion)
    torch.testing.assert_close(warped[0, 0, 1, 1:], previous[0, 0, 1, 1:] - 0.25)


def test_warp_survives_vectors_far_outside_and_nan():
    previous = torch.ones(1, 3, 6, 6)
    motion = torch.zeros(1, 2, 6, 6)
    motion[:, 0, 0, 0] = 1e9
    motion[:, 1, 1, 1] = float("nan")
    warped = warp_backward(previous, motion)
    assert torch.isfinite(warped).all()
    assert warped[0, 0, 0, 0] == 0 and warped[0, 0, 1, 1] == 0 and warped[0, 0, 3, 3] == 1


# ---------------------------------------------------------------------------------------------- masks


def _gbuffer(h, w, depth=1.0, normal=(0.0, 0.0, 1.0), albedo=0.5):
    return {
        "depth": torch.full((1, 1, h, w), depth),
        "normal": torch.tensor(normal).view(1, 3, 1, 1).expand(1, 3, h, w).clone(),
        "base_color": torch.full((1, 3, h, w), albedo),
    }


def test_spatial_mask_marks_a_crafted_depth_edge_only_where_it_is():
    hr = _gbuffer(8, 8)
    hr["depth"][..., :, 5:] = 2.0  # edge between columns 4 and 5
    lr = {k: point_sample(v, (4, 4)) for k, v in hr.items()}  # samples HR columns 1, 3, 5, 7: [1, 1, 2, 2]
    mask = spatial_mask(hr, lr)
    assert mask.shape == (1, 1, 8, 8)
    # Bilinear upsampling puts HR column x at LR coordinate (x + .5) / 2 - .5: columns 3 and 4 straddle the
    # LR step (1.25 and 1.75 instead of 1); every other column interpolates between equal LR samples.
    assert mask[0, 0, :, 3:5].all()
    assert mask[0, 0, :, :3].sum() == 0 and mask[0, 0, :, 5:].sum() == 0


@pytest.mark.parametrize(
    "change, expected",
    [({"normal": (1.0, 0.0, 0.0)}, 1.0), ({"albedo": 0.65}, 1.0), ({"albedo": 0.55}, 0.0), ({"depth": 1.005}, 0.0)],
)
def test_spatial_mask_thresholds(change, expected):
    hr = _gbuffer(4, 4)
    lr = _gbuffer(2, 2, **change)
    assert torch.all(spatial_mask(hr, lr) == expected)


def test_temporal_mask_channels_and_degenerate_normals():
    current = _gbuffer(2, 2)
    previous = _gbuffer(2, 2, depth=1.5, normal=(0.0, 1.0, 0.0), albedo=0.2)
    previous["normal"][..., 0, 0] = 0.0  # zero-length normal
    previous["normal"][..., 0, 1] = float("nan")
    mask = temporal_mask(current, previous)
    assert mask.shape == (1, 5, 2, 2) and torch.isfinite(mask).all()
    torch.testing.assert_close(mask[:, 0], torch.full((1, 2, 2), 0.5))
    torch.testing.assert_close(mask[:, 1:4], torch.full((1, 3, 2, 2), 0.3))
    torch.testing.assert_close(mask[:, 4], torch.full((1, 2, 2), 0.5))  # orthogonal or missing: (1 - 0) / 2


# ---------------------------------------------------------------------------------------------- tone maps


def test_hable_matches_the_authors_curve():
    a, b, c, d, e, f = 0.15, 0.5, 0.1, 0.2, 0.02, 0.3

    def curve(x):
        return (x * (a * x + c * b) + d * e) / (x * (a * x + b) + d * f) - e / f

    x = torch.tensor([0.0, 0.01, 0.1, 0.5, 1.12, 5.0, 1e5])
    expected = np.clip([curve(10 * v) / curve(11.2) for v in x.tolist()], 0, 1)
    np.testing.assert_allclose(hable(x).numpy(), expected, rtol=1e-5)
    assert hable(torch.tensor(1.12)) == pytest.approx(1.0)  # white point 11.2 at exposure 10


def test_srgb_reinhard_gamma():
    x = torch.tensor([0.0, 0.002, 0.5, 1.0, 4.0])
    expected_srgb = [0.0, 12.92 * 0.002, 1.055 * 0.5 ** (1 / 2.4) - 0.055, 1.0, 1.0]
    np.testing.assert_allclose(srgb(x).numpy(), expected_srgb, rtol=1e-6)
    np.testing.assert_allclose(reinhard(x).numpy(), (x / (1 + x)).numpy())
    np.testing.assert_allclose(gamma(x).numpy(), np.clip(x.numpy(), 0, 1) ** (1 / 2.2))
    assert tonemap(x, "reinhard").equal(reinhard(x))
    with pytest.raises(ValueError, match="unknown tone map 'aces'"):
        tonemap(x, "aces")


# ---------------------------------------------------------------------------------------------- LR grid


@pytest.mark.parametrize("scale", [2.0, 3.0, 2.5])
def test_lr_pixels_are_the_hr_pixels_under_their_cell_centres(scale):
    height, width = 30, 45
    h, w = lr_size(height, width, scale)
    assert (h, w) == (round(height / scale), round(width / scale))
    index = torch.arange(height * width, dtype=torch.float64).view(1, 1, height, width)
    lr = point_sample(index, (h, w))
    for i in range(h):
        for j in range(w):
            # Cell centre of LR pixel (i, j) in HR pixel units, [0, H) x [0, W): ((i + .5) H / h, (j + .5) W / w).
            y, x = int((i + 0.5) * height / h), int((j + 0.5) * width / w)
            assert lr[0, 0, i, j] == y * width + x


def test_lr_size_refuses_scales_outside_one_to_eight():
    assert lr_size(216, 384, 8) == (27, 48)
    assert lr_size(5, 7, 1.0) == (5, 7)
    with pytest.raises(ValueError, match=r"scale must lie in \[1, 8\], got 0.5"):
        lr_size(10, 10, 0.5)


# ---------------------------------------------------------------------------------------------- flips


def test_flips_mirror_motion_and_normals_consistently():
    camera = torch.linalg.qr(torch.randn(3, 3))[0]  # an arbitrary camera rotation
    normal = torch.nn.functional.normalize(torch.randn(3, 4, 5), dim=0)
    buffers = {"motion": torch.randn(2, 4, 5), "normal": normal, "depth": torch.rand(1, 4, 5)}
    out = flip(buffers, horizontal=True, vertical=False, camera=camera)
    torch.testing.assert_close(out["depth"], buffers["depth"].flip(-1))
    torch.testing.assert_close(out["motion"][0], -buffers["motion"][0].flip(-1))
    torch.testing.assert_close(out["motion"][1], buffers["motion"][1].flip(-1))
    right = camera[:, 0].view(3, 1, 1)
    torch.testing.assert_close((out["normal"] * right).sum(0), -(normal * right).sum(0).flip(-1))
    torch.testing.assert_close(out["normal"].norm(dim=0), torch.ones(4, 5))
    back = flip(out, horizontal=True, vertical=False, camera=camera)
    for name in buffers:
        torch.testing.assert_close(back[name], buffers[name])


def test_flipping_world_normals_without_a_camera_is_refused():
    with pytest.raises(ValueError, match="needs the camera rotation"):
        flip({"normal": torch.zeros(3, 2, 2)}, horizontal=True, vertical=False)
