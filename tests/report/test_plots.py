"""The report's figures: per-frame PSNR lines that stay apart."""

from __future__ import annotations

from tests.report.sweeps import fake_sweep, summary_of


def test_frames_plot_lines_of_equal_values_stay_apart(tmp_path):
    from wdss.report.plots import frames_plot

    jobs = [({"variant": v, "seed": "0"}, {"test/psnr_3x": 28.0}, "FINISHED") for v in ("bicubic", "dfasr", "nsrr")]
    uri = fake_sweep(tmp_path, "methods", jobs)
    client, groups, _ = summary_of(uri, "methods")
    for runs in groups.values():
        for frame in range(1, 6):  # every row the same values: one line would hide the others
            client.log_metric(runs[0].info.run_id, "frames/test_000/psnr_3x", 28 + frame / 10, step=frame)
    _, groups, _ = summary_of(uri, "methods")
    figure = frames_plot(client, groups, tmp_path / "frames.png", "3x")
    lines = [line for line in figure.axes[0].get_lines() if line.get_label() in groups]
    assert len(lines) == 3
    assert len({(line.get_marker(), line.get_linestyle()) for line in lines}) == 3
    assert len({tuple(line.get_xdata()) for line in lines}) == 3  # shifted sideways, a fraction of a frame
    assert all(abs(x - round(x)) <= 0.15 + 1e-9 for line in lines for x in line.get_xdata())
