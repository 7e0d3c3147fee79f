"""Stiff and extreme cases: each returns the worst relative error against a float64 or analytic reference and
whether anything became non-finite. ``python -m wdss.bench stability`` prints them; the tests assert on them.

Relative errors are ``max |got - ref| / max |ref|`` (or against the analytic value where one exists).
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass

import numpy as np
import pywt
import torch

from wdss.ops.brdf import BRDF_KNEE, demodulate, remodulate, safe_brdf
from wdss.ops.tonemap import hable
from wdss.ops.warp import spatial_mask, temporal_mask, warp_backward
from wdss.wavelets import analysis, synthesis

__all__ = ["CASES", "Case", "run_cases"]


@dataclass
class Case:
    group: str
    name: str
    error: float  # worst relative error (0 where only finiteness is checked)
    finite: bool
    tolerance: float  # what the tests require of `error`


def _rel(got: torch.Tensor | np.ndarray, ref: np.ndarray) -> float:
    got = got.detach().double().cpu().numpy() if isinstance(got, torch.Tensor) else np.asarray(got, np.float64)
    scale = max(float(np.abs(ref).max()), 1e-300)
    return float(np.abs(got - ref).max() / scale)


def _finite(*tensors: torch.Tensor) -> bool:
    return all(bool(torch.isfinite(t).all()) for t in tensors)


def _pywt(x: np.ndarray, transform: str, wavelet: str, level: int) -> np.ndarray:
    if transform == "dwt":
        coeffs = pywt.wavedec2(x, wavelet, mode="periodization", level=level, axes=(-2, -1))
        if level > 1:
            raise ValueError("level-2 DWT cases compare round trips only")
        return np.concatenate([coeffs[0], *coeffs[1]], axis=1)
    coeffs = pywt.swt2(x, wavelet, level=level, trim_approx=True, norm=False, axes=(-2, -1))
    return np.concatenate([coeffs[0], *(np.concatenate(d, axis=1) for d in coeffs[1:])], axis=1)


def _wavelet_cases() -> list[Case]:
    rng = np.random.default_rng(0)
    images = {
        "magnitudes 1e-6..1e5": rng.choice([-1, 1], (1, 3, 32, 32)) * 10 ** rng.uniform(-6, 5, (1, 3, 32, 32)),
        "constant 7.5": np.full((1, 3, 16, 16), 7.5),
        "single hot pixel 1e5": np.pad(np.full((1, 3, 1, 1), 1e5), ((0, 0), (0, 0), (7, 8), (7, 8))),
        "Nyquist checkerboard": np.indices((16, 16)).sum(0)[None, None].repeat(3, 1) % 2 * 2.0 - 1.0,
        "4x4 (below the 8-tap support)": rng.random((1, 3, 4, 4)),
    }
    cases = []
    for transform in ("dwt", "swt"):
        for wavelet in ("haar", "db4", "sym4"):
            for name, x in images.items():
                x32 = torch.from_numpy(x).float()
                coeffs = analysis(x32, transform=transform, wavelet=wavelet)
                back = synthesis(coeffs, transform=transform, wavelet=wavelet)
                error = max(_rel(coeffs, _pywt(x, transform, wavelet, 1)), _rel(back, x))
                cases.append(Case("wavelets", f"{transform}-{wavelet}, {name}", error, _finite(coeffs, back), 2e-6))
            odd = rng.random((1, 3, 5, 7))
            if transform == "swt":  # PyWavelets refuses odd sizes: the inverse is the reference
                back = synthesis(
                    analysis(torch.from_numpy(odd).float(), transform="swt", wavelet=wavelet),
                    transform="swt",
                    wavelet=wavelet,
                )
                cases.append(Case("wavelets", f"swt-{wavelet}, 5x7 round trip", _rel(back, odd), _finite(back), 2e-6))
            x = rng.random((1, 3, 16, 16)) * 100
            level2 = analysis(torch.from_numpy(x).float(), transform=transform, wavelet=wavelet, level=2)
            back = synthesis(level2, transform=transform, wavelet=wavelet, level=2)
            error = (
                _rel(back, x) if transform == "dwt" else max(_rel(back, x), _rel(level2, _pywt(x, "swt", wavelet, 2)))
            )
            cases.append(Case("wavelets", f"{transform}-{wavelet}, level 2", error, _finite(level2, back), 2e-6))
    return cases


def _brdf_cases() -> list[Case]:
    cases = []
    radiance = torch.logspace(-6, 5, 12, dtype=torch.float64).view(1, 1, 1, 12).expand(1, 3, 4, 12).float()
    for knee in (0.0, BRDF_KNEE):
        for label, value in (("F = 0", 0.0), ("F = 1e-8", 1e-8), ("F = 1e4", 1e4), ("F = 0.3", 0.3)):
            brdf = safe_brdf(torch.full_like(radiance, value), knee=knee)
            back = remodulate(demodulate(radiance, brdf), brdf)
            ref = radiance.double().numpy()
            name = f"{label}, knee {knee:g}, radiance 1e-6..1e5"
            cases.append(Case("brdf", name, _rel(back, ref) if value else 0.0, _finite(back), 1e-6))
            if value == 0:  # pass-through is exact, not merely close
                cases[-1].error = float((back - radiance).abs().max())
    black = torch.zeros(1, 3, 2, 2)
    emitter = torch.full((1, 3, 2, 2), 3e4)
    brdf = safe_brdf(black + (1 - 0.0) * 0.08 * 0.0)
    back = remodulate(demodulate(emitter, brdf), brdf)
    cases.append(Case("brdf", "black albedo + emitter 3e4", float((back - emitter).abs().max()), _finite(back), 0.0))
    return cases


def _warp_cases() -> list[Case]:
    previous = torch.rand(1, 3, 8, 8)
    motion = torch.zeros(1, 2, 8, 8)
    motion[:, 0, :4] = 1e9
    motion[:, 1, 4:6] = float("nan")
    motion[:, 0, 6:] = -1e30
    warped = warp_backward(previous, motion)
    outside = float(warped[..., :6, :].abs().max())  # far outside / NaN: zeros
    g = {
        "depth": torch.full((1, 1, 8, 8), 1e10),
        "normal": torch.zeros(1, 3, 8, 8),
        "base_color": torch.rand(1, 3, 8, 8),
    }
    g["normal"][..., :2, :] = float("nan")
    lr = {k: v[..., ::2, ::2] for k, v in g.items()}
    masks = (spatial_mask(g, lr), temporal_mask(g, {**g, "depth": torch.zeros(1, 1, 8, 8)}))
    return [
        Case("warp", "motion 1e9 / -1e30 / NaN -> zeros", outside, _finite(warped), 0.0),
        Case("warp", "zero and NaN normals, depth 1e10 in masks", 0.0, _finite(*masks), 0.0),
    ]


def _metric_cases() -> list[Case]:
    from wdss.training.losses import WDSSLoss
    from wdss.training.metrics import psnr, ssim

    image = torch.rand(1, 3, 16, 16)
    zeros = torch.zeros(1, 3, 16, 16)
    loss = WDSSLoss({"l1": 1.0, "ssim": 0.4, "masked_l1": 0.1})
    same = loss(image, image, spatial_mask=torch.ones(1, 1, 16, 16))["total"]
    zero = loss(zeros, zeros, spatial_mask=torch.ones(1, 1, 16, 16))["total"]
    return [
        Case(
            "metrics",
            "identical images: PSNR +inf, SSIM 1, loss 0",
            abs(float(ssim(image, image)) - 1.0),
            float(psnr(image, image)) == float("inf") and _finite(same),
            1e-5,
        ),
        Case(
            "metrics",
            "all-zero images: loss 0, SSIM 1",
            float(zero) + abs(float(ssim(zeros, zeros)) - 1.0),
            _finite(zero, psnr(zeros, image)),
            1e-5,
        ),
        Case(
            "metrics",
            "Hable tone map of 1e5 and 3e38 radiance",
            abs(float(hable(torch.tensor(1e5))) - 1.0),
            _finite(hable(torch.tensor([0.0, 1e5, 3e38]))),
            0.0,
        ),
    ]


def _network_cases() -> list[Case]:
    from wdss.nets.wdss.network import WIDTHS, WDSSNet
    from wdss.ops.sampling import lr_size

    torch.manual_seed(0)
    net = WDSSNet("swt", "db4", **WIDTHS["tiny"])
    cases = []
    for scale in (1.0, 1.01, 2.37, 4.0, 8.0):
        h, w = 37, 53  # divisible by none of the scales
        lh, lw = lr_size(h, w, scale)
        out = net(
            torch.rand(1, 3, lh, lw) * 1e5,
            torch.rand(1, 11, h, w),
            torch.zeros(1, 1, h, w),
            torch.tensor([scale]),
            torch.rand(1, 3, h, w) * 1e5,
            torch.rand(1, 5, h, w),
        )
        ok = out["irradiance"].shape == (1, 3, h, w)
        cases.append(
            Case(
                "scales",
                f"s = {scale:g}, 37x53 frame, 1e5 radiance",
                0.0 if ok else 1.0,
                _finite(out["irradiance"]),
                0.0,
            )
        )
    return cases


def _autocast_cases() -> list[Case]:
    from wdss.training.module import SuperResolutionModule

    torch.manual_seed(0)
    from wdss.nets.wdss.network import WIDTHS

    tiny = {k: list(v) if isinstance(v, tuple) else v for k, v in WIDTHS["tiny"].items()}
    net = {"_target_": "wdss.nets.wdss.network.WDSSNet", "transform": "swt", "basis": "db4", **tiny}
    module = SuperResolutionModule(net, {"l1": 1.0, "ssim": 0.4, "wavelet": 0.1}, flip=False)
    h, w = 16, 16
    batch = {
        "lr": torch.rand(2, 3, 8, 8) * 1e5, "gbuffer": torch.rand(2, 11, h, w), "spatial_mask": torch.zeros(2, 1, h, w),
        "history": torch.rand(2, 3, h, w) * 1e5, "temporal_mask": torch.rand(2, 5, h, w),
        "brdf": torch.rand(2, 3, h, w) + 0.1, "target": torch.rand(2, 3, h, w) * 1e5, "scale": torch.full((2,), 2.0),
    }  # fmt: skip
    with torch.autocast("cpu", dtype=torch.bfloat16):
        out = module(batch)
        terms = module._loss(batch, out)
    terms["total"].backward()
    grads = [p.grad for p in module.parameters() if p.grad is not None]
    float32 = out["irradiance"].dtype == torch.float32 and terms["total"].dtype == torch.float32
    reference = module(batch)["irradiance"].detach()
    error = _rel(out["irradiance"], reference.double().numpy())
    return [
        Case(
            "autocast",
            "bf16 forward + step, 1e5 radiance: synthesis and loss in float32",
            error if float32 else 1.0,
            _finite(out["irradiance"], terms["total"], *grads),
            0.1,
        )
    ]


CASES: tuple[Callable[[], list[Case]], ...] = (
    _wavelet_cases,
    _brdf_cases,
    _warp_cases,
    _metric_cases,
    _network_cases,
    _autocast_cases,
)


def run_cases() -> list[Case]:
    return [case for make in CASES for case in make()]
