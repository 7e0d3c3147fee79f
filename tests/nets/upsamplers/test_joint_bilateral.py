"""Joint bilateral upsampling: against a per-pixel loop, and its edge-preserving and degenerate behaviour."""

from __future__ import annotations

import math

import numpy as np
import pytest
import torch
import torch.nn.functional as F

from tests.helpers import batch
from wdss.nets.upsamplers.joint_bilateral import FALLBACK_WEIGHT, JointBilateralUpsample, joint_bilateral_upsample
from wdss.ops.sampling import lr_size
from wdss.training.module import SuperResolutionModule


def loop_reference(lr, gbuffer, sigma_depth, sigma_normal, sigma_albedo, radius):
    """The definition, one HR pixel and one LR neighbour at a time, in float64 numpy."""
    lr, gbuffer = lr.double().numpy(), gbuffer.double().numpy()
    n, c, h, w = lr.shape
    height, width = gbuffer.shape[-2:]
    out = np.zeros((n, c, height, width))
    for b in range(n):
        for y in range(height):
            v = (y + 0.5) * h / height - 0.5
            for x in range(width):
                u = (x + 0.5) * w / width - 0.5
                albedo, depth, normal = gbuffer[b, 0:3, y, x], gbuffer[b, 3, y, x], gbuffer[b, 4:7, y, x]
                acc, total = np.zeros(c), 0.0
                for jy in range(math.floor(v) - radius + 1, math.floor(v) + radius + 1):
                    for jx in range(math.floor(u) - radius + 1, math.floor(u) + radius + 1):
                        spatial = max(0.0, 1 - abs(v - jy) / radius) * max(0.0, 1 - abs(u - jx) / radius)
                        cy, cx = min(max(jy, 0), h - 1), min(max(jx, 0), w - 1)
                        # LR pixel i is the HR pixel floor((i + 0.5) H / h), in exact integer arithmetic.
                        py, px = ((2 * cy + 1) * height) // (2 * h), ((2 * cx + 1) * width) // (2 * w)
                        g = gbuffer[b, :, py, px]
                        exponent = (
                            (depth - g[3]) ** 2 / (2 * sigma_depth**2)
                            + (1 - normal @ g[4:7]) / sigma_normal
                            + ((albedo - g[0:3]) ** 2).sum() / (2 * sigma_albedo**2)
                        )
                        weight = spatial * (math.exp(-exponent) + FALLBACK_WEIGHT)
                        acc += weight * lr[b, :, cy, cx]
                        total += weight
                out[b, :, y, x] = acc / total
    return torch.from_numpy(out)


def random_gbuffer(n, height, width, generator, dtype=torch.float64):
    gbuffer = torch.rand(n, 11, height, width, generator=generator, dtype=dtype)
    gbuffer[:, 4:7] = F.normalize(gbuffer[:, 4:7] * 2 - 1, dim=1)  # unit normals, as the data has
    return gbuffer


def flat_gbuffer(n, height, width, dtype=torch.float64):
    gbuffer = torch.full((n, 11, height, width), 0.5, dtype=dtype)
    gbuffer[:, 4:7] = torch.tensor([0.0, 0.0, 1.0], dtype=dtype).view(1, 3, 1, 1)
    return gbuffer


def tent_matrix(hr: int, lr: int, radius: int) -> np.ndarray:
    """Row x: the normalised tent weights of the LR samples (border repeated), as a dense (hr, lr) matrix."""
    matrix = np.zeros((hr, lr))
    for x in range(hr):
        u = (x + 0.5) * lr / hr - 0.5
        for j in range(math.floor(u) - radius + 1, math.floor(u) + radius + 1):
            matrix[x, min(max(j, 0), lr - 1)] += max(0.0, 1 - abs(u - j) / radius)
    return matrix / matrix.sum(1, keepdims=True)


@pytest.mark.parametrize(
    "size, scale, radius, sigmas",
    [
        ((8, 10), 2.0, 2, (0.3, 1.0, 0.5)),
        ((7, 11), 2.5, 2, (0.2, 0.5, 0.4)),
        ((9, 9), 3.0, 1, (0.3, 1.0, 0.5)),
        ((6, 8), 2.0, 2, (0.01, 0.1, 0.1)),  # the defaults: mostly the spatial fallback on random guides
    ],
)
def test_matches_a_per_pixel_loop(size, scale, radius, sigmas):
    g = torch.Generator().manual_seed(1)
    h, w = lr_size(*size, scale)
    lr = torch.rand(2, 3, h, w, generator=g, dtype=torch.float64)
    gbuffer = random_gbuffer(2, *size, g)
    expected = loop_reference(lr, gbuffer, *sigmas, radius)
    kwargs = dict(zip(("sigma_depth", "sigma_normal", "sigma_albedo"), sigmas, strict=True))
    got = joint_bilateral_upsample(lr, gbuffer, radius=radius, **kwargs)
    torch.testing.assert_close(got, expected, rtol=1e-5, atol=1e-5)
    got32 = joint_bilateral_upsample(lr.float(), gbuffer.float(), radius=radius, **kwargs)
    assert got32.dtype == torch.float32
    torch.testing.assert_close(got32.double(), expected, rtol=1e-5, atol=1e-5)


def test_constant_irradiance_stays_constant():
    g = torch.Generator().manual_seed(2)
    lr = torch.full((1, 3, 5, 7), 0.37)
    out = joint_bilateral_upsample(lr, random_gbuffer(1, 13, 17, g, torch.float32))
    torch.testing.assert_close(out, torch.full((1, 3, 13, 17), 0.37))


@pytest.mark.parametrize("radius", [1, 2, 3])
def test_flat_guides_give_the_spatial_tent_interpolation(radius):
    g = torch.Generator().manual_seed(3)
    lr = torch.rand(1, 3, 5, 6, generator=g, dtype=torch.float64)
    out = joint_bilateral_upsample(lr, flat_gbuffer(1, 11, 15), radius=radius)
    rows, cols = torch.from_numpy(tent_matrix(11, 5, radius)), torch.from_numpy(tent_matrix(15, 6, radius))
    torch.testing.assert_close(out, rows @ lr @ cols.T)
    if radius == 1:  # a radius-1 tent is bilinear interpolation with cell centres aligned
        torch.testing.assert_close(out, F.interpolate(lr, size=(11, 15), mode="bilinear", align_corners=False))


def test_a_depth_edge_does_not_bleed():
    # Left half near (depth 0.2, value 1), right half far (depth 0.8, value 5); a vertical edge at HR column 8.
    height, width = 6, 16
    gbuffer = flat_gbuffer(1, height, width)
    gbuffer[:, 3, :, 8:] = 0.8
    gbuffer[:, 3, :, :8] = 0.2
    h, w = lr_size(height, width, 2.0)
    lr = torch.where(torch.arange(w) < w // 2, 1.0, 5.0).double().expand(1, 3, h, w)
    out = joint_bilateral_upsample(lr, gbuffer)
    torch.testing.assert_close(out[..., :8], torch.ones_like(out[..., :8]), rtol=0, atol=1e-4)
    torch.testing.assert_close(out[..., 8:], torch.full_like(out[..., 8:], 5.0), rtol=0, atol=1e-4)
    spatial = joint_bilateral_upsample(lr, flat_gbuffer(1, height, width))
    assert float(spatial[..., 7].min()) > 1.5  # without the guide, the edge pixels mix both sides


def test_scale_one_with_identical_guides_returns_the_input():
    g = torch.Generator().manual_seed(4)
    height, width = 7, 9
    gbuffer = random_gbuffer(1, height, width, g)
    # Every pixel's depth differs from its 8 neighbours' by >= 0.1 (a 2x2 pattern of 4 levels): only itself counts.
    y, x = torch.meshgrid(torch.arange(height), torch.arange(width), indexing="ij")
    gbuffer[:, 3] = 0.2 + 0.1 * (x % 2) + 0.2 * (y % 2)
    lr = torch.rand(1, 3, height, width, generator=g, dtype=torch.float64)
    torch.testing.assert_close(joint_bilateral_upsample(lr, gbuffer), lr, rtol=1e-5, atol=1e-5)


@pytest.mark.parametrize("scale", [1.0, 2.0, 3.0, 4.0, 2.5, 8.0])
@pytest.mark.parametrize("size", [(17, 23), (9, 31)])
def test_shapes_dtypes_and_gradients_at_any_scale(size, scale):
    g = torch.Generator().manual_seed(5)
    h, w = lr_size(*size, scale)
    for dtype in (torch.float32, torch.float64):
        lr = torch.rand(2, 3, h, w, generator=g, dtype=dtype).requires_grad_()
        gbuffer = random_gbuffer(2, *size, g, dtype).requires_grad_()
        out = joint_bilateral_upsample(lr, gbuffer, sigma_depth=1e-4)  # mostly the fallback: 0/0 must not occur
        assert out.shape == (2, 3, *size) and out.dtype == dtype and torch.isfinite(out).all()
        out.square().sum().backward()
        assert torch.isfinite(lr.grad).all() and torch.isfinite(gbuffer.grad).all() and lr.grad.abs().sum() > 0


def test_bad_arguments_are_refused():
    lr, gbuffer = torch.rand(1, 3, 4, 4), torch.rand(1, 11, 8, 8)
    with pytest.raises(ValueError, match="radius"):
        joint_bilateral_upsample(lr, gbuffer, radius=0)
    with pytest.raises(ValueError, match="positive"):
        joint_bilateral_upsample(lr, gbuffer, sigma_depth=0.0)


def test_baseline_runs_through_the_module_without_parameters():
    net_config = {"_target_": "wdss.nets.upsamplers.joint_bilateral.JointBilateralUpsample", "sigma_depth": 0.05}
    module = SuperResolutionModule(net_config, flip=False, trainable=False)
    assert not module.trainable and module.configure_optimizers() is None and module.temporal == "none"
    # It upsamples demodulated irradiance: the emission the data takes out of the LR comes back at HR.
    assert set(module.inputs) == {"lr", "gbuffer", "lr_guide", "lr_jitter", "brdf", "target", "emission"}
    data = batch(size=(15, 21), scale=3.0)
    out = module(data)
    expected = joint_bilateral_upsample(data["lr"], data["gbuffer"], sigma_depth=0.05) * data["brdf"]
    torch.testing.assert_close(out["color"], expected)
    assert out["coefficients"] is None and isinstance(module.net, JointBilateralUpsample)
    data["emission"] = torch.rand_like(data["brdf"])
    torch.testing.assert_close(module(data)["color"], expected + data["emission"])
    colour_space = SuperResolutionModule({**net_config, "demodulated": False}, flip=False, trainable=False)
    assert "emission" not in colour_space.inputs  # its LR colour holds the emission already


def test_the_colour_space_variant_filters_the_lr_colour():
    """``demodulated=False``: joint bilateral upsampling of the LR colour, returned as irradiance of the HR F so
    that the module's remodulation gives that colour back; through the module, on the batch keys it names."""
    torch.manual_seed(0)
    data = batch(size=(15, 21), scale=3.0)
    model = JointBilateralUpsample(demodulated=False)
    assert model.inputs == ("lr_color", "gbuffer", "brdf", "lr_guide", "lr_jitter")
    out = model(gbuffer=data["gbuffer"], lr_color=data["lr_color"], brdf=data["brdf"])["irradiance"]
    torch.testing.assert_close(out * data["brdf"], joint_bilateral_upsample(data["lr_color"], data["gbuffer"]))
    with pytest.raises(ValueError, match="demodulated=false needs lr_color and the HR brdf"):
        model(gbuffer=data["gbuffer"], lr_color=data["lr_color"])
    assert JointBilateralUpsample().inputs == ("lr", "gbuffer", "lr_guide", "lr_jitter")  # demodulated: no F
    module = SuperResolutionModule(
        {"_target_": "wdss.nets.upsamplers.joint_bilateral.JointBilateralUpsample", "demodulated": False}
    )
    assert {"lr_color", "brdf"} <= set(module.inputs) and "lr" not in module.inputs
    colour = module({k: v for k, v in data.items() if k != "lr"})["color"]
    torch.testing.assert_close(colour, joint_bilateral_upsample(data["lr_color"], data["gbuffer"]))
