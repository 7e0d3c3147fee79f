"""Every metric of a row as the mean and 95% t-interval over its seeds, and the scales the runs tested."""

from __future__ import annotations

import math
import statistics
from collections import defaultdict

Cell = tuple[float, float, int]  # mean, 95% half-width, n


def interval(values: list[float]) -> tuple[float, float]:
    """Mean and half-width of the 95% t-interval of the finite values (NaN, undefined, below two values)."""
    finite = [v for v in values if math.isfinite(v)]
    if not finite:
        return float("nan"), float("nan")
    mean = statistics.fmean(finite)
    if len(finite) < 2:
        return mean, float("nan")
    from scipy.stats import t

    return mean, float(t.ppf(0.975, len(finite) - 1) * statistics.stdev(finite) / math.sqrt(len(finite)))


def summarise(groups: dict[str, list]) -> tuple[dict[str, dict[str, tuple[float, float, int]]], dict[str, str]]:
    """Per row, every metric as (mean, 95% half-width, n finite values); and a note per row about failed jobs."""
    metrics: dict[str, dict[str, tuple[float, float, int]]] = {}
    notes: dict[str, str] = {}
    for row, row_runs in groups.items():
        finished = [r for r in row_runs if r.info.status == "FINISHED"]
        failed = [r for r in row_runs if r.info.status != "FINISHED"]
        if failed:
            notes[row] = f"{len(failed)} of {len(row_runs)} jobs {'/'.join(sorted({r.info.status for r in failed}))}"
        values: dict[str, list[float]] = defaultdict(list)
        for run in finished:
            data = dict(run.data.metrics)
            per_scale: dict[str, list[float]] = defaultdict(list)
            for key, value in data.items():
                parsed = _scale_metric(key)
                if parsed:
                    per_scale[parsed[0]].append(value)
            for name, scaled in per_scale.items():
                data[f"test/{name}_avg"] = statistics.fmean(scaled)
            for key, value in data.items():
                values[key].append(value)
        metrics[row] = {k: (*interval(v), sum(math.isfinite(x) for x in v)) for k, v in values.items()}
    return metrics, notes


def _scale_metric(key: str) -> tuple[str, str] | None:
    """``test/psnr_3x`` -> ``("psnr", "3x")``; None for anything else."""
    if not key.startswith("test/") or "_" not in key or key.startswith("test/noise_ceiling"):
        return None
    name, scale = key[len("test/") :].rsplit("_", 1)
    return (name, scale) if scale.endswith("x") and scale[:-1].replace(".", "").isdigit() else None


def test_scales(metrics: dict[str, dict[str, tuple[float, float, int]]]) -> list[str]:
    """The scales the sweep tested (``2x``, ...), smallest first."""
    scales = {parsed[1] for m in metrics.values() for k in m if (parsed := _scale_metric(k)) and parsed[0] == "psnr"}
    return sorted(scales, key=lambda s: float(s[:-1]))
