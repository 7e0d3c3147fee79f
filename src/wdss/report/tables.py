"""The report's tables: the compact paper-style markdown table at one scale, the full CSV, and the notes below
the table (the metric path, the targets' noise ceiling)."""

from __future__ import annotations

import csv
import io
import math
from collections.abc import Sequence

# The compact table's columns: metric, heading, decimals, higher is better (None: closest to 1 is, for a ratio to
# the ground truth). Cost columns stand in for the quality ones in a sweep that tests nothing (the runtime figure).
QUALITY = (
    ("psnr", "PSNR", 2, True),
    ("ssim", "SSIM", 4, True),
    ("flip", "FLIP", 4, False),
    ("lpips", "LPIPS", 4, False),
    ("twe_ratio", "tWE / target's", 3, None),
    ("tpsnr", "tPSNR", 2, True),
)
COST = (
    ("bench/ms_per_frame", "ms/frame", 1, False),
    ("bench/gflops", "GFLOPs", 1, False),
    ("bench/params_m", "params (M)", 3, False),
)


def table_scale(paper: str | None, scales: Sequence[str], requested: str | None = None) -> str:
    """The table's scale: the one asked for, the sweep's only one, else its paper table's (``paper``: the sweep
    file's ``report.scale``), else 2x where tested."""
    if requested:
        if requested in scales or (requested == "avg" and len(scales) > 1):
            return requested
        raise SystemExit(f"wdss.report: no test metrics at {requested!r}; this sweep has {', '.join(scales) or 'none'}")
    if len(scales) <= 1:
        return scales[0] if scales else "2x"
    if paper in scales or paper == "avg":
        return paper
    return "2x" if "2x" in scales else scales[0]


def scale_words(scale: str, scales: Sequence[str]) -> str:
    return f"mean of {'/'.join(scales)}" if scale == "avg" else scale


_ARROWS = {True: "↑", False: "↓", None: "→1"}
TEMPORAL_NOTE = (
    "\ntWE / target's: the mean change between consecutive frames after warping by the motion vectors, over the "
    "target's own (1: as stable as the ground truth; above: flicker the target does not have; below: smoother than "
    "the truth). tPSNR: PSNR of the frame differences against the target's.\n"
)


def compact_columns(metrics, scale: str, scales: Sequence[str]) -> list[tuple[str, str, int, bool]]:
    """(metric key, heading, decimals, higher is better) of the compact table, only what the runs logged."""

    def logged(key: str) -> bool:
        return any(key in m for m in metrics.values())

    columns = [
        (f"test/{name}_{scale}", f"{heading} {_ARROWS[higher]}", decimals, higher)
        for name, heading, decimals, higher in QUALITY
        if logged(f"test/{name}_{scale}")
    ]
    if columns and len(scales) > 1 and scale != "avg" and logged("test/psnr_avg"):
        columns.append(("test/psnr_avg", f"PSNR {scale_words('avg', scales)} ↑", 2, True))
    if not columns:  # nothing tested (a runtime sweep): its cost is the table
        columns = [(key, f"{heading} ↓", decimals, higher) for key, heading, decimals, higher in COST if logged(key)]
    return columns


def _fixed(value: float, decimals: int) -> str:
    """``value`` to ``decimals`` places, or to its first significant digit when those would show 0."""
    if value > 0 and round(value, decimals) == 0:
        decimals = 1 - math.floor(math.log10(value))
    return f"{value:.{decimals}f}"


def _score(value: float, higher: bool | None) -> float:
    """Larger is better: the value, its negative, or (a ratio to the ground truth's) minus its log distance to 1."""
    if higher is None:
        return -abs(math.log(value)) if value > 0 else -math.inf
    return value if higher else -value


def compact_table(
    rows: Sequence[str], metrics, notes: dict[str, str], columns, scales: Sequence[str], blocks=None
) -> str:
    """The paper-style markdown table: ``mean ± half-width`` (``n/a`` with one seed), the best per column bold
    (among the rows of one block, ``blocks[row]``: rows of different data are not compared)."""
    blocks = blocks or {}
    cells: dict[str, list[str]] = {row: [] for row in rows}
    for key, _, decimals, higher in columns:
        means: dict[str, float] = {}
        for row in rows:
            mean, half, n = metrics[row].get(key, (float("nan"), float("nan"), 0))
            row_scales = [s for s in scales if f"test/psnr_{s}" in metrics[row]]
            if key.endswith("_avg") and row_scales and row_scales != list(scales):
                cells[row].append(f"n/a (only {'/'.join(row_scales)})")  # not comparable with the full mean
            elif n == 0 or not math.isfinite(mean):
                cells[row].append("missing")
            elif key == "bench/gflops" and mean <= 0:  # torch's counter saw no matrix product or convolution
                cells[row].append("not counted")
            else:
                half_text = _fixed(half, decimals) if n > 1 and math.isfinite(half) else "n/a"
                cells[row].append(f"{mean:.{decimals}f} ± {half_text}")
                means[row] = round(mean, decimals)
        for block in {blocks.get(row) for row in means}:
            score = {row: _score(mean, higher) for row, mean in means.items() if blocks.get(row) == block}
            if len(score) < 2:
                continue
            best = max(score.values())  # bold the best shown value, ties included
            for row, value in score.items():
                if value == best:
                    cells[row][-1] = f"**{cells[row][-1]}**"
    with_notes = any(notes.get(row) for row in rows)
    header = ["Configuration", *(heading for _, heading, _, _ in columns), "n", *(["note"] if with_notes else [])]
    lines = ["| " + " | ".join(header) + " |", "|" + "---|" * len(header)]
    for row in rows:
        n = max((metrics[row].get(key, (0, 0, 0))[2] for key, *_ in columns), default=0)
        note = [notes.get(row, "")] if with_notes else []
        lines.append("| " + " | ".join([row, *cells[row], str(n), *note]) + " |")
    return "\n".join(lines) + "\n"


def full_csv(rows: Sequence[str], metrics, notes: dict[str, str]) -> str:
    """Every metric of every row: mean, 95% half-width (empty below two seeds) and n."""
    keys = sorted({k for m in metrics.values() for k in m})
    out = io.StringIO()
    writer = csv.writer(out, lineterminator="\n")
    writer.writerow(["configuration", "seeds", "note", *(f"{k}{part}" for k in keys for part in ("", " ci95", " n"))])
    for row in rows:
        values = []
        for key in keys:
            mean, half, n = metrics[row].get(key, (float("nan"), float("nan"), 0))
            values += [
                repr(mean) if math.isfinite(mean) else "",  # full precision: the data, not a display
                repr(half) if n > 1 and math.isfinite(half) else "",
                n,
            ]
        seeds = max((s[2] for s in metrics[row].values()), default=0)
        writer.writerow([row, seeds, notes.get(row, ""), *values])
    return out.getvalue()


def metric_path(runs: Sequence) -> str:
    """How the metrics were measured, as the runs' parameters say: the tone map and its exposure."""
    from wdss.ops.tonemap import DEFAULT_EXPOSURE

    paths = set()
    for run in runs:
        params = run.data.params
        name = params.get("model.tonemap_name", params.get("tonemap_name", "hable"))
        exposure = params.get("tonemap_exposure", "None")
        if exposure in ("None", ""):
            exposure = f"exposure {DEFAULT_EXPOSURE.get(name, 1.0):g} (the curve's default)"
        elif exposure == "auto":
            exposure = "exposure auto (per image, from the target's median luminance)"
        else:
            exposure = f"exposure {exposure}"
        paths.add(f"{name.capitalize()}, {exposure}")
    return "; ".join(sorted(paths))


def noise_ceiling_note(runs: Sequence) -> str:
    """The targets' noise ceiling of the test sequences, as the runs logged it (``test/noise_ceiling*``: the PSNR a
    perfect method would score against these targets, :mod:`wdss.render.noise`), or why there is none."""
    found = set()
    for run in runs:
        metrics = run.data.metrics
        if "test/noise_ceiling" in metrics:
            per = sorted(
                (k.removeprefix("test/noise_ceiling_"), v)
                for k, v in metrics.items()
                if k.startswith("test/noise_ceiling_")
            )
            found.add((round(metrics["test/noise_ceiling"], 2), tuple((name, round(v, 2)) for name, v in per)))
    if not found:
        return (
            "\nTargets' noise ceiling: not measured for these test sequences (render them with noise_ceiling: true, "
            "or python -m wdss.bench noise --record).\n"
        )
    sets = [
        f"{mean:.2f} dB mean" + (f" ({', '.join(f'{name} {v:.2f}' for name, v in per)})" if per else "")
        for mean, per in sorted(found)
    ]
    return (
        "\nTargets' noise ceiling (the PSNR a perfect method would score against these targets; no row can exceed it): "
        + "; ".join(sets)
        + (" -- the runs tested different data" if len(sets) > 1 else "")
        + ".\n"
    )
