"""Learned joint bilateral upsampling: starts as joint bilateral, stays a convex combination, learns a kernel."""

from __future__ import annotations

import pytest
import torch
import torch.nn.functional as F

from tests.helpers import batch
from wdss.nets.upsamplers.joint_bilateral import joint_bilateral_upsample
from wdss.nets.upsamplers.learned_bilateral import LearnedBilateralUpsample
from wdss.ops.sampling import lr_size, point_sample


def _randomise(model: LearnedBilateralUpsample, seed: int = 1) -> LearnedBilateralUpsample:
    """The same module with a non-zero last MLP layer: a kernel far from joint bilateral."""
    g = torch.Generator().manual_seed(seed)
    with torch.no_grad():
        last = model.mlp[-1]
        last.weight.copy_(torch.randn(last.weight.shape, generator=g))
        last.bias.copy_(torch.randn(last.bias.shape, generator=g))
    return model


@pytest.mark.parametrize("size,scale", [((16, 20), 2.0), ((15, 21), 3.0), ((17, 13), 2.5), ((24, 24), 4.0)])
@pytest.mark.parametrize("context", [8, 0])
def test_it_starts_as_joint_bilateral_upsampling(size, scale, context):
    torch.manual_seed(0)
    data = batch(size=size, scale=scale)
    model = LearnedBilateralUpsample(context=context)
    out = model(data["lr"], data["gbuffer"])
    assert out["coefficients"] is None
    torch.testing.assert_close(
        out["irradiance"], joint_bilateral_upsample(data["lr"], data["gbuffer"]), atol=1e-5, rtol=1e-5
    )


def test_any_kernel_is_a_convex_combination_of_the_neighbours():
    """Whatever the MLP predicts: a constant LR frame stays constant, and no value leaves the LR range."""
    torch.manual_seed(0)
    data = batch(size=(18, 22), scale=3.0)
    model = _randomise(LearnedBilateralUpsample())
    constant = torch.full_like(data["lr"], 0.7)
    torch.testing.assert_close(model(constant, data["gbuffer"])["irradiance"], torch.full((2, 3, 18, 22), 0.7))
    out = model(data["lr"], data["gbuffer"])["irradiance"]
    assert torch.isfinite(out).all()
    assert (out >= data["lr"].amin() - 1e-6).all() and (out <= data["lr"].amax() + 1e-6).all()
    assert not torch.allclose(out, joint_bilateral_upsample(data["lr"], data["gbuffer"]), atol=1e-3)


@pytest.mark.parametrize("context", [0, 8])
def test_the_gradient_reaches_every_parameter_after_one_step(context):
    torch.manual_seed(0)
    data = batch(size=(16, 16))
    model = LearnedBilateralUpsample(context=context)
    optimizer = torch.optim.Adam(model.parameters(), lr=1e-2)
    for step in range(2):
        optimizer.zero_grad()
        loss = (model(data["lr"], data["gbuffer"])["irradiance"] - data["target"] / data["brdf"]).abs().mean()
        loss.backward()
        if step == 1:  # the zero last layer moved in step 0, so now every layer before it has a gradient
            for name, parameter in model.named_parameters():
                assert parameter.grad is not None and parameter.grad.abs().sum() > 0, name
        optimizer.step()


@pytest.mark.parametrize("raise_within_albedo", [False, True])
def test_it_learns_an_edge_the_fixed_kernel_blurs(raise_within_albedo):
    """Two surfaces whose albedos differ by less than the fixed albedo range (sigma 0.1) but whose irradiance
    differs by 4x: joint bilateral upsampling mixes them at the edge, a learned kernel separates them (lowering
    the weights of the other side's taps, or raising its own side's: raise_within_albedo learns it too). Not
    never_raise: its correction starts at the cap, and once every output of the zero-initialised last layer has
    moved above it no gradient reaches the kernel (whether that happens here depends on the thread count)."""
    torch.manual_seed(0)
    n, height, width, scale = 4, 32, 32, 2.0
    g = torch.Generator().manual_seed(0)
    gbuffer = torch.zeros(n, 11, height, width)
    gbuffer[:, 3] = 0.5  # one depth, one normal: only albedo tells the surfaces apart
    gbuffer[:, 6] = 1.0
    irradiance = torch.zeros(n, 3, height, width)
    for i in range(n):  # a vertical edge at a random column, a different one per image
        edge = int(torch.randint(8, 24, (1,), generator=g))
        gbuffer[i, :3, :, edge:] = 0.05
        irradiance[i, :, :, :edge], irradiance[i, :, :, edge:] = 0.5, 2.0
    lr = point_sample(irradiance, lr_size(height, width, scale))
    model = LearnedBilateralUpsample(raise_within_albedo=raise_within_albedo)

    def error() -> float:
        with torch.no_grad():
            return float((model(lr, gbuffer)["irradiance"] - irradiance).abs().mean())

    before = error()
    assert before == pytest.approx(float((joint_bilateral_upsample(lr, gbuffer) - irradiance).abs().mean()), rel=1e-5)
    optimizer = torch.optim.Adam(model.parameters(), lr=1e-2)
    for _ in range(60):
        optimizer.zero_grad()
        F.l1_loss(model(lr, gbuffer)["irradiance"], irradiance).backward()
        optimizer.step()
    assert error() < 0.3 * before


def test_bad_arguments_are_refused():
    with pytest.raises(ValueError, match="hidden"):
        LearnedBilateralUpsample(hidden=0)
    with pytest.raises(ValueError, match="radius"):
        LearnedBilateralUpsample(radius=0)
    with pytest.raises(ValueError, match="sigma"):
        LearnedBilateralUpsample(sigma_depth=0.0)


# ------------------------------------------------------------------------------------------ tap_brdf


def _exponent_one(model: LearnedBilateralUpsample) -> LearnedBilateralUpsample:
    """Every tap's BRDF exponent at 1 (its logit correction still 0): the colour-space kernel."""
    with torch.no_grad():
        model.mlp[-1].bias[1] = 5.0  # clamped to 1
    return model


@pytest.mark.parametrize("size,scale", [((16, 20), 2.0), ((15, 21), 3.0), ((17, 13), 2.5)])
def test_with_tap_brdf_it_starts_as_joint_bilateral_and_spans_the_colour_space_kernel(size, scale):
    """Exponent 0 (the start) is demodulated joint bilateral upsampling; exponent 1 filters each tap's colour
    (irradiance times its own F) and returns it unchanged after remodulation, as
    ``JointBilateralUpsample(demodulated=False)`` does."""
    torch.manual_seed(0)
    data = batch(size=size, scale=scale)
    model = LearnedBilateralUpsample(tap_brdf=True)
    assert model.inputs == ("lr", "gbuffer", "lr_guide", "lr_jitter", "brdf", "lr_brdf")
    f = dict(brdf=data["brdf"], lr_brdf=point_sample(data["brdf"], data["lr"].shape[-2:]))  # as data/mini's LR
    start = model(data["lr"], data["gbuffer"], **f)["irradiance"]
    torch.testing.assert_close(start, joint_bilateral_upsample(data["lr"], data["gbuffer"]), atol=1e-5, rtol=1e-5)
    colour = _exponent_one(model)(data["lr"], data["gbuffer"], **f)["irradiance"] * data["brdf"]
    torch.testing.assert_close(
        colour, joint_bilateral_upsample(data["lr_color"], data["gbuffer"]), atol=1e-5, rtol=1e-5
    )
    with pytest.raises(ValueError, match="tap_brdf=true: it needs the HR brdf and the lr_brdf"):
        model(data["lr"], data["gbuffer"], brdf=data["brdf"])


def test_the_brdf_exponent_is_learned_where_the_target_does_not_follow_the_hr_brdf():
    """A target whose colour is smooth while the HR BRDF factor carries fine texture (as a denoiser or a shading
    model that is not albedo times irradiance leaves it): demodulated upsampling paints the texture on, the learned
    exponent learns to carry the taps' colour through instead."""
    torch.manual_seed(0)
    n, height, width, scale = 4, 32, 32, 2.0
    g = torch.Generator().manual_seed(0)
    gbuffer = torch.rand(n, 11, height, width, generator=g)
    brdf = 0.2 + 0.8 * torch.rand(n, 3, height, width, generator=g)
    colour = torch.full((n, 3, height, width), 0.6)
    lr_brdf = point_sample(brdf, lr_size(height, width, scale))
    lr = point_sample(colour, lr_size(height, width, scale)) / lr_brdf  # the data's demodulation at the LR pixels
    model = LearnedBilateralUpsample(tap_brdf=True)

    def error() -> float:
        with torch.no_grad():
            return float((model(lr, gbuffer, brdf=brdf, lr_brdf=lr_brdf)["irradiance"] * brdf - colour).abs().mean())

    before = error()
    assert before > 0.05
    optimizer = torch.optim.Adam(model.parameters(), lr=1e-2)
    for _ in range(60):
        optimizer.zero_grad()
        F.l1_loss(model(lr, gbuffer, brdf=brdf, lr_brdf=lr_brdf)["irradiance"] * brdf, colour).backward()
        optimizer.step()
    assert error() < 0.2 * before
    without = LearnedBilateralUpsample()  # the logits alone cannot: every tap carries the wrong texture
    optimizer = torch.optim.Adam(without.parameters(), lr=1e-2)
    for _ in range(60):
        optimizer.zero_grad()
        F.l1_loss(without(lr, gbuffer)["irradiance"] * brdf, colour).backward()
        optimizer.step()
    with torch.no_grad():
        assert float((without(lr, gbuffer)["irradiance"] * brdf - colour).abs().mean()) > 0.5 * before


def test_with_tap_brdf_the_gradient_reaches_every_parameter():
    torch.manual_seed(0)
    data = batch(size=(16, 16))
    model = LearnedBilateralUpsample(tap_brdf=True)
    optimizer = torch.optim.Adam(model.parameters(), lr=1e-2)
    for step in range(2):
        optimizer.zero_grad()
        lr_brdf = point_sample(data["brdf"], data["lr"].shape[-2:])
        out = model(data["lr"], data["gbuffer"], brdf=data["brdf"], lr_brdf=lr_brdf)["irradiance"]
        (out * data["brdf"] - data["target"].roll(1, -1)).abs().mean().backward()
        if step == 1:
            for name, parameter in model.named_parameters():
                assert parameter.grad is not None and parameter.grad.abs().sum() > 0, name
        optimizer.step()


def test_never_raise_ignores_every_correction_that_would_raise_a_tap_above_joint_bilateral():
    """never_raise caps the logit correction at 0: an MLP whose corrections are all positive (each tap raised by its
    own amount) leaves joint bilateral upsampling exactly as it is; without the cap the same MLP changes it."""
    torch.manual_seed(0)
    data = batch(size=(18, 22), scale=3.0)
    fixed = joint_bilateral_upsample(data["lr"], data["gbuffer"])
    outputs = []
    for never_raise in (True, False):
        model = LearnedBilateralUpsample(never_raise=never_raise)
        with torch.no_grad():  # positive corrections that differ per tap: small weights, a large bias
            model.mlp[-1].weight.normal_(0.0, 0.05, generator=torch.Generator().manual_seed(1))
            model.mlp[-1].bias.fill_(5.0)
        outputs.append(model(data["lr"], data["gbuffer"])["irradiance"])
    torch.testing.assert_close(outputs[0], fixed, atol=1e-5, rtol=1e-5)
    assert not torch.allclose(outputs[1], fixed, atol=1e-4)


def test_checkpoints_of_kernels_that_raised_taps_load_as_they_were_trained():
    """never_raise and raise_within_albedo are off unless a config turns one on (every config does since they exist):
    a checkpoint whose stored network config predates them builds the kernel it was trained as; today's configs
    raise only within one albedo."""
    from tests.test_train import compose_train

    plain = LearnedBilateralUpsample()
    assert not plain.never_raise and not plain.raise_within_albedo
    from wdss.config.targets import instantiate

    for variant in ("swt_db4", "learned_bilateral"):
        net = instantiate(compose_train([f"variant={variant}", "experiment=cpu"]).model.net)
        kernel = getattr(net, "upsampler", None) or net
        assert kernel.raise_within_albedo and not kernel.never_raise


def test_never_raise_and_raise_within_albedo_exclude_each_other():
    with pytest.raises(ValueError, match="never_raise and raise_within_albedo"):
        LearnedBilateralUpsample(never_raise=True, raise_within_albedo=True)


def test_a_raise_never_carries_a_tap_across_an_albedo_edge():
    """Two surfaces of very different albedo whose demodulated irradiance differs (as it does where demodulation
    is inexact). Raising every tap by the same logit changes nothing without the gate (a softmax is blind to a
    common shift); with raise_within_albedo only the taps of the pixel's own albedo are raised, so the pixels by
    the edge take less of the other side than joint bilateral does, never more, and pixels away from it are
    unchanged."""
    height, width, scale, edge = 24, 24, 2.0, 12
    gbuffer = torch.zeros(1, 11, height, width)
    gbuffer[:, 3], gbuffer[:, 6] = 0.5, 1.0  # one depth, one normal
    gbuffer[:, :3, :, :edge], gbuffer[:, :3, :, edge:] = 0.5, 0.42  # within the albedo range: JBU mixes the sides
    irradiance = torch.zeros(1, 3, height, width)
    irradiance[..., :edge], irradiance[..., edge:] = 1.0, 3.0
    lr = point_sample(irradiance, lr_size(height, width, scale))
    fixed = joint_bilateral_upsample(lr, gbuffer)
    outputs = {}
    for gated in (False, True):
        model = LearnedBilateralUpsample(raise_within_albedo=gated)
        with torch.no_grad():  # the same positive correction for every tap
            model.mlp[-1].bias.fill_(4.0)
        outputs[gated] = model(lr, gbuffer)["irradiance"]
    torch.testing.assert_close(outputs[False], fixed, atol=1e-5, rtol=1e-5)
    mixing = lambda out: (out - irradiance).abs()  # noqa: E731  (how much of the other side a pixel took)
    assert float(mixing(fixed).max()) > 0.05  # joint bilateral mixes the two sides at the edge
    assert bool((mixing(outputs[True]) <= mixing(fixed) + 1e-5).all())
    assert float(mixing(outputs[True]).max()) < 0.2 * float(mixing(fixed).max())
    torch.testing.assert_close(outputs[True][..., :4], fixed[..., :4])  # away from the edge: as joint bilateral
