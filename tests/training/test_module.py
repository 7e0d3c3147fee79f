"""The LightningModule: losses, a step that learns, overfitting, metrics against scikit-image, checkpoints."""

from __future__ import annotations

import numpy as np
import pytest
import torch
import torch.nn.functional as F
from skimage.metrics import peak_signal_noise_ratio, structural_similarity

from tests.helpers import TINY, batch, head_config, losses_over_steps
from tests.nets.wdss.test_network import VARIANTS
from wdss.config.sizes import size_widths
from wdss.training.losses import WDSSLoss, temporal_difference_loss
from wdss.training.metrics import LPIPS, psnr, ssim
from wdss.training.module import SuperResolutionModule

WEIGHTS = {"l1": 1.0, "ssim": 0.4, "masked_l1": 0.1, "wavelet": 0.1}


def module(transform="swt", basis="haar", head="shared_inr", temporal=True, widths=TINY, temporal_mode=None, **kwargs):
    net = {
        "_target_": "wdss.nets.wdss.network.WDSSNet",
        "transform": transform,
        "basis": basis,
        "head": head_config(head),
        "temporal": temporal,
        **{k: list(v) if isinstance(v, tuple) else v for k, v in widths.items()},
    }
    if kwargs.get("upsampler") is not None:
        net["upsampler"] = kwargs.pop("upsampler")
    kwargs.pop("flip", None)
    mode = temporal_mode or ("gt_history" if temporal else "none")
    weights = kwargs.pop("weights", WEIGHTS)
    return SuperResolutionModule(net, loss_weights=weights, flip=False, temporal=mode, **kwargs)


@pytest.mark.parametrize("transform,basis,head,temporal", VARIANTS)
def test_one_step_lowers_the_loss_on_a_fixed_batch(transform, basis, head, temporal):
    torch.manual_seed(0)
    model = module(
        transform, basis, head, temporal, optimizer={"_target_": "torch.optim.Adam", "_partial_": True, "lr": 1e-3}
    )
    data = batch(size=(16, 16))
    losses = losses_over_steps(model, data)
    assert losses[1] < losses[0]
    if transform != "none":
        assert "wavelet" in model._loss(data, model(data))


def test_the_small_preset_overfits_one_fixture_patch():
    """300 Adam steps on one 32x32 patch of the committed render raise the tone-mapped PSNR by over 6 dB."""
    from pathlib import Path

    from wdss.data import SceneDataModule

    torch.manual_seed(0)
    small = size_widths("small")
    model = module(
        "swt",
        "db4",
        widths=small,
        weights={"l1": 1.0},
        optimizer={"_target_": "torch.optim.Adam", "_partial_": True, "lr": 2e-3},
    )
    fixture = Path(__file__).resolve().parents[1] / "fixtures" / "rendered"
    dm = SceneDataModule(fixture, {"train": ["fixture_000"]}, model.inputs, scale=2.0, patch_size=32, batch_size=1)
    dm.setup("fit")
    data = next(iter(dm.train_dataloader()))
    optimizer = model.configure_optimizers()

    def score() -> float:
        with torch.no_grad():
            return float(model.metrics(model(data)["color"], data["target"])["psnr"][0])

    before = score()
    for _ in range(300):
        optimizer.zero_grad()
        model._loss(data, model(data))["total"].backward()
        optimizer.step()
    after = score()
    assert after > before + 6.0, (before, after)


def test_metrics_agree_with_scikit_image():
    g = torch.Generator().manual_seed(0)
    a = torch.rand(2, 3, 40, 48, generator=g, dtype=torch.float64)
    b = (a + 0.05 * torch.randn(2, 3, 40, 48, generator=g, dtype=torch.float64)).clamp(0, 1)
    for i in range(2):
        x, y = a[i].permute(1, 2, 0).numpy(), b[i].permute(1, 2, 0).numpy()
        assert float(psnr(b, a)[i]) == pytest.approx(peak_signal_noise_ratio(x, y, data_range=1.0), rel=1e-9)
        reference = structural_similarity(
            x, y, data_range=1.0, channel_axis=2, gaussian_weights=True, sigma=1.5, use_sample_covariance=False
        )
        assert float(ssim(b, a)[i]) == pytest.approx(reference, abs=2e-3)


def test_identical_images_report_infinite_psnr_not_nan():
    a = torch.rand(1, 3, 16, 16)
    assert psnr(a, a).item() == float("inf")
    assert float(ssim(a, a)) == pytest.approx(1.0)
    assert torch.isfinite(psnr(torch.zeros(1, 3, 8, 8), torch.ones(1, 3, 8, 8))).all()


def test_the_temporal_term_does_not_collapse_to_plain_l1():
    target, previous = torch.rand(1, 3, 8, 8), torch.rand(1, 3, 8, 8)
    output = target + 0.1
    # A constant offset on every frame is temporally stable: no temporal penalty, though L1 is 0.1.
    assert float(temporal_difference_loss(output, previous + 0.1, target, previous)) == pytest.approx(0.0, abs=1e-7)
    assert float(temporal_difference_loss(output, previous, target, previous)) == pytest.approx(0.1, rel=1e-5)


def test_lpips_needs_local_weights():
    with pytest.raises(ValueError, match="lpips > 0 needs LPIPS backbone weights"):
        WDSSLoss({"l1": 1.0, "lpips": 0.2})
    with pytest.raises(FileNotFoundError, match="LPIPS backbone weights not found"):
        LPIPS("/nonexistent/vgg16.pth", "/nonexistent/lin.pth")
    with pytest.raises(ValueError, match=r"unknown loss terms \['perceptual'\]"):
        WDSSLoss({"perceptual": 1.0})


def test_lpips_loads_torchvision_and_lpips_weight_layouts(tmp_path):
    """Structure only (random weights, never for numbers): identical images score 0, different ones > 0."""
    from wdss.training.metrics import _CHANNELS, _VGG16

    state, index, cin = {}, 0, 3
    for v in _VGG16:
        if v == "M":
            index += 1
            continue
        state[f"features.{index}.weight"] = torch.randn(v, cin, 3, 3) * 0.1
        state[f"features.{index}.bias"] = torch.zeros(v)
        index, cin = index + 2, v
    torch.save(state, tmp_path / "vgg16.pth")
    torch.save(
        {f"lin{i}.model.1.weight": torch.rand(1, c, 1, 1) for i, c in enumerate(_CHANNELS)}, tmp_path / "lin.pth"
    )
    lpips = LPIPS(tmp_path / "vgg16.pth", tmp_path / "lin.pth")
    a, b = torch.rand(2, 3, 32, 32), torch.rand(2, 3, 32, 32)
    assert torch.allclose(lpips(a, a), torch.zeros(2)) and (lpips(a, b) > 0).all()


def test_a_non_finite_loss_stops_training_naming_the_batch():
    model = module()
    data = batch()
    data["target"][0, 0, 0, 0] = float("nan")
    with pytest.raises(FloatingPointError, match=r"non-finite training loss at step 0 \(batch 3: sequences"):
        model.training_step(data, 3)


def test_an_hdr_overflow_of_the_loss_points_at_color_max():
    data = batch()
    data["target"][0, :, :4, :4] = 3e38  # finite, as loading checks, but the loss overflows
    with pytest.raises(
        FloatingPointError, match=r"brightest target value is 3e\+38: .* data\.preprocessing\.color_max \(e\.g\. 10\)"
    ):
        module().training_step(data, 0)


def test_baselines_run_through_the_same_path():
    data = batch(size=(16, 20), scale=2.0)
    for mode, demodulated in (("bilinear", False), ("bicubic", False), ("bilinear", True)):
        model = SuperResolutionModule(
            {"_target_": "wdss.nets.upsamplers.baselines.Upsample", "mode": mode, "demodulated": demodulated},
            flip=False,
        )
        out = model(data)
        assert out["color"].shape == data["target"].shape and model.configure_optimizers() is None
    # bilinear-demodulated restores the HR BRDF's detail: better than upsampling colour here.
    colour = SuperResolutionModule({"_target_": "wdss.nets.upsamplers.baselines.Upsample"}, flip=False)
    demod = SuperResolutionModule(
        {"_target_": "wdss.nets.upsamplers.baselines.Upsample", "demodulated": True}, flip=False
    )
    err = {name: float((m(data)["color"] - data["target"]).abs().mean()) for name, m in (("c", colour), ("d", demod))}
    assert err["d"] < err["c"]


def test_checkpoint_round_trip_rebuilds_the_model(tmp_path):
    import lightning as L
    from torch.utils.data import DataLoader

    torch.manual_seed(0)
    model = module("dwt", "db4", "fusion_ll")
    data = batch(n=2, size=(16, 16))
    loader = DataLoader([data], batch_size=None)
    trainer = L.Trainer(
        max_steps=2,
        logger=False,
        enable_progress_bar=False,
        enable_model_summary=False,
        default_root_dir=tmp_path,
        enable_checkpointing=False,
    )
    trainer.fit(model, loader)
    path = tmp_path / "model.ckpt"
    trainer.save_checkpoint(path)
    loaded = SuperResolutionModule.load_from_checkpoint(path, weights_only=True)
    assert loaded.net.transform == "dwt" and loaded.net.head.name == "fusion_ll"
    model.eval()
    loaded.eval()
    with torch.no_grad():
        torch.testing.assert_close(loaded(data)["color"], model(data)["color"])
    assert np.isclose(loaded.hparams.loss_weights["ssim"], 0.4)


def test_recurrent_training_feeds_back_its_own_warped_output():
    torch.manual_seed(0)
    model = module("swt", "haar", temporal=True, weights={"l1": 1.0, "temporal": 0.3}, temporal_mode="recurrent")
    assert "motion" in model.inputs and "history" not in model.inputs
    steps = []
    for t in range(3):
        step = batch(size=(16, 16), seed=t)
        step["motion"] = torch.zeros(2, 2, 16, 16)
        steps.append(step)
    seen = []
    forward = model.net.forward

    def spy(**kwargs):
        seen.append(kwargs["history"].clone())
        return forward(**kwargs)

    model.net.forward = spy
    loss = model.training_step({"steps": steps}, 0)
    assert torch.isfinite(loss) and loss.requires_grad
    # A sequence starts from the upsampled LR irradiance (as DFASR does); step 2 sees step 1's output (zero motion).
    start = F.interpolate(steps[0]["lr"], size=(16, 16), mode="bilinear", align_corners=False)
    torch.testing.assert_close(seen[0], start)
    assert not torch.allclose(seen[1], F.interpolate(steps[1]["lr"], size=(16, 16), mode="bilinear"))
    loss.backward()
    assert model.net.temporal_branch.layers[0].feature.weight.grad.abs().sum() > 0


def test_recurrent_evaluation_carries_state_only_between_consecutive_frames():
    model = module("dwt", "haar", temporal=True, temporal_mode="recurrent", flip=None)
    seen, fresh = [], []
    forward = model.net.forward
    model.net.forward = lambda **kw: (seen.append(kw["history"].clone()), forward(**kw))[1]
    for sequence, frame in (("a", 1), ("a", 2), ("a", 4), ("b", 5)):
        data = batch(n=1, size=(16, 16))
        data["motion"] = torch.zeros(1, 2, 16, 16)
        data["sequence"], data["frame"] = [sequence], torch.tensor([frame])
        fresh.append(F.interpolate(data["lr"], size=(16, 16), mode="bilinear", align_corners=False))
        with torch.no_grad():
            model._evaluate(data, "val", "")
    # A new sequence (or a gap) starts from the upsampled LR; frame 2 follows frame 1 and sees its output.
    starts = [torch.allclose(history, start) for history, start in zip(seen, fresh, strict=True)]
    assert starts == [True, False, True, True]


def test_temporal_settings_must_agree():
    with pytest.raises(ValueError, match="only temporal=recurrent produces"):
        module(weights={"l1": 1.0, "temporal": 0.3})
    with pytest.raises(ValueError, match="model.temporal=none but the network has temporal branch"):
        module(temporal=True, temporal_mode="none")


@pytest.mark.parametrize("in_validation", [False, True])
def test_flip_is_a_test_metric_and_in_validation_only_when_asked(in_validation):
    model = SuperResolutionModule(
        {"_target_": "wdss.nets.upsamplers.baselines.Upsample", "demodulated": True},
        flip=True,
        flip_in_validation=in_validation,
    )
    logged: list[str] = []
    model.log = lambda name, *args, **kwargs: logged.append(name)
    data = batch(n=1, size=(16, 16))
    data["sequence"], data["frame"] = ["a"], torch.tensor([1])
    with torch.no_grad():
        model._evaluate(data, "val", "")
        model._evaluate(data, "test", "_2x")
    assert {"test/flip_2x", "test/flip_hdr_2x", "test/psnr_2x"} <= set(logged)
    assert ("val/flip" in logged) == ("val/flip_hdr" in logged) == in_validation and "val/psnr" in logged


def test_the_kernel_can_learn_at_its_own_rate_and_by_default_shares_the_networks():
    kernel = {"_target_": "wdss.nets.upsamplers.learned_bilateral.LearnedBilateralUpsample", "hidden": 4}
    adam = {"_target_": "torch.optim.Adam", "_partial_": True, "lr": 2e-3}
    same = module(temporal=False, upsampler=kernel, optimizer=adam)
    net_params = {id(p) for p in same.net.parameters()}
    (group,) = same.configure_optimizers().param_groups
    assert {id(p) for p in group["params"]} == net_params and group["lr"] == 2e-3

    apart = module(temporal=False, upsampler=kernel, optimizer=adam, upsampler_lr_scale=3.0)
    rest, own = apart.configure_optimizers().param_groups
    kernel_params = {id(p) for p in apart.net.upsampler.parameters()}
    assert kernel_params and {id(p) for p in own["params"]} == kernel_params
    assert {id(p) for p in rest["params"]} == {id(p) for p in apart.net.parameters()} - kernel_params
    assert rest["lr"] == 2e-3 and own["lr"] == pytest.approx(6e-3)
    assert apart.hparams.upsampler_lr_scale == 3.0

    # a network without a residual upsampler (and a checkpoint of before the option) keeps one group
    (alone,) = module(temporal=False, optimizer=adam, upsampler_lr_scale=3.0).configure_optimizers().param_groups
    assert alone["lr"] == 2e-3
