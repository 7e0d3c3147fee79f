"""The trade-off plot's costs: each run's own timing, or one runtime sweep's, and FLOPs that were not counted."""

from __future__ import annotations

import pytest

from tests.report.sweeps import body, fake_sweep, summary_of
from wdss.report.write import report

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


def test_runtime_from_runs_that_timed_themselves_says_so_and_names_device_and_size(timed):
    from wdss.report.costs import costs
    from wdss.report.plots import tradeoff_plot

    root, uri = timed
    text = (report("methods", tracking_uri=uri, out_dir=root / "own") / "table.md").read_text()
    assert "ms/frame from each run's own timing: 7 different processes timed these rows" in text
    assert "--runtime runtime" in text  # how to get a fair comparison
    _, groups, metrics = summary_of(uri, "methods")
    cost = costs(groups, metrics)
    assert cost.ms_label == "ms / frame (cpu: Test CPU (2 threads); 960x540 output, 2x)"
    figure = tradeoff_plot(list(groups), metrics, root / "own.png", "3x", cost)
    assert figure.axes[0].get_xlabel() == cost.ms_label and "different processes" in figure.texts[0].get_text()


def test_runtime_from_a_runtime_sweep_is_one_process_timing_every_row(timed):
    from wdss.report.costs import costs
    from wdss.report.plots import tradeoff_plot
    from wdss.report.runs import runtime_runs

    root, uri = timed
    text = (report("methods", tracking_uri=uri, out_dir=root / "swept", runtime="runtime") / "table.md").read_text()
    one = "ms/frame from the runtime sweep runtime, matched to the rows by configuration name: one process timed "
    assert one + "every row (cuda: NVIDIA H100)." in text
    assert "No configuration of runtime matches Joint bilateral: left out of both panels." in text
    client, groups, metrics = summary_of(uri, "methods")
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
    from wdss.report.costs import costs
    from wdss.report.plots import tradeoff_plot

    root, uri = timed
    _, groups, metrics = summary_of(uri, "methods")
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
