"""The network: shapes for every variant, arbitrary scales, configuration errors, block folding."""

from __future__ import annotations

import itertools

import pytest
import torch
from torch.utils._python_dispatch import TorchDispatchMode

from tests.helpers import TINY, batch, head
from wdss.nets.blocks import RIRBlock
from wdss.nets.wdss.network import WDSSNet, shuffle_channels_last

VARIANTS = [
    (t, b, h, temporal)
    for t, b, h, temporal in itertools.product(
        ("none", "dwt", "swt"), ("haar", "db4", "sym4"), ("shared_inr", "multi_inr", "fusion_ll"), (True, False)
    )
    if not (t == "none" and (h != "shared_inr" or b != "haar"))
]


def run(net: WDSSNet, data: dict) -> dict:
    return net(**{k: data[k] for k in (*net.inputs, "scale")})


@pytest.mark.parametrize("transform,basis,head_name,temporal", VARIANTS)
def test_forward_shapes_of_every_variant(transform, basis, head_name, temporal):
    net = WDSSNet(transform, basis, head(head_name), temporal, **TINY)
    data = batch(size=(16, 20))
    out = run(net, data)
    assert out["irradiance"].shape == (2, 3, 16, 20) and (out["irradiance"] >= 0).all()
    expected = {"none": None, "dwt": (2, 12, 8, 10), "swt": (2, 12, 16, 20)}[transform]
    assert (out["coefficients"] is None) if expected is None else out["coefficients"].shape == expected
    assert ("history" in net.inputs) == temporal


@pytest.mark.parametrize("scale", [1.0, 1.01, 2.37, 3.0, 4.0, 8.0])
@pytest.mark.parametrize("transform", ["dwt", "swt"])
def test_any_scale_and_frames_not_divisible_by_it(transform, scale):
    net = WDSSNet(transform, "db4", **TINY)
    data = batch(size=(27, 35), scale=scale)
    out = run(net, data)
    assert out["irradiance"].shape == (2, 3, 27, 35) and torch.isfinite(out["irradiance"]).all()


def test_heads_that_need_subbands_refuse_transform_none():
    with pytest.raises(ValueError, match="head=fusion_ll needs wavelet subbands, but transform=none"):
        WDSSNet("none", "haar", head("fusion_ll"))
    with pytest.raises(ValueError, match=r"model.net.head must be a head of wdss.nets.wdss.heads .*got 'two_inr'"):
        WDSSNet("swt", "haar", "two_inr")
    with pytest.raises(ValueError, match=r"model.net.upsampler must be a residual upsampler .*got 'bilinear'"):
        WDSSNet("swt", "haar", upsampler="bilinear")


def test_a_temporal_network_asks_for_history():
    net = WDSSNet("swt", "haar", temporal=True, **TINY)
    data = batch()
    with pytest.raises(ValueError, match="needs history and temporal_mask"):
        net(data["lr"], data["gbuffer"], data["spatial_mask"], data["scale"])


def test_paper_widths_give_the_papers_parameter_count():
    counts = {t: sum(p.numel() for p in WDSSNet(t, "db4").parameters()) for t in ("none", "dwt", "swt")}
    assert all(0.5e6 < c < 0.62e6 for c in counts.values()), counts


def test_rir_blocks_fold_into_one_convolution_exactly():
    block = RIRBlock(6).double()
    x = torch.randn(2, 6, 9, 7, dtype=torch.float64)
    before = block(x)
    block.reparameterize()
    torch.testing.assert_close(block(x), before)
    net = WDSSNet("swt", "haar", gbuffer_block="rir", **TINY)
    assert any(isinstance(m, RIRBlock) for m in net.modules())


class _Ops(TorchDispatchMode):
    """Records every aten call with its arguments."""

    def __init__(self) -> None:
        super().__init__()
        self.calls: list[tuple[str, tuple]] = []

    def __torch_dispatch__(self, func, types, args=(), kwargs=None):
        self.calls.append((str(func.overloadpacket), args))
        return func(*args, **(kwargs or {}))


@pytest.mark.parametrize("transform", ["none", "swt"])
def test_eager_inference_copies_nothing_it_does_not_need(transform):
    """Eager CPU speed (python -m wdss.bench inference): an even frame is not copied by a zero padding, one INR MLP's
    output is not concatenated, and the SWT exit convolution and synthesis on full-resolution channels run
    channels-last (oneDNN's fast layout for them)."""
    net = WDSSNet(transform, "db4", **TINY).eval()
    data = batch(size=(16, 20))
    with torch.no_grad(), _Ops() as ops:
        run(net, data)
    assert not [name for name, args in ops.calls if "pad" in name and args[0].shape[-2:] == data["gbuffer"].shape[-2:]]
    assert not [args for name, args in ops.calls if name == "aten.cat" and len(args[0]) == 1]
    full = [args[0] for name, args in ops.calls if name == "aten.convolution" and args[0].shape[-2] >= 16]
    assert full and all(x.is_contiguous(memory_format=torch.channels_last) for x in full) == (transform == "swt")


@pytest.mark.parametrize("shape", [(1, 48, 5, 7), (2, 12, 4, 6), (1, 4, 1, 1)])
@pytest.mark.parametrize("channels_last", [False, True])
def test_shuffle_channels_last_is_pixel_shuffle_in_channels_last(shape, channels_last):
    x = torch.randn(shape, dtype=torch.float64, requires_grad=True)
    given = x.contiguous(memory_format=torch.channels_last) if channels_last else x
    out = shuffle_channels_last(given)
    expected = torch.nn.functional.pixel_shuffle(x, 2)
    assert torch.equal(out, expected)
    assert out.is_contiguous(memory_format=torch.channels_last)
    weight = torch.randn_like(expected)
    (grad,) = torch.autograd.grad((out * weight).sum(), x)
    (grad_expected,) = torch.autograd.grad((expected * weight).sum(), x)
    assert torch.equal(grad, grad_expected)
