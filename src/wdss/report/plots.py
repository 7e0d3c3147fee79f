"""The report's figures: the error-vs-cost trade-off, the qualitative crops, and PSNR per frame."""

from __future__ import annotations

import math
import statistics
import tempfile
from collections import defaultdict
from collections.abc import Sequence
from pathlib import Path

from wdss.report.costs import Costs, costs
from wdss.report.summary import Cell

# Each row of a plot its own marker (and in frames.png its own dash and a small sideways offset): rows of equal
# values stay visible.
MARKERS = ("o", "s", "^", "v", "D", "P", "X", "*", "<", ">", "h", "p")
DASHES = ("-", "--", "-.", ":")
FRAME_SPREAD = 0.3  # the offsets span this much of a frame


def pareto(points: list[tuple[float, float]], higher_is_better: bool) -> list[int]:
    """Indices of the points no other point beats in both cost (lower) and quality."""
    front = []
    for i, (cost, quality) in enumerate(points):
        dominated = any(
            (c <= cost and (q >= quality if higher_is_better else q <= quality)) and (c, q) != (cost, quality)
            for c, q in points
        )
        if not dominated:
            front.append(i)
    return front


def _decades(values: Sequence[float]) -> bool:
    """Values that span a factor of ten or more: a linear axis would crush the small ones together."""
    positive = [v for v in values if math.isfinite(v) and v > 0]
    return len(positive) > 1 and max(positive) / min(positive) >= 10


MIN_N_FOR_INTERVAL = 3  # two seeds give a t-interval 12.7 standard errors wide: drawn, it says nothing


def _error(cell: Cell) -> float:
    """The half-width drawn for a cell: none below ``MIN_N_FOR_INTERVAL`` values."""
    return cell[1] if cell[2] >= MIN_N_FOR_INTERVAL and math.isfinite(cell[1]) else 0.0


def _training_time_panel(ax, rows, metrics) -> None:
    """Each row's training wall-clock, a bar per row in its colour (intervals only for n >= 3)."""
    times = [metrics[row].get("time/train_s", (float("nan"), float("nan"), 0)) for row in rows]
    means = [t[0] / 60 if math.isfinite(t[0]) else 0.0 for t in times]
    errors = [min(_error(t) / 60, m) for t, m in zip(times, means, strict=True)]
    ax.barh(rows, means, xerr=errors, color=[f"C{i % 10}" for i in range(len(rows))])
    ax.set_xlabel("training wall-clock (min), mean over seeds")
    if not any(means):
        ax.set_xticks([])
        ax.text(0.5, 0.5, "no training time logged", ha="center", transform=ax.transAxes)


def tradeoff_plot(rows, metrics, path: Path, scale: str, cost: Costs | None = None):
    """PSNR and FLIP against ms/frame and GFLOPs (log-x where the costs span decades), the Pareto front marked,
    intervals only for n >= 3, the training wall-clock beside; the caption says where the costs come from. Returns
    the (closed) figure."""
    import textwrap

    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    from matplotlib.lines import Line2D

    cost = cost or costs({row: [] for row in rows}, metrics)
    # A row keeps its colour and marker in every panel, named once in the legend (labels beside close points
    # would overlap).
    styles = {row: (f"C{i % 10}", MARKERS[i % len(MARKERS)]) for i, row in enumerate(rows)}
    panels = [(cost.ms, cost.ms_label), (cost.gflops, cost.gflops_label)]
    qualities = [(f"test/psnr_{scale}", "PSNR (dB)", True), (f"test/flip_{scale}", "FLIP", False)]
    caption = "\n".join(textwrap.fill(note, 190) for note in cost.notes)
    lines = caption.count("\n") + 1 if caption else 0
    fig, axes = plt.subplots(2, 3, figsize=(15, 8 + 0.16 * lines))
    for r, (quality, qlabel, higher) in enumerate(qualities):
        for c, (values, clabel) in enumerate(panels):
            ax = axes[r, c]
            points, labels = [], []
            for row in rows:
                m = metrics[row]
                if row in values and quality in m and math.isfinite(values[row][0]) and math.isfinite(m[quality][0]):
                    x, y = values[row][0], m[quality][0]
                    points.append((x, y))
                    labels.append(row)
                    colour, marker = styles[row]
                    ax.errorbar(x, y, yerr=_error(m[quality]) or None, fmt=marker, capsize=3, color=colour, label=row)
            if not points:
                ax.text(
                    0.5,
                    0.5,
                    f"no {clabel} logged in these runs"
                    if not values
                    else f"no {qlabel} logged in these runs"
                    if not any(quality in metrics[row] for row in rows)
                    else f"no row has both {qlabel} and {clabel.split(' (')[0]}",
                    ha="center",
                    va="center",
                    transform=ax.transAxes,
                    fontsize=9,
                )
            front = sorted((points[i] for i in pareto(points, higher)), key=lambda p: p[0])
            if front:
                ax.plot(*zip(*front, strict=True), "--", color="gray", label="Pareto front", zorder=0)
            if _decades([x for x, _ in points]):
                ax.set_xscale("log")
            ax.set_xlabel(clabel, fontsize=8)
            ax.set_ylabel(f"{qlabel} @ {scale}")
            ax.grid(alpha=0.3, which="both")
        ax = axes[r, 2]
        if r == 0:
            _training_time_panel(ax, rows, metrics)
        else:
            ax.axis("off")
            handles = [
                Line2D([], [], color=colour, marker=marker, linestyle="none", label=row)
                for row, (colour, marker) in styles.items()
            ]
            handles.append(Line2D([], [], color="gray", linestyle="--", label="Pareto front"))
            ax.legend(handles=handles, loc="upper left", fontsize=8, frameon=False)
    if caption:
        fig.text(0.01, 0.005, caption, fontsize=7.5, va="bottom", ha="left")
    fig.tight_layout(rect=(0, 0.02 + 0.16 * lines / fig.get_figheight(), 1, 1))
    fig.savefig(path, dpi=110)
    plt.close(fig)
    return fig


def qualitative_figure(client, groups: dict[str, list], path: Path, scale: str) -> bool:
    """The same centre crop (the videos' crop, :data:`wdss.video.CROP`) of the first three test frames of one run
    of every row and of the target: a column per configuration, a row per frame (old runs: the first frame only)."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    from PIL import Image

    from wdss.video import centre_box

    suffixes = ("", "_t1", "_t2")  # frames t, t+1, t+2 (wdss.training.module.SuperResolutionModule.test_step)
    images: dict[str, list] = {}
    target: list = []
    with tempfile.TemporaryDirectory() as tmp:
        for row, runs in groups.items():
            run = next((r for r in runs if r.info.status == "FINISHED"), None)
            if run is None:
                continue
            frames, references = [], []
            for suffix in suffixes:
                try:
                    pred = client.download_artifacts(run.info.run_id, f"test/pred_{scale}{suffix}.png", tmp)
                    frames.append(Image.open(pred).convert("RGB").copy())
                    if not target:
                        ref = client.download_artifacts(run.info.run_id, f"test/target_{scale}{suffix}.png", tmp)
                        references.append(Image.open(ref).convert("RGB").copy())
                except Exception:  # fewer frames (an older run), or none (bench-only, failed before testing)
                    break
            if frames:
                images[row] = frames
                target = target or references
    if not images or not target:
        return False
    count = min(len(target), *(len(frames) for frames in images.values()))
    width, height = target[0].size
    top, left, side = centre_box(height, width)
    box = (left, top, left + side, top + side)
    panels = [*images.items(), ("target", target)]
    fig, axes = plt.subplots(count, len(panels), figsize=(2.4 * len(panels), 2.5 * count + 0.3), squeeze=False)
    for column, (label, frames) in enumerate(panels):
        for t in range(count):
            ax = axes[t, column]
            ax.imshow(frames[t].crop(box), interpolation="nearest")
            ax.set_xticks([])
            ax.set_yticks([])
            if t == 0:
                ax.set_title(label, fontsize=8)
            if column == 0:
                ax.set_ylabel(f"frame t{f'+{t}' if t else ''}", fontsize=8)
    fig.tight_layout()
    fig.savefig(path, dpi=120)
    plt.close(fig)
    return True


def frames_plot(client, groups: dict[str, list], path: Path, scale: str):
    """PSNR against frame index over the first test sequence (by name), a line per row: the mean over its
    finished runs of the ``frames/<sequence>/psnr_<scale>`` histories that the test logs. Each line has its own
    marker (hollow) and dash and is shifted sideways by a fraction of a frame, so that no line hides another.
    Returns the (closed) figure, or None without per-frame metrics."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    suffix = f"/psnr_{scale}"
    keys = sorted(
        key
        for runs in groups.values()
        for run in runs
        for key in run.data.metrics
        if key.startswith("frames/") and key.endswith(suffix)
    )
    if not keys:
        return None
    key = keys[0]
    curves = {}
    for row, runs in groups.items():
        by_frame: dict[int, list[float]] = defaultdict(list)
        for run in runs:
            if run.info.status == "FINISHED" and key in run.data.metrics:
                for metric in client.get_metric_history(run.info.run_id, key):
                    by_frame[metric.step].append(metric.value)
        if by_frame:
            curves[row] = {frame: statistics.fmean(values) for frame, values in sorted(by_frame.items())}
    fig, ax = plt.subplots(figsize=(8, 4.5))
    count = len(curves)
    for i, (row, curve) in enumerate(curves.items()):
        shift = (i - (count - 1) / 2) * FRAME_SPREAD / max(count - 1, 1)
        ax.plot(
            [frame + shift for frame in curve],
            list(curve.values()),
            marker=MARKERS[i % len(MARKERS)],
            linestyle=DASHES[(i // len(MARKERS) + i) % len(DASHES)],
            markerfacecolor="none",
            markersize=5,
            linewidth=1.2,
            label=row,
        )
    ax.xaxis.get_major_locator().set_params(integer=True)
    ax.set_xlabel(
        "frame" + (f" (lines shifted by up to ±{FRAME_SPREAD / 2:g} frame to stay apart)" if count > 1 else "")
    )
    ax.set_ylabel(f"PSNR (dB) @ {scale}")
    ax.set_title(f"per-frame PSNR, test sequence {key.split('/')[1]}", fontsize=9)
    ax.grid(alpha=0.3)
    ax.legend(fontsize=7)
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)
    return fig
