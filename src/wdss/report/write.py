"""Paper-style reports from MLflow runs: ``python -m wdss.report --sweep NAME`` (or ``--parent RUN_ID``), or for
any runs: ``--runs ID [ID ...]`` or ``--experiment NAME [--filter "tags.model = 'joint_bilateral'"]``.

Reads the jobs of a sweep (the runs nested under its parent run), or the runs named, and writes, into
``outputs/reports/<sweep>/`` (``--name``; ``runs`` or the experiment's name for ad-hoc runs) and, for a sweep, as
artifacts of the parent run:

* ``table.md``: one compact table as the paper prints it: a row per configuration and data (the sweep's axes other
  than the seed, and the data root where the runs read several; named as the paper names its rows: ``SWT-db4``,
  ``No wavelet``, ``Bilinear (demod.)``), PSNR, SSIM,
  FLIP (and LPIPS when logged) and the temporal stability (the warping error's ratio to the target's own, best
  closest to 1, and the temporal PSNR; :mod:`wdss.training.temporal_metrics`) at the table's scale, each
  ``mean ± half-width`` of the 95% t-interval over the ``n`` seeds (``n/a`` with one seed), the best of each
  column in bold; a cell whose jobs failed says so instead of disappearing;
  below it, which of the paper's orderings hold at that scale (:data:`PAPER_ORDERINGS`: the PSNR difference of
  each claimed pair, paired by seed, with its 95% t-interval);
* ``table.csv``: every metric at every scale and their average over scales, as mean, 95% half-width and n;
* ``tradeoff.png``: PSNR and FLIP against ms/frame and against GFLOPs, the Pareto front marked, with the
  training wall-clock per configuration beside it; log-x where the costs span decades, intervals only for n >= 3.
  The costs are the runs' own or, with ``--runtime runtime``, those of the runtime sweep (:file:`sweeps/runtime.yaml`:
  one process times every configuration); the axes name the device and the size, and the caption (also below the
  table) says how many processes timed the rows and which rows have no counted FLOPs (left out of that panel);
* ``qualitative.png``: the same crop of the first three test frames from every configuration and the target;
* ``frames.png``: PSNR against frame index over the first test sequence, a line per configuration (the mean over
  its seeds; each its own marker and dash, shifted sideways by a fraction of a frame), so that the drift of
  recurrent models shows.
"""

from __future__ import annotations

import argparse
import csv
import io
import math
import os
import re
import statistics
import tempfile
from collections import Counter, defaultdict
from collections.abc import Sequence
from dataclasses import dataclass, field
from pathlib import Path

__all__ = ["collect", "find_runs", "main", "report"]

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
# Row names as the paper's tables print them, by variant (conf/variant) or, without one, by baseline model.
PAPER_LABELS = {
    "none": "No wavelet",
    "dwt_haar": "DWT-haar",
    "swt_haar": "SWT-haar",
    "swt_sym4": "SWT-sym4",
    "swt_db4": "SWT-db4",
    "fusion_ll": "Fusion-LL (SWT-haar)",
    "multi_inr": "Multi-INR (DWT-haar)",
    "fixed2x": "Single-scale (DWT-haar)",
    "bicubic": "Bicubic",
    "bilinear": "Bilinear",
    "bilinear_demodulated": "Bilinear (demod.)",
    "joint_bilateral": "Joint bilateral",
    "joint_bilateral_color": "Joint bilateral (colour)",
    "learned_bilateral": "Learned bilateral",
    "real_esrgan": "Real-ESRGAN",
    "real_esrgan_demodulated": "Real-ESRGAN (demod.)",
    "nsrr": "NSRR",
    "fusesr": "FuseSR",
    "dfasr": "DFASR",
}
# The scale a paper table reports when its sweep tests several: "avg" is the mean over the tested scales.
PAPER_SCALES = {"ablation_wavelet": "2x", "ablation_arch": "2x", "methods": "3x", "scales": "avg"}
# The paper's orderings by PSNR, as adjacent claims (lower, relation, higher) between variants: the report states
# which hold at the scale its table shows. Wavelet formulation: none < DWT-haar < SWT-haar < SWT-sym4 <= SWT-db4;
# methods: WDSS (SWT-db4) > DFASR > Real-ESRGAN > bicubic.
PAPER_ORDERINGS = {
    "ablation_wavelet": (
        ("none", "<", "dwt_haar"),
        ("dwt_haar", "<", "swt_haar"),
        ("swt_haar", "<", "swt_sym4"),
        ("swt_sym4", "<=", "swt_db4"),
    ),
    "methods": (("bicubic", "<", "real_esrgan"), ("real_esrgan", "<", "dfasr"), ("dfasr", "<", "swt_db4")),
}


def _client(uri: str | None):
    from mlflow import MlflowClient

    return MlflowClient(uri or os.environ.get("MLFLOW_TRACKING_URI", "sqlite:///mlflow.db"))


def find_parent(client, sweep: str | None = None, parent: str | None = None):
    """The parent run of a sweep: by id, or the newest parent run tagged with the sweep's name."""
    if parent:
        return client.get_run(parent)
    experiments = [e.experiment_id for e in client.search_experiments()]
    runs = client.search_runs(experiments, filter_string=f"tags.sweep = '{sweep}'", order_by=["start_time DESC"])
    parents = [r for r in runs if "mlflow.parentRunId" not in r.data.tags]
    if not parents:
        raise SystemExit(f"wdss.report: no sweep named {sweep!r} in {client.tracking_uri}")
    return parents[0]


def overrides(run) -> dict[str, str]:
    """A job's Hydra overrides: its tag ``overrides`` (``wdss.tracking.run_overrides``; an evaluation carries its
    training run's, so it is a row of that training), or for runs from before the tag, their name (then the job's
    ``override_dirname``); {} for a custom name or one that leads with the variant (``swt_db4 · seed0 · mini``)."""
    from wdss.tracking import NAME_SEPARATOR, split_overrides

    tags = run.data.tags
    if "overrides" in tags:
        text = tags["overrides"]
    else:
        text = tags.get("mlflow.runName", "")
        if NAME_SEPARATOR in text:
            return {}
    items = split_overrides(text)
    if any(value is None for _, value in items):
        return {}
    return dict(items)


def sweep_axes(runs: Sequence) -> list[str]:
    """The override keys whose value differs between the jobs (the sweep's axes), the seed left out."""
    jobs = [overrides(run) for run in runs]
    keys = sorted({key for job in jobs for key in job} - {"seed"})
    return [key for key in keys if len({job.get(key) for job in jobs}) > 1]


def base_label(tags: dict[str, str]) -> tuple[str, set[str]]:
    """The paper's name of a run's configuration, and the override keys that name already says."""
    if tags.get("variant"):
        return PAPER_LABELS.get(tags["variant"], tags["variant"]), {"variant"}
    transform, basis, model = tags.get("transform", ""), tags.get("basis", ""), tags.get("model", "")
    if transform.startswith("n/a") and model:  # a baseline: no wavelet, its model names it
        return PAPER_LABELS.get(model, model), {"model"}
    if transform == "none":
        return "No wavelet", {"transform", "basis"}
    if transform and basis:
        return f"{transform.upper()}-{basis}", {"transform", "basis"}
    return "default", set()


def configuration(run, axes: Sequence[str]) -> str:
    """A row's label: the paper's name, then every other axis of the sweep as ``key=value``."""
    label, said = base_label(_tags(run))
    job = overrides(run)
    return ", ".join([label, *(f"{key}={job.get(key, 'default')}" for key in axes if key not in said)])


def group(runs: Sequence) -> dict[str, list]:
    """The jobs of each configuration, rows in the order their first job started; where the runs read several data
    roots (tag ``data_root``), each row is also one data root."""
    axes = sweep_axes(runs)
    several = len({_tags(run).get("data_root") for run in runs}) > 1
    groups: dict[str, list] = defaultdict(list)
    for run in sorted(runs, key=lambda r: r.info.start_time):
        label = configuration(run, [a for a in axes if not (several and a == "data.root")])
        if several:
            label += f" · {_tags(run).get('data_root', 'unknown data')}"
        groups[label].append(run)
    if several:  # the rows of one data root together
        return dict(sorted(groups.items(), key=lambda item: _tags(item[1][0]).get("data_root", "")))
    return dict(groups)


def runtime_runs(client, runtime: str) -> list:
    """The jobs of a runtime sweep, by sweep name or parent run id."""
    from mlflow.exceptions import MlflowException

    try:
        parent = client.get_run(runtime)
    except MlflowException:
        parent = find_parent(client, sweep=runtime)
    jobs = collect(client, parent.info.run_id)
    if not any("bench/ms_per_frame" in run.data.metrics for run in jobs):
        raise SystemExit(f"wdss.report: the runtime sweep {runtime!r} ({parent.info.run_id}) has no timed job")
    return jobs


def collect(client, parent_id: str) -> list:
    experiment = client.get_run(parent_id).info.experiment_id
    return client.search_runs([experiment], filter_string=f"tags.mlflow.parentRunId = '{parent_id}'")


def _reported(run) -> bool:
    """A run with something to report: test metrics or a benchmark (not a sweep's parent, not a bare training)."""
    return any(key.startswith(("test/", "bench/")) for key in run.data.metrics)


def find_runs(client, ids: Sequence[str] = (), experiment: str | None = None, filter_string: str = "") -> list:
    """The runs named by id, or those of an experiment that match an MLflow filter; runs without test or bench
    metrics (sweep parents, trainings stopped before testing) are left out."""
    from mlflow.exceptions import MlflowException

    if ids:
        runs = []
        for run_id in ids:
            try:
                runs.append(client.get_run(run_id))
            except MlflowException:
                raise SystemExit(f"wdss.report: no run {run_id} in {client.tracking_uri}") from None
    else:
        found = client.get_experiment_by_name(experiment)
        if found is None:
            names = ", ".join(e.name for e in client.search_experiments())
            raise SystemExit(f"wdss.report: no experiment {experiment!r} in {client.tracking_uri} (it has: {names})")
        runs = client.search_runs([found.experiment_id], filter_string=filter_string, max_results=5000)
    reported = [run for run in runs if _reported(run)]
    if not reported:
        raise SystemExit("wdss.report: none of these runs has test or bench metrics")
    return reported


def check_one_dataset(parent_run, runs: Sequence) -> None:
    """Refuse to average a parent's children as seeds when they evaluated different data (a training run whose
    evaluations read other scenes): ``--runs`` reports them with a row per data root."""
    roots = Counter(_tags(run).get("data_root", "unknown") for run in runs)
    if len(roots) > 1:
        listed = ", ".join(f"{root} ({n} run{'s' * (n > 1)})" for root, n in sorted(roots.items()))
        ids = " ".join(run.info.run_id for run in runs)
        raise SystemExit(
            f"wdss.report: the runs under {parent_run.info.run_id} read different data ({listed}); they are not "
            f"seeds of one row: python -m wdss.report --runs {ids}"
        )


def path_component(name: str) -> str:
    """``name`` (a sweep's tag, which anyone who logs to the store can set) as one safe folder name: never a path
    that leaves ``--out`` (``../x``, ``/etc``), never hidden or empty."""
    safe = re.sub(r"[^\w.+=-]+", "_", name).strip("._")
    return safe or "report"


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


def _tags(run) -> dict[str, str]:
    return dict(run.data.tags)


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


def table_scale(sweep: str, scales: Sequence[str], requested: str | None = None) -> str:
    """The table's scale: the one asked for, the sweep's only one, else its paper table's (2x if unknown)."""
    if requested:
        if requested in scales or (requested == "avg" and len(scales) > 1):
            return requested
        raise SystemExit(f"wdss.report: no test metrics at {requested!r}; this sweep has {', '.join(scales) or 'none'}")
    if len(scales) <= 1:
        return scales[0] if scales else "2x"
    paper = PAPER_SCALES.get(sweep, "2x" if sweep.startswith("ablation") else None)
    if paper in scales or paper == "avg":
        return paper
    return "2x" if "2x" in scales else scales[0]


def _scale_words(scale: str, scales: Sequence[str]) -> str:
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
        columns.append(("test/psnr_avg", f"PSNR {_scale_words('avg', scales)} ↑", 2, True))
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


def _seed(run) -> str:
    return overrides(run).get("seed", run.data.tags.get("seed", "?"))


def _psnr(run, scale: str, scales: Sequence[str]) -> float:
    data = run.data.metrics
    if scale == "avg":
        values = [data.get(f"test/psnr_{s}", float("nan")) for s in scales]
        return statistics.fmean(values) if values else float("nan")
    return data.get(f"test/psnr_{scale}", float("nan"))


def orderings(sweep: str, groups: dict[str, list], scale: str, scales: Sequence[str]) -> str:
    """Which of the paper's orderings (:data:`PAPER_ORDERINGS`) hold, by the PSNR difference of each claimed pair
    on the seeds both rows finished (paired by seed), with its 95% t-interval; empty for a sweep without claims.

    A strict claim holds when the interval lies above zero and is reversed when it lies below; a ``<=`` claim holds
    unless the interval lies below zero. Otherwise the difference is within the seeds' spread: not resolved.
    """
    claims = PAPER_ORDERINGS.get(sweep)
    if not claims or not scales:
        return ""
    rows: dict[str, list[str]] = defaultdict(list)
    for row, row_runs in groups.items():
        variant = row_runs[0].data.tags.get("variant")
        if variant:
            rows[variant].append(row)
    label = "the mean over " + "/".join(scales) if scale == "avg" else scale
    lines = [f"\nThe paper's orderings at {label} (PSNR of the higher minus the lower row, paired by seed):\n"]
    for low, relation, high in claims:
        claim = f"{PAPER_LABELS.get(low, low)} {relation} {PAPER_LABELS.get(high, high)}"
        if len(rows.get(low, [])) != 1 or len(rows.get(high, [])) != 1:
            found = "not in this sweep" if not rows.get(low) or not rows.get(high) else "several rows per variant"
            lines.append(f"- {claim}: not tested ({found})")
            continue

        def by_seed(variant: str) -> dict[str, float]:
            runs = [r for r in groups[rows[variant][0]] if r.info.status == "FINISHED"]
            return {_seed(r): _psnr(r, scale, scales) for r in runs}

        lower, higher = by_seed(low), by_seed(high)
        seeds = sorted(set(lower) & set(higher))
        differences = [higher[seed] - lower[seed] for seed in seeds]
        mean, half = interval(differences)
        if not math.isfinite(mean):
            lines.append(f"- {claim}: not tested (no seed finished in both rows)")
            continue
        if not math.isfinite(half):
            verdict = f"not resolved (one seed, no interval; the sign {'agrees' if mean > 0 else 'disagrees'})"
            lines.append(f"- {claim}: {verdict}, {mean:+.2f} dB, n=1")
            continue
        if mean - half > 0:
            verdict = "holds"
        elif mean + half < 0:
            verdict = "reversed"
        else:
            verdict = "holds as a tie" if relation == "<=" else "not resolved"
            verdict += " (the interval contains 0)"
        lines.append(f"- {claim}: {verdict}, {mean:+.2f} ± {half:.2f} dB, n={len(differences)}")
    return "\n".join(lines) + "\n"


KERNEL = "learned_bilateral"  # the learned kernel alone: the residual base experiment=cpu's networks add to


def over_kernel(groups: dict[str, list], scales: Sequence[str]) -> str:
    """Each row's PSNR minus the learned kernel alone's (a ``learned_bilateral`` row of the same runs), paired by
    seed, at every tested scale: for a network built on that kernel, what the network adds over the start it
    corrects. Empty without exactly one kernel row or without test scales."""
    kernels = [row for row, row_runs in groups.items() if row_runs[0].data.tags.get("variant") == KERNEL]
    if len(kernels) != 1 or not scales:
        return ""

    def by_seed(row: str, scale: str) -> dict[str, float]:
        return {_seed(r): _psnr(r, scale, scales) for r in groups[row] if r.info.status == "FINISHED"}

    lines = [
        f"\nEach row minus the learned kernel alone ({kernels[0]}), PSNR paired by seed (mean ± 95% half-width, n): "
        "for a network that adds its output to that kernel, what the network adds.\n",
        "| | " + " | ".join(scales) + " |",
        "|---|" + "---|" * len(scales),
    ]
    for row in groups:
        if row == kernels[0]:
            continue
        cells = []
        for scale in scales:
            kernel, own = by_seed(kernels[0], scale), by_seed(row, scale)
            differences = [own[seed] - kernel[seed] for seed in sorted(set(own) & set(kernel))]
            mean, half = interval(differences)
            cells.append(
                "n/a" if not math.isfinite(mean)
                else f"{mean:+.2f}" + (f" ± {half:.2f}" if math.isfinite(half) else "") + f", n={len(differences)}"
            )  # fmt: skip
        lines.append(f"| {row} | " + " | ".join(cells) + " |")
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


Cell = tuple[float, float, int]  # mean, 95% half-width, n
# Each row of a plot its own marker (and in frames.png its own dash and a small sideways offset): rows of equal
# values stay visible.
MARKERS = ("o", "s", "^", "v", "D", "P", "X", "*", "<", ">", "h", "p")
DASHES = ("-", "--", "-.", ":")
FRAME_SPREAD = 0.3  # the offsets span this much of a frame


@dataclass
class Costs:
    """The cost axes of the trade-off plot, per row, and what the caption says about where they come from."""

    ms: dict[str, Cell]
    gflops: dict[str, Cell]
    ms_label: str = "ms / frame"
    gflops_label: str = "GFLOPs / frame"
    notes: list[str] = field(default_factory=list)


def _bench_setting(run) -> tuple[str, str, str]:
    """Where a run's ``bench/*`` were measured: device, output size and scale, and the process that timed them
    (runs from before the tags: the process by host and pid, the size from the params)."""
    tags, params = run.data.tags, run.data.params
    resolution = tags.get("bench/resolution")
    if resolution is None and "bench.width" in params:
        resolution = f"{params['bench.width']}x{params['bench.height']} output, {float(params['bench.scale']):g}x"
    process = tags.get("bench/process") or (f"{tags['host']}:{tags['pid']}" if "pid" in tags else run.info.run_id)
    return tags.get("bench/device", "device not recorded"), resolution or "size not recorded", process


def _axis_words(settings: set[str], what: str) -> str:
    return next(iter(settings)) if len(settings) == 1 else f"{len(settings)} {what} (see caption)"


def costs(groups: dict[str, list], metrics, runtime: Sequence = (), runtime_name: str = "") -> Costs:
    """The trade-off plot's ms/frame and GFLOPs per row: the rows' own ``bench/*``, or with ``runtime`` (the jobs of
    a runtime sweep, :file:`sweeps/runtime.yaml`) that sweep's, matched by configuration name (variant or model).

    Timings compare only when one process took them (the runtime sweep runs its jobs one after another): the caption
    says how many processes did, on which device and at which size. Rows whose FLOPs were not counted (0 GFLOPs:
    torch's counter sees matrix products and convolutions, not the per-pixel arithmetic of parameter-free kernels)
    are left out of the FLOPs panel and named.
    """
    notes = []
    if runtime:
        by_label: dict[str, list] = defaultdict(list)
        for run in runtime:
            if run.info.status == "FINISHED" and "bench/ms_per_frame" in run.data.metrics:
                by_label[base_label(_tags(run))[0]].append(run)
        sources = {row: by_label.get(base_label(_tags(runs[0]))[0], []) for row, runs in groups.items()}
        missing = [row for row, jobs in sources.items() if not jobs]
        sources = {row: jobs for row, jobs in sources.items() if jobs}
        cells = {
            key: {row: (*interval([j.data.metrics[key] for j in jobs]), len(jobs)) for row, jobs in sources.items()}
            for key in ("bench/ms_per_frame", "bench/gflops")
        }
        ms, gflops = cells["bench/ms_per_frame"], cells["bench/gflops"]
        timed = [run for jobs in sources.values() for run in jobs]
        origin = f"the runtime sweep {runtime_name}, matched to the rows by configuration name"
        if missing:
            notes.append(f"No configuration of {runtime_name} matches {'; '.join(missing)}: left out of both panels.")
    else:
        ms = {row: m["bench/ms_per_frame"] for row, m in metrics.items() if "bench/ms_per_frame" in m}
        gflops = {row: m["bench/gflops"] for row, m in metrics.items() if "bench/gflops" in m}
        timed = [r for runs in groups.values() for r in runs if "bench/ms_per_frame" in r.data.metrics]
        timed = [r for r in timed if r.info.status == "FINISHED"]
        origin = "each run's own timing"
    settings = [_bench_setting(run) for run in timed]
    devices, sizes, processes = ({setting[i] for setting in settings} for i in range(3))
    if timed and len(processes) == 1:
        notes.insert(0, f"ms/frame from {origin}: one process timed every row ({next(iter(devices))}).")
    elif timed:
        hint = "" if runtime else " (python -m wdss.train -cd sweeps -cn runtime, then --runtime runtime)"
        notes.insert(
            0,
            f"ms/frame from {origin}: {len(processes)} different processes timed these rows, each at its own moment "
            f"under its own load: differences between rows may be the machine's, not the models'; for a fair "
            f"comparison time every row in one process{hint}.",
        )
    if len(devices) > 1 or len(sizes) > 1:
        notes.append(f"Timed on {' / '.join(sorted(devices))}; at {' / '.join(sorted(sizes))}.")
    uncounted = [row for row, cell in gflops.items() if math.isfinite(cell[0]) and cell[0] <= 0]
    if uncounted:
        notes.append(
            f"FLOPs not counted for {'; '.join(uncounted)} (0 GFLOPs: torch's FLOP counter counts matrix products "
            "and convolutions, not the per-pixel arithmetic of parameter-free kernels): left out of the FLOPs panel."
        )
    device, size = _axis_words(devices, "devices"), _axis_words(sizes, "sizes")
    return Costs(
        ms=ms,
        gflops={row: cell for row, cell in gflops.items() if row not in uncounted},
        ms_label=f"ms / frame ({device}; {size})" if timed else "ms / frame",
        gflops_label=f"GFLOPs / frame ({size})" if timed else "GFLOPs / frame",
        notes=notes,
    )


def _decades(values: Sequence[float]) -> bool:
    """Values that span a factor of ten or more: a linear axis would crush the small ones together."""
    positive = [v for v in values if math.isfinite(v) and v > 0]
    return len(positive) > 1 and max(positive) / min(positive) >= 10


MIN_N_FOR_INTERVAL = 3  # two seeds give a t-interval 12.7 standard errors wide: drawn, it says nothing


def _error(cell: Cell) -> float:
    """The half-width drawn for a cell: none below ``MIN_N_FOR_INTERVAL`` values."""
    return cell[1] if cell[2] >= MIN_N_FOR_INTERVAL and math.isfinite(cell[1]) else 0.0


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
            times = [metrics[row].get("time/train_s", (float("nan"), float("nan"), 0)) for row in rows]
            means = [t[0] / 60 if math.isfinite(t[0]) else 0.0 for t in times]
            errors = [min(_error(t) / 60, m) for t, m in zip(times, means, strict=True)]
            ax.barh(rows, means, xerr=errors, color=[f"C{i % 10}" for i in range(len(rows))])
            ax.set_xlabel("training wall-clock (min), mean over seeds")
            if not any(means):
                ax.set_xticks([])
                ax.text(0.5, 0.5, "no training time logged", ha="center", transform=ax.transAxes)
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


def report(
    sweep: str | None = None,
    parent: str | None = None,
    *,
    runs: Sequence[str] = (),
    experiment: str | None = None,
    filter_string: str = "",
    name: str | None = None,
    tracking_uri: str | None = None,
    out_dir: str | Path = "outputs/reports",
    scale: str | None = None,
    runtime: str | None = None,
) -> Path:
    """Write the table, trade-off plot and qualitative figure of a sweep (``sweep`` or ``parent``; logged on the
    parent run too) or of any runs (``runs`` by id, or ``experiment`` with an MLflow ``filter_string``).

    ``scale``: the table's and the plots' scale (``3x``, or ``avg`` over the tested scales); by default the
    sweep's only test scale, else its paper table's (``PAPER_SCALES``). ``runtime``: a runtime sweep (its name or
    parent run id) whose ms/frame and GFLOPs, all timed by one process, the trade-off plot shows for each row.
    """
    client = _client(tracking_uri)
    if runs or experiment:
        parent_run = None
        selected = find_runs(client, runs, experiment, filter_string)
        name = name or (experiment if experiment and not runs else "runs")
    else:
        parent_run = find_parent(client, sweep, parent)
        name = name or sweep or parent_run.data.tags.get("sweep", parent_run.info.run_id)
        selected = collect(client, parent_run.info.run_id)
        if not selected:
            raise SystemExit(f"wdss.report: the sweep {name!r} ({parent_run.info.run_id}) has no jobs")
        check_one_dataset(parent_run, selected)
    runs = selected
    groups = group(runs)
    rows = list(groups)
    metrics, notes = summarise(groups)
    timing = runtime_runs(client, runtime) if runtime else []
    cost = costs(groups, metrics, timing, runtime or "")
    scales = test_scales(metrics)
    shown = table_scale(name, scales, scale)
    columns = compact_columns(metrics, shown, scales)
    statuses = Counter(sorted((run.info.status for run in runs), key=lambda status: status != "FINISHED"))
    counts = ", ".join(f"{n} {status.lower() if status == 'FINISHED' else status}" for status, n in statuses.items())
    markdown = (
        f"# {name}\n\n"
        + (f"Test metrics at {_scale_words(shown, scales)}: " if scales else "Inference cost: ")
        + "mean ± half-width of the 95% t-interval over n seeds (n/a with one seed); the best of each column in bold."
        + "\n\n"
        + compact_table(
            rows, metrics, notes, columns, scales, {row: _tags(g[0]).get("data_root") for row, g in groups.items()}
        )
        + "".join(orderings(name, groups, at, scales) for at in [shown, *(s for s in scales if s != shown)])
        + over_kernel(groups, scales)
        + (TEMPORAL_NOTE if any("twe_ratio" in key or "tpsnr" in key for key, *_ in columns) else "")
        + (noise_ceiling_note(runs) if scales else "")
        + ("\nCosts (tradeoff.png): " + " ".join(cost.notes) + "\n" if cost.notes else "")
        + f"\nMetrics on tone-mapped output: {metric_path(runs)}. {len(runs)} runs ({counts}); "
        + (f"parent run {parent_run.info.run_id}; " if parent_run is not None else "")
        + "every metric at every scale in table.csv.\n"
    )
    out = Path(out_dir) / path_component(name)
    out.mkdir(parents=True, exist_ok=True)
    (out / "table.md").write_text(markdown)
    (out / "table.csv").write_text(full_csv(rows, metrics, notes))
    plot_scale = shown if shown in scales or not scales else ("2x" if "2x" in scales else scales[0])
    tradeoff_plot(rows, metrics, out / "tradeoff.png", shown, cost)  # "avg" plots the means over scales
    qualitative_figure(client, groups, out / "qualitative.png", plot_scale)
    frames_plot(client, groups, out / "frames.png", plot_scale)
    print(markdown)
    if parent_run is not None:
        client.log_artifacts(parent_run.info.run_id, str(out), "report")
        print(f"wdss.report: wrote {out} (also logged on run {parent_run.info.run_id})")
    else:
        print(f"wdss.report: wrote {out}")
    return out


def main(argv: Sequence[str] | None = None) -> None:
    os.environ.setdefault("MLFLOW_ENABLE_ARTIFACTS_PROGRESS_BAR", "false")
    parser = argparse.ArgumentParser(
        prog="python -m wdss.report", description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter
    )
    which = parser.add_mutually_exclusive_group(required=True)
    which.add_argument("--sweep", help="the sweep's name (its newest parent run)")
    which.add_argument("--parent", help="the parent run id (its children: a sweep's jobs, or a training's evaluations)")
    which.add_argument("--runs", nargs="+", metavar="ID", help="any runs by id: a row per configuration and data")
    which.add_argument("--experiment", help="the runs of this experiment that have test or bench metrics")
    parser.add_argument(
        "--filter", default="", help="with --experiment: an MLflow filter, e.g. \"tags.data = 'bench'\""
    )
    parser.add_argument("--name", default=None, help="the report's folder under --out (default: the sweep's name)")
    parser.add_argument("--tracking-uri", default=None, help="default: $MLFLOW_TRACKING_URI or sqlite:///mlflow.db")
    parser.add_argument("--out", default="outputs/reports")
    parser.add_argument(
        "--scale",
        default=None,
        help="the scale of the table and plots, e.g. 3x, or avg (default: the sweep's only test scale, else its "
        "paper table's: 2x for the ablations, 3x for methods, avg for scales)",
    )
    parser.add_argument(
        "--runtime",
        default=None,
        metavar="SWEEP",
        help="take the plot's ms/frame and GFLOPs from this runtime sweep (name or parent run id; sweeps/runtime.yaml "
        "times every configuration in one process) instead of each run's own timing",
    )
    args = parser.parse_args(argv)
    if args.filter and not args.experiment:
        parser.error("--filter selects among the runs of --experiment")
    report(
        args.sweep,
        args.parent,
        runs=args.runs or (),
        experiment=args.experiment,
        filter_string=args.filter,
        name=args.name,
        tracking_uri=args.tracking_uri,
        out_dir=args.out,
        scale=args.scale,
        runtime=args.runtime,
    )


if __name__ == "__main__":
    main()
