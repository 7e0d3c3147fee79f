"""The sweep report from fake MLflow sweeps in a temporary SQLite store: the compact paper-style table."""

from __future__ import annotations

import csv
import math

import numpy as np
import pytest
from scipy import stats

from wdss.report import overrides, report, table_scale

SEEDS = (0, 1, 2)


def fake_sweep(root, name: str, jobs: list[tuple[dict[str, str], dict[str, float], str]], tags=None, old=True) -> str:
    """A parent run tagged ``sweep=name`` and one nested run per job (overrides, metrics, status), as
    ``wdss.train`` logs them: the variant and seed tags (and ``tags[i]``), the tone-map params, and the run named
    by its overrides (``old``: as before the tag ``overrides``) or variant first with the tag ``overrides``."""
    from mlflow import MlflowClient

    uri = f"sqlite:///{root}/mlflow.db"
    client = MlflowClient(uri)
    experiment = client.create_experiment(name, artifact_location=(root / "artifacts").as_uri())
    parent = client.create_run(experiment, run_name=f"sweep {name}", tags={"sweep": name}, start_time=1)
    for i, (job, metrics, status) in enumerate(jobs):
        given = ",".join(f"{k}={v}" for k, v in sorted(job.items()))
        rest = [f"{k.rsplit('.', 1)[-1]}={v}" for k, v in sorted(job.items()) if k not in ("variant", "seed")]
        run = client.create_run(
            experiment,
            run_name=given if old else " · ".join([job["variant"], *rest, f"seed{job.get('seed', 0)}", "mini"]),
            tags={
                "mlflow.parentRunId": parent.info.run_id,
                "sweep": name,
                "variant": job["variant"],
                "seed": "0",
                **({} if old else {"overrides": given}),
                **(tags[i] if tags else {}),
            },
            start_time=10 + i,
        )
        client.log_param(run.info.run_id, "model.tonemap_name", "hable")
        client.log_param(run.info.run_id, "tonemap_exposure", "None")
        for key, value in metrics.items():
            client.log_metric(run.info.run_id, key, value)
        client.set_terminated(run.info.run_id, status)
    client.set_terminated(parent.info.run_id, "FINISHED")
    return uri


def body(markdown: str) -> tuple[list[str], dict[str, list[str]]]:
    """The table's header cells and its rows by configuration."""
    lines = [line for line in markdown.splitlines() if line.startswith("| ")]
    cells = [[c.strip() for c in line.strip("|").split("|")] for line in lines]
    return cells[0], {row[0]: row[1:] for row in cells[1:]}


def t_half_width(values) -> float:
    values = np.asarray(values, dtype=float)
    return float(stats.t.ppf(0.975, len(values) - 1) * values.std(ddof=1) / math.sqrt(len(values)))


# Three seeds of three configurations of the wavelet ablation at 2x, 3x, 4x; SWT-db4 is best in PSNR and
# SSIM, DWT-haar in FLIP; one No-wavelet job failed.
PSNR = {"none": (28.91, 29.12, 28.77), "dwt_haar": (29.40, 29.61, 29.35), "swt_db4": (30.43, 30.58, 30.21)}
FLIP = {"none": (0.1401, 0.1388, 0.1420), "dwt_haar": (0.1102, 0.1121, 0.1095), "swt_db4": (0.1200, 0.1189, 0.1211)}


@pytest.fixture(scope="module")
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


@pytest.fixture(scope="module")
def one_seed(tmp_path_factory):
    root = tmp_path_factory.mktemp("one_seed")
    jobs = [
        ({"variant": "bicubic", "seed": "0"}, {"test/psnr_3x": 24.0, "test/ssim_3x": 0.76, "test/lpips_3x": 0.35}, ""),
        ({"variant": "swt_db4", "seed": "0"}, {"test/psnr_3x": 29.7, "test/ssim_3x": 0.89, "test/lpips_3x": 0.12}, ""),
        ({"variant": "dfasr", "seed": "0"}, {"test/psnr_3x": 28.2, "test/ssim_3x": 0.85, "test/lpips_3x": 0.18}, ""),
    ]
    uri = fake_sweep(root, "methods", [(job, metrics, "FINISHED") for job, metrics, _ in jobs])
    return report("methods", tracking_uri=uri, out_dir=root / "reports")


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


def test_the_papers_orderings_are_judged_by_paired_seed_differences_and_their_interval(three_seeds, one_seed):
    text = (three_seeds / "table.md").read_text()
    assert "The paper's orderings at 2x" in text
    differences = [d - n for d, n in zip(PSNR["dwt_haar"], PSNR["none"], strict=True)]  # the failed seed 3 drops out
    mean, half = float(np.mean(differences)), t_half_width(differences)
    assert mean - half > 0
    assert f"- No wavelet < DWT-haar: holds, {mean:+.2f} ± {half:.2f} dB, n=3" in text
    assert "- DWT-haar < SWT-haar: not tested (not in this sweep)" in text
    methods = (one_seed / "table.md").read_text()
    assert "- DFASR < SWT-db4: not resolved (one seed, no interval; the sign agrees), +1.50 dB, n=1" in methods
    assert "- Bicubic < Real-ESRGAN: not tested (not in this sweep)" in methods


def test_an_ordering_is_reversed_or_unresolved_by_the_interval(tmp_path):
    psnr = {"swt_haar": (30.0, 30.2, 30.1), "swt_sym4": (29.5, 29.6, 29.6), "swt_db4": (29.2, 29.9, 29.4)}
    jobs = [({"variant": v, "seed": str(s)}, {"test/psnr_2x": psnr[v][s]}, "FINISHED") for v in psnr for s in SEEDS]
    uri = fake_sweep(tmp_path, "ablation_wavelet", jobs)
    text = (report("ablation_wavelet", tracking_uri=uri, out_dir=tmp_path / "reports") / "table.md").read_text()
    down = [b - a for a, b in zip(psnr["swt_haar"], psnr["swt_sym4"], strict=True)]
    assert f"- SWT-haar < SWT-sym4: reversed, {np.mean(down):+.2f} ± {t_half_width(down):.2f} dB, n=3" in text
    tie = [b - a for a, b in zip(psnr["swt_sym4"], psnr["swt_db4"], strict=True)]
    assert abs(np.mean(tie)) < t_half_width(tie)
    assert "- SWT-sym4 <= SWT-db4: holds as a tie (the interval contains 0)" in text


def test_other_axes_than_the_seed_split_rows_and_runs_names_parse_with_lists(tmp_path):
    jobs = [
        ({"variant": "swt_haar", "data.patch_size": str(p), "seed": str(s)}, {"test/psnr_2x": 30.0 + p / 100 + s}, "")
        for p in (24, 48)
        for s in (0, 1)
    ]
    uri = fake_sweep(tmp_path, "ablation_arch", [(job, metrics, "FINISHED") for job, metrics, _ in jobs])
    _, rows = body((report("ablation_arch", tracking_uri=uri, out_dir=tmp_path / "reports") / "table.md").read_text())
    assert list(rows) == ["SWT-haar, data.patch_size=24", "SWT-haar, data.patch_size=48"]
    assert rows["SWT-haar, data.patch_size=48"][0] == f"**{30.98:.2f} ± {t_half_width([30.48, 31.48]):.2f}**"

    class Run:  # only what overrides() reads
        class data:
            tags = {"mlflow.runName": "data.test_scales=[2.0,3.0],seed=1,variant=none"}

    assert overrides(Run) == {"data.test_scales": "[2.0,3.0]", "seed": "1", "variant": "none"}


def test_runs_named_variant_first_are_read_by_their_overrides_tag(tmp_path):
    jobs = [
        ({"variant": "swt_haar", "data.patch_size": str(p), "seed": str(s)}, {"test/psnr_2x": 30.0 + p / 100 + s}, "")
        for p in (24, 48)
        for s in (0, 1)
    ]
    uri = fake_sweep(tmp_path, "ablation_arch", [(j, m, "FINISHED") for j, m, _ in jobs], old=False)
    out = report("ablation_arch", tracking_uri=uri, out_dir=tmp_path / "reports")
    _, rows = body((out / "table.md").read_text())
    assert list(rows) == ["SWT-haar, data.patch_size=24", "SWT-haar, data.patch_size=48"]

    class Run:  # a name that leads with the variant is never parsed as overrides
        class data:
            tags = {"mlflow.runName": "swt_haar · patch_size=48 · seed0 · mini"}

    assert overrides(Run) == {}
    Run.data.tags = {**Run.data.tags, "overrides": "data.patch_size=48,seed=0,variant=swt_haar"}
    assert overrides(Run) == {"data.patch_size": "48", "seed": "0", "variant": "swt_haar"}
    Run.data.tags["overrides"] = ""  # a run of the defaults
    assert overrides(Run) == {}


def test_the_table_scale_follows_the_sweep():
    assert table_scale("methods", ["3x"]) == "3x"  # its only test scale
    assert table_scale("methods", ["2x", "3x", "4x"]) == "3x"  # the paper's methods table
    assert table_scale("ablation_arch", ["2x", "3x", "4x"]) == "2x"
    assert table_scale("scales", ["2x", "3x", "4x"]) == "avg"
    assert table_scale("anything", ["3x", "4x"]) == "3x"
    assert table_scale("methods", ["2x", "3x"], "2x") == "2x"
    with pytest.raises(SystemExit, match="no test metrics at '5x'"):
        table_scale("methods", ["2x", "3x"], "5x")


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


def _adhoc_runs(root):
    """A training run of the default model with two evaluations nested under it (its own test scene and held-out
    scenes), and a baseline run on each of those data roots, logged as wdss.train and wdss.eval tag them."""
    from mlflow import MlflowClient

    uri = f"sqlite:///{root}/mlflow.db"
    client = MlflowClient(uri)
    experiment = client.create_experiment("wdss", artifact_location=(root / "artifacts").as_uri())

    def run(name, tags, psnr, parent=None, start=0):
        tags = {**tags, **({"mlflow.parentRunId": parent} if parent else {})}
        created = client.create_run(experiment, run_name=name, tags=tags, start_time=start)
        for k, scale in enumerate(("2x", "3x", "4x")):
            client.log_metric(created.info.run_id, f"test/psnr_{scale}", psnr - k)
        client.set_terminated(created.info.run_id, "FINISHED")
        return created.info.run_id

    trained = {"model": "wdss", "transform": "swt", "basis": "db4", "seed": "0"}
    training = run("experiment=cpu", {**trained, "data_root": "data/mini"}, 32.0, start=1)
    trained["overrides"] = "experiment=cpu"  # wdss.eval copies its training's
    own = run("eval epoch015.ckpt · data/mini", {**trained, "data_root": "data/mini"}, 32.1, training, 2)
    held = run("eval epoch015.ckpt · data/heldout", {**trained, "data_root": "data/heldout"}, 27.0, training, 3)
    baseline = {"model": "joint_bilateral", "transform": "n/a (baseline)", "basis": "n/a (baseline)", "seed": "0"}
    jb_mini = run("experiment=cpu,model=joint_bilateral", {**baseline, "data_root": "data/mini"}, 31.5, start=4)
    jb_held = run("experiment=cpu,model=joint_bilateral", {**baseline, "data_root": "data/heldout"}, 26.7, start=5)
    parent = client.create_run(experiment, run_name="sweep x", tags={"sweep": "x"}, start_time=6).info.run_id
    return uri, training, own, held, jb_mini, jb_held, parent


def test_any_runs_make_one_table_a_row_per_configuration_and_data(tmp_path):
    uri, training, own, held, jb_mini, jb_held, _ = _adhoc_runs(tmp_path)
    out = report(runs=[held, jb_held, jb_mini, own], tracking_uri=uri, out_dir=tmp_path / "reports")
    assert out == tmp_path / "reports" / "runs"
    _, rows = body((out / "table.md").read_text())
    assert list(rows) == [
        "SWT-db4, model=default · data/heldout",
        "Joint bilateral · data/heldout",
        "SWT-db4, model=default · data/mini",
        "Joint bilateral · data/mini",
    ]
    assert [cells[0] for cells in rows.values()] == ["**27.00 ± n/a**", "26.70 ± n/a", "**32.10 ± n/a**", "31.50 ± n/a"]
    # An experiment's runs with test metrics (the sweep parent has none), narrowed by a filter.
    out = report(experiment="wdss", filter_string="tags.data_root = 'data/heldout'", tracking_uri=uri, out_dir=tmp_path)
    _, rows = body((out / "table.md").read_text())
    assert set(rows) == {"SWT-db4, model=default", "Joint bilateral"} and out.name == "wdss"


def test_a_parent_whose_children_read_other_data_is_not_averaged_as_seeds(tmp_path):
    uri, training, own, held, *_ = _adhoc_runs(tmp_path)
    listed = r"data/heldout \(1 run\), data/mini \(1 run\)"
    with pytest.raises(SystemExit, match=rf"read different data \({listed}\).*--runs"):
        report(parent=training, tracking_uri=uri, out_dir=tmp_path)
    with pytest.raises(SystemExit, match="no run nope"):
        report(runs=["nope"], tracking_uri=uri, out_dir=tmp_path)


# The methods at 3x: two parameter-free kernels (0 GFLOPs counted) and two networks, each run timed by a process of
# its own on the training machine; seeds: 3 for SWT-db4 (drawn intervals), 2 for DFASR (none), 1 for the kernels.
COST_ROWS = {  # variant: (ms/frame, GFLOPs, PSNR per seed)
    "bicubic": (0.5, 0.0, (24.0,)),
    "joint_bilateral": (3.0, 0.0, (26.0,)),
    "swt_db4": (450.0, 4.2, (29.5, 29.9, 29.7)),
    "dfasr": (800.0, 9.8, (28.0, 28.6)),
}
OWN_DEVICE = {"bench/device": "cpu: Test CPU (2 threads)", "bench/resolution": "960x540 output, 2x"}
RUNTIME_DEVICE = {"bench/device": "cuda: NVIDIA H100", "bench/resolution": "1920x1080 output, 2x"}


@pytest.fixture(scope="module")
def timed(tmp_path_factory):
    """A methods sweep whose runs timed themselves, and a runtime sweep that timed three of its rows in one process."""
    root = tmp_path_factory.mktemp("timed")
    jobs, tags = [], []
    for variant, (ms, gflops, psnrs) in COST_ROWS.items():
        for seed, psnr in enumerate(psnrs):
            metrics = {"test/psnr_3x": psnr, "bench/ms_per_frame": ms + seed, "bench/gflops": gflops}
            jobs.append(({"variant": variant, "seed": str(seed)}, metrics, "FINISHED"))
            tags.append({**OWN_DEVICE, "bench/process": f"trainer:{len(jobs)}:x"})
    uri = fake_sweep(root, "methods", jobs, tags, old=False)
    timings = {"bicubic": (0.2, 0.0), "swt_db4": (5.0, 4.2), "dfasr": (9.0, 9.8)}  # joint_bilateral not timed
    runtime = [
        ({"variant": v, "model": "paper"}, {"bench/ms_per_frame": ms, "bench/gflops": g}, "FINISHED")
        for v, (ms, g) in timings.items()
    ]
    fake_sweep(root, "runtime", runtime, [{**RUNTIME_DEVICE, "bench/process": "gpu:7:y"}] * 3, old=False)
    return root, uri


def _summary(uri, sweep):
    from mlflow import MlflowClient

    from wdss.report import collect, find_parent, group, summarise

    client = MlflowClient(uri)
    groups = group(collect(client, find_parent(client, sweep).info.run_id))
    return client, groups, summarise(groups)[0]


def test_runtime_from_runs_that_timed_themselves_says_so_and_names_device_and_size(timed):
    from wdss.report import costs, tradeoff_plot

    root, uri = timed
    text = (report("methods", tracking_uri=uri, out_dir=root / "own") / "table.md").read_text()
    assert "ms/frame from each run's own timing: 7 different processes timed these rows" in text
    assert "--runtime runtime" in text  # how to get a fair comparison
    _, groups, metrics = _summary(uri, "methods")
    cost = costs(groups, metrics)
    assert cost.ms_label == "ms / frame (cpu: Test CPU (2 threads); 960x540 output, 2x)"
    figure = tradeoff_plot(list(groups), metrics, root / "own.png", "3x", cost)
    assert figure.axes[0].get_xlabel() == cost.ms_label and "different processes" in figure.texts[0].get_text()


def test_runtime_from_a_runtime_sweep_is_one_process_timing_every_row(timed):
    from wdss.report import costs, runtime_runs, tradeoff_plot

    root, uri = timed
    text = (report("methods", tracking_uri=uri, out_dir=root / "swept", runtime="runtime") / "table.md").read_text()
    one = "ms/frame from the runtime sweep runtime, matched to the rows by configuration name: one process timed "
    assert one + "every row (cuda: NVIDIA H100)." in text
    assert "No configuration of runtime matches Joint bilateral: left out of both panels." in text
    client, groups, metrics = _summary(uri, "methods")
    cost = costs(groups, metrics, runtime_runs(client, "runtime"), "runtime")
    assert {row: cell[0] for row, cell in cost.ms.items()} == {"Bicubic": 0.2, "SWT-db4": 5.0, "DFASR": 9.0}
    assert cost.ms_label == "ms / frame (cuda: NVIDIA H100; 1920x1080 output, 2x)"
    figure = tradeoff_plot(list(groups), metrics, root / "swept.png", "3x", cost)
    [psnr_ms] = [ax for ax in figure.axes if ax.get_xlabel() == cost.ms_label and "PSNR" in ax.get_ylabel()]
    assert sorted(x for c in psnr_ms.containers for x in c.lines[0].get_xdata()) == [0.2, 5.0, 9.0]
    with pytest.raises(SystemExit, match="no sweep named 'nope'"):
        runtime_runs(client, "nope")
    header, rows = body((report("runtime", tracking_uri=uri, out_dir=root / "runtime") / "table.md").read_text())
    assert header == ["Configuration", "ms/frame ↓", "GFLOPs ↓", "n"]  # the runtime sweep's own table
    assert rows["Bicubic"][1] == "not counted" and rows["SWT-db4"][1] == "**4.2 ± n/a**"  # 0 is no best


def test_uncounted_flops_are_left_out_and_named_intervals_need_three_values_costs_over_decades_are_log(timed):
    from wdss.report import costs, tradeoff_plot

    root, uri = timed
    _, groups, metrics = _summary(uri, "methods")
    cost = costs(groups, metrics)
    assert set(cost.gflops) == {"SWT-db4", "DFASR"} and set(cost.ms) == set(groups)
    assert any(note.startswith("FLOPs not counted for Bicubic; Joint bilateral (0 GFLOPs") for note in cost.notes)
    figure = tradeoff_plot(list(groups), metrics, root / "flops.png", "3x", cost)
    by_label = {(ax.get_xlabel().split(" (")[0], ax.get_ylabel().split(" @")[0]): ax for ax in figure.axes[:5]}
    psnr_ms, psnr_flops = by_label["ms / frame", "PSNR (dB)"], by_label["GFLOPs / frame", "PSNR (dB)"]
    assert [c.get_label() for c in psnr_flops.containers] == ["SWT-db4", "DFASR"]  # no 0-GFLOPs point on the axis
    drawn = {c.get_label(): c.has_yerr for c in psnr_ms.containers}
    assert drawn == {"Bicubic": False, "Joint bilateral": False, "SWT-db4": True, "DFASR": False}  # n = 1, 1, 3, 2
    assert psnr_ms.get_xscale() == "log" and psnr_flops.get_xscale() == "linear"  # 0.5-800 ms; 4.2-9.8 GFLOPs


def test_frames_plot_lines_of_equal_values_stay_apart(tmp_path):
    from wdss.report import frames_plot

    jobs = [({"variant": v, "seed": "0"}, {"test/psnr_3x": 28.0}, "FINISHED") for v in ("bicubic", "dfasr", "nsrr")]
    uri = fake_sweep(tmp_path, "methods", jobs)
    client, groups, _ = _summary(uri, "methods")
    for runs in groups.values():
        for frame in range(1, 6):  # every row the same values: one line would hide the others
            client.log_metric(runs[0].info.run_id, "frames/test_000/psnr_3x", 28 + frame / 10, step=frame)
    _, groups, _ = _summary(uri, "methods")
    figure = frames_plot(client, groups, tmp_path / "frames.png", "3x")
    lines = [line for line in figure.axes[0].get_lines() if line.get_label() in groups]
    assert len(lines) == 3
    assert len({(line.get_marker(), line.get_linestyle()) for line in lines}) == 3
    assert len({tuple(line.get_xdata()) for line in lines}) == 3  # shifted sideways, a fraction of a frame
    assert all(abs(x - round(x)) <= 0.15 + 1e-9 for line in lines for x in line.get_xdata())


def test_each_row_is_stated_over_the_learned_kernel_alone_and_the_orderings_at_every_scale(tmp_path):
    psnr = {"learned_bilateral": (29.0, 29.3, 29.1), "none": (29.2, 29.4, 29.5), "swt_db4": (29.9, 30.4, 30.0)}
    jobs = [
        (
            {"variant": v, "seed": str(s)},
            {"test/psnr_2x": psnr[v][s], "test/psnr_4x": psnr[v][s] - 3 + (v != "none")},
            "",
        )
        for v in psnr
        for s in SEEDS
    ]
    uri = fake_sweep(tmp_path, "ablation_wavelet", [(job, metrics, "FINISHED") for job, metrics, _ in jobs])
    text = (report("ablation_wavelet", tracking_uri=uri, out_dir=tmp_path / "reports") / "table.md").read_text()
    lines = text[text.index("Each row minus the learned kernel alone") :].splitlines()
    rows = {cells[0]: cells[1:] for cells in ([c.strip() for c in line.strip("|").split("|")] for line in lines[4:6])}
    assert lines[2] == "| | 2x | 4x |"
    for variant, label in (("swt_db4", "SWT-db4"), ("none", "No wavelet")):
        at_2x = [a - b for a, b in zip(psnr[variant], psnr["learned_bilateral"], strict=True)]
        assert rows[label][0] == f"{np.mean(at_2x):+.2f} ± {t_half_width(at_2x):.2f}, n=3"
    assert rows["No wavelet"][1].startswith(f"{np.mean([0.2, 0.1, 0.4]) - 1:+.2f} ± ")  # its own 4x offset
    assert "Learned bilateral" not in rows and len(rows) == 2
    assert "The paper's orderings at 2x" in text and "The paper's orderings at 4x" in text


def test_a_sweep_tag_that_names_a_path_writes_only_under_out(tmp_path):
    """The report's folder comes from the parent run's ``sweep`` tag, which anyone who logs to the store sets."""
    from wdss.report import path_component

    jobs = [({"variant": "swt_db4", "seed": "0"}, {"test/psnr_3x": 30.0}, "FINISHED")]
    uri = fake_sweep(tmp_path, "../../escaped", jobs)
    out = report("../../escaped", tracking_uri=uri, out_dir=tmp_path / "reports")
    assert out.parent == tmp_path / "reports" and out.name == "escaped"
    assert not (tmp_path.parent / "escaped").exists()
    assert [path_component(n) for n in ("/etc/x", "..", "ablation_wavelet", "a b")] == ["etc_x", "report"] + [
        "ablation_wavelet",
        "a_b",
    ]
