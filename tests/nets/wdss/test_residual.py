"""Options that make the network learn at small scale: a residual over an upsampled LR irradiance, a log1p
output space, loss spaces, and the masked L1 as a mean over the mask."""

from __future__ import annotations

import pytest
import torch
import torch.nn.functional as F

from tests.helpers import TINY, batch, head, upsampler
from wdss.nets.upsamplers.joint_bilateral import joint_bilateral_upsample
from wdss.nets.wdss.network import WDSSNet
from wdss.ops.tonemap import ToneMap, hable
from wdss.training.losses import WDSSLoss


def net(transform="swt", basis="db4", head_name="shared_inr", residual="none", tap_brdf=False, **kwargs):
    """A tiny network without a temporal branch; ``residual``: the residual group's option (``tap_brdf``: the learned
    kernel's option, which does nothing for another)."""
    kernel = upsampler(residual, tap_brdf=tap_brdf) if residual == "learned_bilateral" else upsampler(residual)
    return WDSSNet(transform, basis, head(head_name), temporal=False, upsampler=kernel, **TINY, **kwargs)


def forward(model, data):
    return model(lr=data["lr"], gbuffer=data["gbuffer"], spatial_mask=data["spatial_mask"], scale=data["scale"])


@pytest.mark.parametrize("transform,basis,head", [("none", "haar", "shared_inr"), ("dwt", "haar", "shared_inr"),
                                                  ("swt", "db4", "shared_inr"), ("swt", "sym4", "fusion_ll"),
                                                  ("dwt", "db4", "multi_inr")])  # fmt: skip
@pytest.mark.parametrize("space", ["linear", "log"])
@pytest.mark.parametrize("size,scale", [((16, 20), 2.0), ((15, 21), 3.0), ((17, 13), 2.5)])
def test_a_residual_network_starts_as_its_upsampler(transform, basis, head, space, size, scale):
    torch.manual_seed(0)
    data = batch(size=size, scale=scale)
    bilinear = F.interpolate(data["lr"], size=size, mode="bilinear", align_corners=False)
    joint = joint_bilateral_upsample(data["lr"], data["gbuffer"])
    for residual, expected in (("bilinear", bilinear), ("joint_bilateral", joint), ("learned_bilateral", joint)):
        for residual_input in (False, True):  # seeing the upsampled irradiance changes nothing at the start
            model = net(transform, basis, head, output_space=space, residual=residual, residual_input=residual_input)
            out = forward(model, data)
            torch.testing.assert_close(out["irradiance"], expected.clamp_min(0), atol=2e-5, rtol=2e-5)


def test_the_upsampled_irradiance_reaches_the_network_when_asked():
    torch.manual_seed(0)
    data = batch(size=(16, 20))
    plain = net(residual="joint_bilateral", exit_init=1.0)
    seeing = net(residual="joint_bilateral", exit_init=1.0, residual_input=True)
    # Three more input channels (per phase of the unshuffled G-buffer stack) and nothing else.
    assert seeing.gbuffer.body[0].in_channels == plain.gbuffer.body[0].in_channels + 4 * 3
    seen = []
    seeing.gbuffer.register_forward_hook(lambda module, args, out: seen.append(args[0]))
    forward(seeing, data)
    last = F.pixel_shuffle(seen[0], 2)[:, -3:]  # the G-buffer stack's last channels, back on the HR grid
    expected = torch.log1p(joint_bilateral_upsample(data["lr"], data["gbuffer"]))  # as the LR input: log1p
    torch.testing.assert_close(last, expected, atol=1e-5, rtol=1e-5)
    with pytest.raises(ValueError, match="residual_input"):
        net(residual="none", residual_input=True)


@pytest.mark.parametrize("transform", ["dwt", "swt"])
@pytest.mark.parametrize("space", ["linear", "log"])
def test_target_coefficients_are_the_analysis_the_head_predicts(transform, space):
    """The wavelet loss term compares like with like: a network that outputs exactly the target's coefficients
    reproduces the target, in either output space, also for odd sizes (padded as the head pads)."""
    torch.manual_seed(0)
    data = batch(size=(15, 21))
    model = net(transform, "db4", output_space=space, residual="bilinear")
    target = data["target"] / data["brdf"]
    coefficients = model.target_coefficients(target)
    out = forward(model, data)
    assert coefficients.shape == out["coefficients"].shape
    # Zero exit: the prediction is the analysis of the upsampled LR, i.e. target_coefficients of it.
    upsampled = F.interpolate(data["lr"], size=(15, 21), mode="bilinear", align_corners=False)
    torch.testing.assert_close(out["coefficients"], model.target_coefficients(upsampled), atol=1e-5, rtol=1e-5)
    assert not torch.allclose(coefficients, out["coefficients"])


def test_the_residual_correction_is_learned():
    """With the exit initialised to zero the gradient still reaches every layer after one step."""
    torch.manual_seed(0)
    data = batch(size=(16, 16))
    # A target the G-buffer explains: the upsampled LR irradiance modulated by a G-buffer channel.
    upsampled = F.interpolate(data["lr"], size=(16, 16), mode="bilinear", align_corners=False)
    data["target"] = upsampled * (0.25 + data["gbuffer"][:, 3:4]) * data["brdf"]
    model = net("swt", "haar", output_space="log", residual="bilinear")
    optimizer = torch.optim.Adam(model.parameters(), lr=3e-3)
    criterion = WDSSLoss({"l1": 1.0, "wavelet": 0.01}, space="tonemapped")
    losses = []
    for _ in range(80):
        out = forward(model, data)
        terms = criterion(
            out["irradiance"] * data["brdf"],
            data["target"],
            coefficients=out["coefficients"],
            target_coefficients=model.target_coefficients(data["target"] / data["brdf"]),
        )
        optimizer.zero_grad()
        terms["total"].backward()
        optimizer.step()
        losses.append(float(terms["total"].detach()))
    assert losses[-1] < 0.5 * losses[0]
    assert model.lr.body[0].weight.grad.abs().sum() > 0


def test_loss_spaces_map_every_image_term():
    torch.manual_seed(0)
    output, target = torch.rand(2, 3, 24, 24) * 4, torch.rand(2, 3, 24, 24) * 4
    tone = ToneMap("hable")
    terms = WDSSLoss({"l1": 1.0}, space="tonemapped", tone=tone)(output, target)
    torch.testing.assert_close(terms["l1"], (hable(output) - hable(target)).abs().mean())
    terms = WDSSLoss({"l1": 1.0}, space="log")(output, target)
    torch.testing.assert_close(terms["l1"], (torch.log1p(output) - torch.log1p(target)).abs().mean())
    # The temporal term is mapped too: identical changes in linear space need not be identical tone-mapped.
    warped = (output * 0.5, target * 0.5)
    terms = WDSSLoss({"temporal": 1.0}, space="tonemapped")(output, target, temporal=warped)
    expected = ((hable(output) - hable(warped[0])) - (hable(target) - hable(warped[1]))).abs().mean()
    torch.testing.assert_close(terms["temporal"], expected)
    with pytest.raises(ValueError, match="loss.space"):
        WDSSLoss({"l1": 1.0}, space="srgb")


def test_l2_is_the_mean_squared_error_in_the_loss_space():
    torch.manual_seed(0)
    output, target = torch.rand(2, 3, 8, 8) * 4, torch.rand(2, 3, 8, 8) * 4
    for space, f in (("linear", lambda x: x), ("log", torch.log1p), ("tonemapped", hable)):
        terms = WDSSLoss({"l2": 2.0}, space=space)(output, target)
        torch.testing.assert_close(terms["l2"], ((f(output) - f(target)) ** 2).mean())
        torch.testing.assert_close(terms["total"], 2.0 * terms["l2"])


def test_masked_l1_is_a_mean_over_the_mask():
    output, target = torch.zeros(1, 3, 8, 8), torch.zeros(1, 3, 8, 8)
    mask = torch.zeros(1, 1, 8, 8)
    mask[..., :2, :2] = 1  # 4 pixels of 64
    output[..., :2, :2] = 0.5  # an error of 0.5 on each of them
    output[..., 4:, 4:] = 9.0  # errors outside the mask do not count
    terms = WDSSLoss({"masked_l1": 1.0})(output, target, spatial_mask=mask)
    torch.testing.assert_close(terms["masked_l1"], torch.tensor(0.5))
    assert float(WDSSLoss({"masked_l1": 1.0})(output, target, spatial_mask=mask * 0)["masked_l1"]) == 0.0


def test_auto_exposure_makes_metrics_independent_of_the_data_exposure():
    """'auto' tone-maps each image at an exposure from its target's median, so scaling the radiance of both the
    prediction and the target (a foreign dataset's arbitrary exposure) changes nothing."""
    torch.manual_seed(0)
    target = torch.rand(2, 3, 16, 16) * 3
    output = target * (1 + 0.2 * torch.randn_like(target)).clamp_min(0)
    tone = ToneMap("hable", "auto")
    for k in (0.01, 1.0, 50.0):
        torch.testing.assert_close(tone(output * k, target * k), tone(output, target), atol=1e-5, rtol=1e-5)
    # the median luminance lands on middle grey: Hable at exposure 10 maps 0.18 to ~0.46
    grey = torch.full((1, 3, 4, 4), 7.0)
    assert abs(float(tone(grey, grey).mean()) - float(hable(torch.tensor(0.18)))) < 1e-5
    with pytest.raises(ValueError, match="exposure"):
        ToneMap("hable", "bright")


def test_the_learned_kernel_with_tap_brdf_is_the_residual_base_and_is_fed_the_brdf():
    torch.manual_seed(0)
    data = batch(size=(16, 20))
    model = net(residual="learned_bilateral", output_space="log", tap_brdf=True)
    assert {"brdf", "lr_brdf"} <= set(model.inputs) and model.upsampler.tap_brdf
    lr_brdf = F.interpolate(data["brdf"], size=data["lr"].shape[-2:], mode="nearest-exact")  # as data/mini's LR
    out = model(
        lr=data["lr"],
        gbuffer=data["gbuffer"],
        spatial_mask=data["spatial_mask"],
        scale=data["scale"],
        brdf=data["brdf"],
        lr_brdf=lr_brdf,
    )
    expected = joint_bilateral_upsample(data["lr"], data["gbuffer"])  # exponent 0 and a zero exit at the start
    torch.testing.assert_close(out["irradiance"], expected, atol=2e-5, rtol=2e-5)
    assert "brdf" not in net(residual="joint_bilateral", tap_brdf=True).inputs  # the learned kernel's option only


def test_the_cpu_experiment_turns_tap_brdf_on_for_the_learned_kernel():
    from tests.test_train import compose_train

    kernel = compose_train(["variant=swt_db4", "experiment=cpu"]).model.net.upsampler  # the residual group's
    assert kernel._target_.endswith(".LearnedBilateralUpsample") and kernel.tap_brdf is True
    assert kernel.raise_within_albedo is True and kernel.never_raise is False
    assert compose_train(["variant=swt_db4", "residual=learned_bilateral"]).model.net.upsampler.tap_brdf is False
    assert compose_train(["variant=swt_db4"]).model.net.upsampler is None  # the paper's: no residual
    assert compose_train(["variant=learned_bilateral", "experiment=cpu"]).model.net.tap_brdf is True
    assert compose_train(["variant=learned_bilateral"]).model.net.tap_brdf is False
    colour = compose_train(["variant=joint_bilateral_color", "experiment=cpu"]).model.net
    assert colour.demodulated is False


@pytest.mark.parametrize("transform,space", [("swt", "log"), ("dwt", "linear"), ("none", "log")])
def test_a_full_resolution_refinement_starts_at_zero_and_learns_from_the_first_step(transform, space):
    """recipe.refine_width: the network with the refinement starts exactly as without it (its last layer is zero),
    and one step of the loss already moves that last layer, while the head's zero exit stays behind it."""
    torch.manual_seed(0)
    data = batch(size=(15, 21), scale=3.0)
    torch.manual_seed(1)
    plain = net(transform, "haar", output_space=space, residual="bilinear")
    torch.manual_seed(1)
    refined = net(transform, "haar", output_space=space, residual="bilinear", refine_width=8)
    torch.testing.assert_close(forward(refined, data)["irradiance"], forward(plain, data)["irradiance"])
    # Its input: log1p of the image, the G-buffer stack and the spatial mask, at full resolution.
    assert refined.refine.body[0].in_channels == 3 + data["gbuffer"].shape[1] + 1
    out = forward(refined, data)
    (out["irradiance"] - data["target"] / data["brdf"]).abs().mean().backward()
    assert refined.refine.body[-1].weight.grad.abs().sum() > 0
    assert refined.refine.body[0].weight.grad.abs().sum() == 0  # behind the zero last layer until it moves
    with pytest.raises(ValueError, match="refine_width"):
        net(refine_width=-1)
    assert net().refine is None  # off by default: the paper's network


def test_the_cpu_experiment_composes_the_refinement_option():
    from tests.test_train import compose_train

    assert compose_train(["experiment=cpu", "recipe.refine_width=16"]).model.net.refine_width == 16
    assert compose_train(["variant=swt_db4"]).model.net.refine_width == 0
