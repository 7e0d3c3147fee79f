"""Comparison models: DFASR and Real-ESRGAN's RRDBNet through the same module, data and tracking."""

from __future__ import annotations

import pytest
import torch

from tests.helpers import batch, losses_over_steps
from wdss.nets.comparison.rrdbnet import RRDBNet
from wdss.training.module import SuperResolutionModule

DFASR = {
    "_target_": "wdss.nets.wdss.network.WDSSNet", "transform": "none", "lr_unshuffle": False,
    "gbuffer_channels": [3, 4, 5, 6, 0, 1, 2], "fusion_final_relu": True, "phase_bias": False, "final_relu": False,
}  # fmt: skip
TINY_DFASR = {
    **DFASR,
    "lr_widths": [8, 8, 8, 8],
    "gbuffer_width": 8,
    "temporal_widths": [8, 4],
    "fusion_widths": [8],
    "inr_width": 8,
    "mlp_width": 8,
    "mlp_depth": 1,
}
TINY_RRDB = {"_target_": "wdss.nets.comparison.rrdbnet.RRDBNet", "num_feat": 8, "num_block": 1, "num_grow_ch": 4}


def test_dfasr_has_its_published_size_and_inputs():
    module = SuperResolutionModule(DFASR, flip=False, temporal="recurrent")
    assert 0.52e6 < sum(p.numel() for p in module.net.parameters()) < 0.54e6  # ~0.53 M
    assert module.net.gbuffer.body[0].in_channels == 32  # 8 G-buffer channels, unshuffled
    assert module.net.lr.body[0].in_channels == 3  # the LR branch sees the full LR grid
    assert "motion" in module.inputs and "history" not in module.inputs  # its own warped output is the history


@pytest.mark.parametrize("scale, size", [(2.0, (16, 20)), (3.0, (18, 27)), (2.37, (19, 23))])
def test_dfasr_shapes_at_any_scale(scale, size):
    module = SuperResolutionModule(TINY_DFASR, flip=False)
    out = module(batch(size=size, scale=scale))
    assert out["color"].shape == (2, 3, *size) and torch.isfinite(out["color"]).all()


def test_real_esrgan_has_its_published_size():
    assert 16.6e6 < sum(p.numel() for p in RRDBNet().parameters()) < 16.8e6  # ~16.7 M


@pytest.mark.parametrize(
    "native, scale, size", [(4, 4.0, (24, 32)), (2, 2.0, (16, 20)), (4, 3.0, (18, 27)), (2, 2.5, (15, 25))]
)
def test_real_esrgan_shapes_native_and_resized(native, scale, size):
    module = SuperResolutionModule({**TINY_RRDB, "scale": native}, flip=False).eval()
    out = module(batch(size=size, scale=scale))
    assert out["display"].shape == (2, 3, *size) and out["color"] is None
    assert float(out["display"].min()) >= 0 and float(out["display"].max()) <= 1
    values = module.metrics.display(out["display"], batch(size=size, scale=scale)["target"])
    assert set(values) == {"psnr", "ssim"}


@pytest.mark.parametrize("net, temporal", [(TINY_DFASR, "gt_history"), (TINY_RRDB, None)], ids=["dfasr", "rrdbnet"])
def test_one_step_lowers_the_loss(net, temporal):
    torch.manual_seed(0)
    module = SuperResolutionModule(
        net,
        {"l1": 1.0, "ssim": 0.4},
        flip=False,
        temporal=temporal,
        optimizer={"_target_": "torch.optim.Adam", "_partial_": True, "lr": 1e-3},
    )
    data = batch(size=(16, 16))
    losses = losses_over_steps(module, data)
    assert losses[1] < losses[0]


def test_real_esrgan_loads_published_weight_layouts(tmp_path):
    reference = RRDBNet(num_feat=8, num_block=1, num_grow_ch=4)
    torch.save({"params_ema": reference.state_dict()}, tmp_path / "RealESRGAN_tiny.pth")
    loaded = RRDBNet(num_feat=8, num_block=1, num_grow_ch=4, weights=str(tmp_path / "RealESRGAN_tiny.pth"))
    assert not loaded.needs_training and reference.needs_training
    data = batch()
    loaded.eval()
    reference.eval()
    torch.testing.assert_close(
        loaded(data["lr_color"], data["brdf"])["display"], reference(data["lr_color"], data["brdf"])["display"]
    )
    with pytest.raises(FileNotFoundError, match="is not a file"):
        RRDBNet(weights="/nowhere/RealESRGAN_x4plus.pth")


def rendering_batch(scale: float, size: tuple[int, int]) -> dict:
    data = batch(size=size, scale=scale)
    n, (h, w) = 2, data["lr"].shape[-2:]
    data.update(
        lr_gbuffer=torch.rand(n, 4, h, w),
        prev_lr_color=torch.rand(n, 3, h, w),
        prev_lr_gbuffer=torch.rand(n, 4, h, w),
        motion=torch.zeros(n, 2, *size),
        history2=torch.rand(n, 3, *size),
    )
    return data


TINY_NSRR = {"_target_": "wdss.nets.comparison.nsrr.NSRR", "widths": [8, 4], "unet": [8, 16], "reweight_width": 8}
TINY_FUSESR = {"_target_": "wdss.nets.comparison.fusesr.FuseSR", "scale": 3, "width": 8, "blocks": 1}


@pytest.mark.parametrize("scale, size", [(2.0, (16, 20)), (3.0, (18, 27)), (2.37, (19, 23))])
def test_nsrr_shapes_at_any_scale(scale, size):
    out = SuperResolutionModule(TINY_NSRR, flip=False)(rendering_batch(scale, size))
    assert out["color"].shape == (2, 3, *size) and torch.isfinite(out["color"]).all()


def test_fusesr_is_a_fixed_integer_scale_method():
    module = SuperResolutionModule(TINY_FUSESR, flip=False)
    assert module(rendering_batch(3.0, (18, 27)))["color"].shape == (2, 3, 18, 27)
    with pytest.raises(ValueError, match="this FuseSR upsamples by 3"):
        module(rendering_batch(2.0, (16, 20)))
    from hydra.errors import InstantiationException

    with pytest.raises(InstantiationException, match="FuseSR needs an integer scale >= 2"):
        SuperResolutionModule({**TINY_FUSESR, "scale": 2.5}, flip=False)


@pytest.mark.parametrize("net, scale", [(TINY_NSRR, 2.0), (TINY_FUSESR, 3.0)], ids=["nsrr", "fusesr"])
def test_rendering_methods_learn(net, scale):
    torch.manual_seed(0)
    module = SuperResolutionModule(
        net, {"l1": 1.0}, flip=False, optimizer={"_target_": "torch.optim.Adam", "_partial_": True, "lr": 1e-3}
    )
    data = rendering_batch(scale, (18, 18) if scale == 3.0 else (16, 16))
    losses = losses_over_steps(module, data)
    assert losses[1] < losses[0]


BASELINE_OF_SKIP = {
    "nsrr": (TINY_NSRR, 2.0, (16, 20), {"_target_": "wdss.nets.upsamplers.baselines.Upsample", "mode": "bilinear"}),
    "fusesr": (
        TINY_FUSESR,
        3.0,
        (18, 27),
        {"_target_": "wdss.nets.upsamplers.baselines.Upsample", "mode": "bilinear", "demodulated": True},
    ),
}  # the parameter-free upsampling each network's skip adds to: NSRR bilinear colour, FuseSR bilinear irradiance


@pytest.mark.parametrize("name", sorted(BASELINE_OF_SKIP))
def test_skip_starts_near_its_upsampling_and_is_exactly_it_without_a_correction(name):
    net, scale, size, upsampler = BASELINE_OF_SKIP[name]
    data = rendering_batch(scale, size)
    expected = SuperResolutionModule(upsampler, flip=False)(data)["color"]
    torch.manual_seed(0)
    module = SuperResolutionModule({**net, "skip": True}, flip=False)
    near = module(data)["color"]
    # The exit is shrunk, not zeroed: the start is within a few per cent of the upsampling, and gradients flow.
    assert float((torch.log1p(near) - torch.log1p(expected)).abs().mean()) < 0.05
    assert (
        float((torch.log1p(SuperResolutionModule(net, flip=False)(data)["color"]) - torch.log1p(expected)).abs().mean())
        > 0.2
    )
    exit_conv = module.net.out if name == "nsrr" else module.net.up
    torch.nn.init.zeros_(exit_conv.weight)
    torch.testing.assert_close(module(data)["color"], expected, rtol=1e-4, atol=1e-5)
    # The skip adds no parameter: checkpoints of both settings load into either.
    assert module.net.state_dict().keys() == SuperResolutionModule(net, flip=False).net.state_dict().keys()


def test_real_esrgan_skip_starts_at_bicubic_of_the_tonemapped_lr():
    from wdss.ops.tonemap import tonemap

    data = batch(size=(18, 27), scale=3.0)
    module = SuperResolutionModule({**TINY_RRDB, "skip": True}, flip=False).eval()
    torch.nn.init.zeros_(module.net.conv_last.weight)
    expected = torch.nn.functional.interpolate(tonemap(data["lr_color"], "hable"), size=(18, 27), mode="bicubic")
    torch.testing.assert_close(module(data)["display"], expected.clamp(0, 1))
    with pytest.raises(ValueError, match="published weights .* need skip=false"):
        RRDBNet(skip=True, weights="/nowhere/RealESRGAN_x4plus.pth")


def test_real_esrgan_demodulated_reads_the_irradiance_and_is_remodulated_with_the_hr_brdf():
    data = batch(size=(18, 27), scale=3.0)
    data["emission"] = 0.1 * torch.rand(2, 3, 18, 27)
    module = SuperResolutionModule({**TINY_RRDB, "skip": True, "demodulated": True}, flip=False).eval()
    assert module.net.inputs == ("lr", "brdf") and "lr_color" not in module.inputs and "emission" in module.inputs
    torch.nn.init.zeros_(module.net.conv_last.weight)
    torch.nn.init.zeros_(module.net.conv_last.bias)
    # With no correction it is the bicubic upsampling of log1p(irradiance), remodulated, the emission added back.
    log = torch.nn.functional.interpolate(torch.log1p(data["lr"]), size=(18, 27), mode="bicubic")
    expected = torch.expm1(log.clamp(0, 20)) * data["brdf"] + data["emission"]
    out = module({k: v for k, v in data.items() if k != "lr_color"})  # the colour is never read
    assert out["display"] is None
    torch.testing.assert_close(out["color"], expected)
    # It learns through the same loss as the irradiance models (on the remodulated colour).
    module.train()
    torch.nn.init.normal_(module.net.conv_last.weight, std=1e-3)
    assert len(losses_over_steps(module, data)) == 2
    with pytest.raises(ValueError, match="trained on tone-mapped colour and need demodulated=false"):
        RRDBNet(demodulated=True, weights="/nowhere/RealESRGAN_x4plus.pth")
    with pytest.raises(ValueError, match="needs the batch key 'lr'"):
        RRDBNet(**{k: v for k, v in TINY_RRDB.items() if k != "_target_"}, demodulated=True)(brdf=data["brdf"])


def test_real_esrgan_demodulated_variant_is_the_published_network_on_the_irradiance():
    from tests.test_train import compose_train

    cfg = compose_train(["variant=real_esrgan_demodulated", "experiment=cpu"])
    assert cfg.model.net._target_ == "wdss.nets.comparison.rrdbnet.RRDBNet"
    assert cfg.model.net.demodulated is True and cfg.model.net.skip is True
    assert compose_train(["variant=real_esrgan"]).model.net.demodulated is False


@pytest.mark.parametrize("variant", ["nsrr", "fusesr", "real_esrgan"])
def test_cpu_experiment_turns_the_comparison_skips_on(variant):
    from tests.test_train import compose_train

    assert compose_train([f"variant={variant}", "experiment=cpu"]).model.net.skip is True
    assert compose_train([f"variant={variant}"]).model.net.skip is False  # the published design by default
