"""Sweeps every report test module reads: three seeds of the wavelet ablation, one seed of the methods."""

from __future__ import annotations

import pytest

from tests.report.sweeps import FLIP, PSNR, SEEDS, fake_sweep
from wdss.report.write import report


@pytest.fixture(scope="package")
def three_seeds(tmp_path_factory):
    root = tmp_path_factory.mktemp("three_seeds")
    jobs = []
    for variant in PSNR:
        for seed in SEEDS:
            metrics = {}
            for k, scale in enumerate(("2x", "3x", "4x")):
                metrics[f"test/psnr_{scale}"] = PSNR[variant][seed] - k
                metrics[f"test/ssim_{scale}"] = 0.9 + PSNR[variant][seed] / 1000 - k / 100
                metrics[f"test/flip_{scale}"] = FLIP[variant][seed] + k / 100
            jobs.append(({"experiment": "cpu", "variant": variant, "seed": str(seed)}, metrics, "FINISHED"))
    jobs.append(({"experiment": "cpu", "variant": "none", "seed": "3"}, {}, "FAILED"))
    uri = fake_sweep(root, "ablation_wavelet", jobs)
    out = report("ablation_wavelet", tracking_uri=uri, out_dir=root / "reports")
    return out


@pytest.fixture(scope="package")
def one_seed(tmp_path_factory):
    root = tmp_path_factory.mktemp("one_seed")
    jobs = [
        ({"variant": "bicubic", "seed": "0"}, {"test/psnr_3x": 24.0, "test/ssim_3x": 0.76, "test/lpips_3x": 0.35}, ""),
        ({"variant": "swt_db4", "seed": "0"}, {"test/psnr_3x": 29.7, "test/ssim_3x": 0.89, "test/lpips_3x": 0.12}, ""),
        ({"variant": "dfasr", "seed": "0"}, {"test/psnr_3x": 28.2, "test/ssim_3x": 0.85, "test/lpips_3x": 0.18}, ""),
    ]
    uri = fake_sweep(root, "methods", [(job, metrics, "FINISHED") for job, metrics, _ in jobs])
    return report("methods", tracking_uri=uri, out_dir=root / "reports")
