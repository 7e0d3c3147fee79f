"""The compact paper-style table, the CSV and the notes below the table, from fake MLflow sweeps."""

from __future__ import annotations

import csv

import numpy as np
import pytest

from tests.report.sweeps import FLIP, PSNR, SEEDS, body, fake_sweep, t_half_width
from wdss.report.facts import paper_facts
from wdss.report.tables import table_scale
from wdss.report.write import report


def test_one_row_per_configuration_named_as_the_paper_does(three_seeds):
    header, rows = body((three_seeds / "table.md").read_text())
    assert list(rows) == ["No wavelet", "DWT-haar", "SWT-db4"]
    assert header[:4] == ["Configuration", "PSNR ↑", "SSIM ↑", "FLIP ↓"]
    assert "LPIPS ↓" not in header  # no run logged LPIPS
    assert header[-2:] == ["n", "note"] and rows["SWT-db4"][-2:] == ["3", ""]
    assert rows["No wavelet"][-1] == "1 of 4 jobs FAILED"  # the failed job is marked, its seeds left out


def test_cells_are_the_mean_and_the_95_t_interval_at_the_ablations_paper_scale(three_seeds):
    text = (three_seeds / "table.md").read_text()
    header, rows = body(text)
    assert "Test metrics at 2x" in text  # several scales tested: the wavelet ablation's table is at 2x
    psnr = rows["DWT-haar"][header.index("PSNR ↑") - 1]
    values = PSNR["dwt_haar"]
    assert psnr == f"{np.mean(values):.2f} ± {t_half_width(values):.2f}"
    flip = rows["No wavelet"][header.index("FLIP ↓") - 1]
    assert flip == f"{np.mean(FLIP['none']):.4f} ± {t_half_width(FLIP['none']):.4f}"
    assert header[4] == "PSNR mean of 2x/3x/4x ↑"  # one compact mean-over-scales column
    assert rows["SWT-db4"][3].strip("*").startswith(f"{np.mean(PSNR['swt_db4']) - 1:.2f} ± ")


def test_the_best_value_of_each_column_is_bold(three_seeds):
    header, rows = body((three_seeds / "table.md").read_text())
    bold = {
        column: [row for row, cells in rows.items() if cells[i].startswith("**")]
        for i, column in enumerate(header[1:5])
    }
    assert bold == {
        "PSNR ↑": ["SWT-db4"],
        "SSIM ↑": ["SWT-db4"],
        "FLIP ↓": ["DWT-haar"],  # lower is better
        "PSNR mean of 2x/3x/4x ↑": ["SWT-db4"],
    }


def test_the_csv_keeps_every_metric_at_every_scale_with_interval_and_n(three_seeds):
    with open(three_seeds / "table.csv", newline="") as f:
        rows = {row["configuration"]: row for row in csv.DictReader(f)}
    assert set(rows) == {"No wavelet", "DWT-haar", "SWT-db4"}
    row = rows["SWT-db4"]
    for metric in ("psnr", "ssim", "flip"):
        for scale in ("2x", "3x", "4x", "avg"):
            assert f"test/{metric}_{scale}" in row and row[f"test/{metric}_{scale} n"] == "3"
    assert float(row["test/psnr_4x"]) == pytest.approx(np.mean(PSNR["swt_db4"]) - 2)
    assert float(row["test/psnr_4x ci95"]) == pytest.approx(t_half_width(PSNR["swt_db4"]))
    assert rows["No wavelet"]["note"] == "1 of 4 jobs FAILED"
    assert (three_seeds / "tradeoff.png").stat().st_size > 0  # the plots still come out


def test_one_seed_has_no_interval_and_lpips_shows_when_logged(one_seed):
    text = (one_seed / "table.md").read_text()
    header, rows = body(text)
    assert header == ["Configuration", "PSNR ↑", "SSIM ↑", "LPIPS ↓", "n"]  # no FLIP logged, no failure noted
    assert "Test metrics at 3x" in text
    assert rows["Bicubic"] == ["24.00 ± n/a", "0.7600 ± n/a", "0.3500 ± n/a", "1"]
    assert rows["SWT-db4"] == ["**29.70 ± n/a**", "**0.8900 ± n/a**", "**0.1200 ± n/a**", "1"]
    assert "nan" not in text.lower() and "± 0" not in text
    assert "Hable, exposure 10 (the curve's default)" in text and "3 runs (3 finished)" in text
    with open(one_seed / "table.csv", newline="") as f:
        swt = next(row for row in csv.DictReader(f) if row["configuration"] == "SWT-db4")
    assert swt["test/psnr_3x ci95"] == "" and swt["test/psnr_3x n"] == "1"


def test_the_table_scale_follows_the_sweep():
    def table_scale_of(sweep, scales, requested=None):  # the scale the sweep file's report node names
        return table_scale(paper_facts(sweep).scale, scales, requested)

    assert table_scale_of("methods", ["3x"]) == "3x"  # its only test scale
    assert table_scale_of("methods", ["2x", "3x", "4x"]) == "3x"  # the paper's methods table
    assert table_scale_of("ablation_arch", ["2x", "3x", "4x"]) == "2x"
    assert table_scale_of("scales", ["2x", "3x", "4x"]) == "avg"
    assert table_scale_of("anything", ["3x", "4x"]) == "3x"
    assert table_scale_of("methods", ["2x", "3x"], "2x") == "2x"
    with pytest.raises(SystemExit, match="no test metrics at '5x'"):
        table_scale_of("methods", ["2x", "3x"], "5x")


def test_temporal_columns_the_per_frame_psnr_plot_and_three_frames_of_the_crop(tmp_path):
    from mlflow import MlflowClient
    from PIL import Image

    ratios = {"bicubic": 0.80, "swt_db4": 1.08, "dfasr": 1.30}  # bicubic: smoother than the truth (blur)
    jobs = [
        ({"variant": variant, "seed": "0"}, {"test/psnr_3x": 28.0, "test/twe_ratio_3x": r, "test/tpsnr_3x": 30 + r})
        for variant, r in ratios.items()
    ]
    uri = fake_sweep(tmp_path, "methods", [(job, metrics, "FINISHED") for job, metrics in jobs])
    client = MlflowClient(uri)
    runs = client.search_runs([client.get_experiment_by_name("methods").experiment_id], "tags.variant != ''")
    rng = np.random.default_rng(0)
    for run in runs:
        for frame in range(1, 6):
            for sequence in ("test_000", "test_001"):
                client.log_metric(run.info.run_id, f"frames/{sequence}/psnr_3x", 28 + frame / 10, step=frame)
        for suffix in ("", "_t1", "_t2"):
            for kind in ("pred", "target"):
                image = rng.integers(0, 255, (120, 200, 3), dtype=np.uint8)
                client.log_image(run.info.run_id, image, artifact_file=f"test/{kind}_3x{suffix}.png")
    out = report("methods", tracking_uri=uri, out_dir=tmp_path / "reports")
    header, rows = body((out / "table.md").read_text())
    assert header == ["Configuration", "PSNR ↑", "tWE / target's →1", "tPSNR ↑", "n"]
    assert rows["SWT-db4"][1] == "**1.080 ± n/a**"  # the ratio closest to 1 is best, not the lowest
    assert rows["Bicubic"][1] == "0.800 ± n/a" and rows["DFASR"][2] == "**31.30 ± n/a**"
    assert "tWE / target's: the mean change between consecutive frames" in (out / "table.md").read_text()
    assert (out / "frames.png").stat().st_size > 0
    # A row per frame (t, t+1, t+2) of the 96-pixel crop: three times the height of the one-frame figure.
    assert Image.open(out / "qualitative.png").size[1] > 800


def test_the_targets_noise_ceiling_is_stated_below_the_table_and_is_no_column(tmp_path, three_seeds):
    assert "Targets' noise ceiling: not measured" in (three_seeds / "table.md").read_text()
    ceilings = {"test/noise_ceiling_test_000": 40.0, "test/noise_ceiling_test_001": 42.0, "test/noise_ceiling": 41.0}
    jobs = [
        ({"variant": v, "seed": str(s)}, {"test/psnr_2x": 30.0 + s, "test/psnr_3x": 29.0, **ceilings}, "FINISHED")
        for v in ("swt_haar", "swt_db4")
        for s in SEEDS
    ]
    uri = fake_sweep(tmp_path, "ablation_wavelet", jobs)
    text = (report("ablation_wavelet", tracking_uri=uri, out_dir=tmp_path / "reports") / "table.md").read_text()
    assert "no row can exceed it): 41.00 dB mean (test_000 40.00, test_001 42.00)." in text
    header, _ = body(text)
    assert all(h.startswith(("Configuration", "PSNR", "n")) for h in header) and "noise" not in text.split("Targets")[0]
