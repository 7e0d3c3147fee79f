"""Render progress in a log: one flushed line per finished frame when stdout is not a terminal."""

from __future__ import annotations

from wdss.progress import duration
from wdss.render import sequence


def test_a_log_gets_a_line_per_frame_with_the_rate_and_the_time_left(capsys, monkeypatch):
    clock = iter([100.0, 104.0, 109.0, 200.0, 230.0])
    monkeypatch.setattr(sequence.time, "perf_counter", lambda: next(clock))
    with sequence._LineProgress() as progress:
        task = progress.add_task("train_000", total=25, completed=0)
        progress.advance(task)  # 4 s for the first frame (the scene's set-up included)
        progress.advance(task)
        resumed = progress.add_task("val_000", total=100, completed=40)
        progress.advance(resumed)  # only this run's frames count towards the rate
    assert capsys.readouterr().out.splitlines() == [
        "render train_000: frame 1/25 (4.0 s/frame, ETA 1m36s)",
        "render train_000: frame 2/25 (4.5 s/frame, ETA 1m44s)",
        "render val_000: 40/100 frames already on disk",
        "render val_000: frame 41/100 (30.0 s/frame, ETA 29m30s)",
    ]


def test_durations_read_at_a_glance():
    assert [duration(s) for s in (0, 45.4, 92, 3600 + 125)] == ["0s", "45s", "1m32s", "1h02m"]
