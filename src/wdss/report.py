"""Paper-style reports from MLflow runs: ``python -m wdss.report --sweep NAME`` (or ``--parent RUN_ID``).

Reads the jobs of a sweep (the runs nested under its parent run) and writes, into
``outputs/reports/<sweep>/`` and as artifacts of the parent run:

* ``table.md`` and ``table.csv``: one row per configuration (the ``variant`` tag, or the group tags), the
  test metrics per scale and their average over scales, as mean and 95% interval over seeds; a cell whose
  jobs failed says so instead of disappearing;
* ``tradeoff.png``: PSNR and FLIP against ms/frame and against GFLOPs, the Pareto front marked, with the
  training wall-clock per configuration beside it;
* ``qualitative.png``: the same crop of the first test frame from every configuration and the target.
"""

from __future__ import annotations

import argparse
import math
import os
import statistics
import tempfile
from collections import defaultdict
from collections.abc import Sequence
from pathlib import Path

__all__ = ["collect", "main", "report"]

LOWER_IS_BETTER = ("flip", "flip_hdr", "lpips")
ROW_TAGS = ("transform", "basis", "head", "scale", "temporal", "model")


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


def row_label(tags: dict[str, str]) -> str:
    if tags.get("variant"):
        return tags["variant"]
    return ", ".join(f"{k}={tags[k]}" for k in ROW_TAGS if k in tags and not tags[k].startswith("n/a"))


def collect(client, parent_id: str) -> list:
    experiment = client.get_run(parent_id).info.experiment_id
    return client.search_runs([experiment], filter_string=f"tags.mlflow.parentRunId = '{parent_id}'")


def interval(values: list[float]) -> tuple[float, float]:
    """Mean and half-width of the 95% t-interval (0 for a single value)."""
    finite = [v for v in values if math.isfinite(v)]
    if not finite:
        return float("nan"), float("nan")
    mean = statistics.fmean(finite)
    if len(finite) < 2:
        return mean, 0.0
    from scipy.stats import t

    return mean, float(t.ppf(0.975, len(finite) - 1) * statistics.stdev(finite) / math.sqrt(len(finite)))


def summarise(runs: list) -> tuple[list[str], dict[str, dict[str, tuple[float, float, int]]], dict[str, str]]:
    """Rows (in first-seen order), per-row metric summaries, and a note per row about failed jobs."""
    by_row: dict[str, list] = defaultdict(list)
    for run in sorted(runs, key=lambda r: r.info.start_time):
        by_row[row_label(_tags(run))].append(run)
    metrics: dict[str, dict[str, tuple[float, float, int]]] = {}
    notes: dict[str, str] = {}
    for row, row_runs in by_row.items():
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
        metrics[row] = {k: (*interval(v), len(v)) for k, v in values.items()}
    return list(by_row), metrics, notes


def _tags(run) -> dict[str, str]:
    return dict(run.data.tags)


def _scale_metric(key: str) -> tuple[str, str] | None:
    """``test/psnr_3x`` -> ``("psnr", "3x")``; None for anything else."""
    if not key.startswith("test/") or "_" not in key:
        return None
    name, scale = key[len("test/") :].rsplit("_", 1)
    return (name, scale) if scale.endswith("x") and scale[:-1].replace(".", "").isdigit() else None


def table(rows, metrics, notes, columns: Sequence[str]) -> tuple[str, str]:
    """Markdown and CSV: mean +- 95% interval over seeds (n), or the reason a cell is missing."""
    header = ["configuration", *columns, "seeds", "note"]
    md = ["| " + " | ".join(header) + " |", "|" + "---|" * len(header)]
    csv = [",".join(header + [f"{c} ci95" for c in columns])]
    for row in rows:
        cells, raw = [], []
        count = 0
        for column in columns:
            mean, half, n = metrics[row].get(column, (float("nan"), float("nan"), 0))
            count = max(count, n)
            cells.append("missing" if not math.isfinite(mean) else f"{mean:.4g} ± {half:.2g}")
            raw.append((mean, half))
        note = notes.get(row, "")
        md.append("| " + " | ".join([row, *cells, str(count), note]) + " |")
        csv.append(
            ",".join(
                [f'"{row}"', *(f"{m:.6g}" for m, _ in raw), str(count), f'"{note}"', *(f"{h:.6g}" for _, h in raw)]
            )
        )
    return "\n".join(md) + "\n", "\n".join(csv) + "\n"


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


def tradeoff_plot(rows, metrics, path: Path, scale: str) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    panels = [("bench/ms_per_frame", "ms / frame"), ("bench/gflops", "GFLOPs")]
    qualities = [(f"test/psnr_{scale}", "PSNR (dB)", True), (f"test/flip_{scale}", "FLIP", False)]
    fig, axes = plt.subplots(2, 3, figsize=(15, 8))
    for r, (quality, qlabel, higher) in enumerate(qualities):
        for c, (cost, clabel) in enumerate(panels):
            ax = axes[r, c]
            points, labels = [], []
            for row in rows:
                m = metrics[row]
                if cost in m and quality in m and math.isfinite(m[cost][0]) and math.isfinite(m[quality][0]):
                    points.append((m[cost][0], m[quality][0]))
                    labels.append(row)
                    ax.errorbar(m[cost][0], m[quality][0], yerr=m[quality][1], fmt="o", capsize=3)
                    ax.annotate(row, (m[cost][0], m[quality][0]), fontsize=7, xytext=(3, 3), textcoords="offset points")
            if not points:
                ax.text(
                    0.5,
                    0.5,
                    f"no {qlabel} logged in these runs",
                    ha="center",
                    va="center",
                    transform=ax.transAxes,
                    fontsize=9,
                )
            front = sorted((points[i] for i in pareto(points, higher)), key=lambda p: p[0])
            if front:
                ax.plot(*zip(*front, strict=True), "--", color="gray", label="Pareto front")
                ax.legend(fontsize=7)
            ax.set_xlabel(clabel)
            ax.set_ylabel(f"{qlabel} @ {scale}")
            ax.grid(alpha=0.3)
        ax = axes[r, 2]
        if r == 0:
            times = [metrics[row].get("time/train_s", (float("nan"), 0, 0)) for row in rows]
            means = [t[0] / 60 if math.isfinite(t[0]) else 0.0 for t in times]
            errors = [min(t[1] / 60, m) if math.isfinite(t[1]) else 0.0 for t, m in zip(times, means, strict=True)]
            ax.barh(rows, means, xerr=errors)
            ax.set_xlabel("training wall-clock (min), mean over seeds")
        else:
            ax.axis("off")
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)


def qualitative_figure(client, rows, runs, path: Path, scale: str, crop: int = 96) -> bool:
    """The same crop of the first test frame from one run of every row, and the target."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    from PIL import Image

    images, target = {}, None
    with tempfile.TemporaryDirectory() as tmp:
        for row in rows:
            run = next((r for r in runs if row_label(_tags(r)) == row and r.info.status == "FINISHED"), None)
            if run is None:
                continue
            try:
                pred = client.download_artifacts(run.info.run_id, f"test/pred_{scale}.png", tmp)
                images[row] = Image.open(pred).convert("RGB").copy()
                if target is None:
                    ref = client.download_artifacts(run.info.run_id, f"test/target_{scale}.png", tmp)
                    target = Image.open(ref).convert("RGB").copy()
            except Exception:  # a run without test images (bench-only, or failed before testing)
                continue
    if not images or target is None:
        return False
    width, height = target.size
    size = min(crop, width, height)
    box = ((width - size) // 2, (height - size) // 2, (width - size) // 2 + size, (height - size) // 2 + size)
    panels = [*images.items(), ("target", target)]
    fig, axes = plt.subplots(1, len(panels), figsize=(2.4 * len(panels), 2.8))
    for ax, (label, image) in zip(list(axes) if len(panels) > 1 else [axes], panels, strict=True):
        ax.imshow(image.crop(box), interpolation="nearest")
        ax.set_title(label, fontsize=8)
        ax.axis("off")
    fig.tight_layout()
    fig.savefig(path, dpi=120)
    plt.close(fig)
    return True


def report(
    sweep: str | None = None,
    parent: str | None = None,
    *,
    tracking_uri: str | None = None,
    out_dir: str | Path = "outputs/reports",
    scale: str = "2x",
) -> Path:
    """Write the sweep's table, trade-off plot and qualitative figure; log them on the parent run."""
    client = _client(tracking_uri)
    parent_run = find_parent(client, sweep, parent)
    name = sweep or parent_run.data.tags.get("sweep", parent_run.info.run_id)
    runs = collect(client, parent_run.info.run_id)
    if not runs:
        raise SystemExit(f"wdss.report: the sweep {name!r} ({parent_run.info.run_id}) has no jobs")
    rows, metrics, notes = summarise(runs)
    scales = sorted({k.rsplit("_", 1)[1] for m in metrics.values() for k in m if k.startswith("test/psnr_")})
    columns = [
        f"test/{m}_{s}"
        for s in scales
        for m in ("psnr", "ssim", "flip", "lpips")
        if any(f"test/{m}_{s}" in v for v in metrics.values())
    ]
    columns += [
        c for c in ("bench/ms_per_frame", "bench/gflops", "time/train_s") if any(c in v for v in metrics.values())
    ]
    out = Path(out_dir) / name
    out.mkdir(parents=True, exist_ok=True)
    markdown, csv = table(rows, metrics, notes, columns)
    title = f"# {name}\n\nparent run {parent_run.info.run_id}; mean ± 95% interval over seeds\n\n"
    (out / "table.md").write_text(title + markdown)
    (out / "table.csv").write_text(csv)
    plot_scale = scale if scale in scales or not scales else scales[0]
    tradeoff_plot(rows, metrics, out / "tradeoff.png", plot_scale)
    qualitative_figure(client, rows, runs, out / "qualitative.png", plot_scale)
    client.log_artifacts(parent_run.info.run_id, str(out), "report")
    print(title + markdown)
    print(f"wdss.report: wrote {out} (also logged on run {parent_run.info.run_id})")
    return out


def main(argv: Sequence[str] | None = None) -> None:
    os.environ.setdefault("MLFLOW_ENABLE_ARTIFACTS_PROGRESS_BAR", "false")
    parser = argparse.ArgumentParser(
        prog="python -m wdss.report", description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter
    )
    which = parser.add_mutually_exclusive_group(required=True)
    which.add_argument("--sweep", help="the sweep's name (its newest parent run)")
    which.add_argument("--parent", help="the parent run id")
    parser.add_argument("--tracking-uri", default=None, help="default: $MLFLOW_TRACKING_URI or sqlite:///mlflow.db")
    parser.add_argument("--out", default="outputs/reports")
    parser.add_argument("--scale", default="2x", help="the scale of the plots, e.g. 3x")
    args = parser.parse_args(argv)
    report(args.sweep, args.parent, tracking_uri=args.tracking_uri, out_dir=args.out, scale=args.scale)


if __name__ == "__main__":
    main()
