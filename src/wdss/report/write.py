"""A report of a sweep or of any runs: its table, CSV and figures written under ``--out`` (and, for a sweep, logged on
its parent run)."""

from __future__ import annotations

import re
from collections import Counter
from collections.abc import Sequence
from pathlib import Path

from wdss.report.costs import costs
from wdss.report.facts import paper_facts, sweep_files
from wdss.report.orderings import orderings, over_kernel
from wdss.report.plots import frames_plot, qualitative_figure, tradeoff_plot
from wdss.report.rows import group, tags_of
from wdss.report.runs import check_one_dataset, collect, find_parent, find_runs, runtime_runs, tracking_client
from wdss.report.summary import summarise, test_scales
from wdss.report.tables import (
    TEMPORAL_NOTE,
    compact_columns,
    compact_table,
    full_csv,
    metric_path,
    noise_ceiling_note,
    scale_words,
    table_scale,
)


def path_component(name: str) -> str:
    """``name`` (a sweep's tag, which anyone who logs to the store can set) as one safe folder name: never a path
    that leaves ``--out`` (``../x``, ``/etc``), never hidden or empty."""
    safe = re.sub(r"[^\w.+=-]+", "_", name).strip("._")
    return safe or "report"


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
    facts: str | None = None,
) -> Path:
    """Write the table, trade-off plot and qualitative figure of a sweep (``sweep`` or ``parent``; logged on the
    parent run too) or of any runs (``runs`` by id, or ``experiment`` with an MLflow ``filter_string``).

    ``scale``: the table's and the plots' scale (``3x``, or ``avg`` over the tested scales); by default the
    sweep's only test scale, else its paper table's. ``runtime``: a runtime sweep (its name or parent run id) whose
    ms/frame and GFLOPs, all timed by one process, the trade-off plot shows for each row.

    The paper's row names, table scale and orderings are the sweep file's ``report`` node (:mod:`wdss.report.facts`),
    of ``facts`` (a sweep file's name: runs by id that make up that table, e.g. a sweep's jobs with rows another
    sweep ran) or else of the sweep the parent run is tagged with; runs of no sweep are named by every sweep file's
    labels.
    """
    if facts is not None and facts not in (known := sweep_files()):
        raise SystemExit(f"wdss.report: --facts {facts!r} is not a sweep file (sweeps/*.yaml: {', '.join(known)})")
    client = tracking_client(tracking_uri)
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
    stated = paper_facts(facts or (parent_run.data.tags.get("sweep") if parent_run is not None else None))
    groups = group(runs, stated.labels)
    rows = list(groups)
    metrics, notes = summarise(groups)
    timing = runtime_runs(client, runtime) if runtime else []
    cost = costs(groups, metrics, timing, runtime or "", stated.labels)
    scales = test_scales(metrics)
    shown = table_scale(stated.scale, scales, scale)
    columns = compact_columns(metrics, shown, scales)
    statuses = Counter(sorted((run.info.status for run in runs), key=lambda status: status != "FINISHED"))
    counts = ", ".join(f"{n} {status.lower() if status == 'FINISHED' else status}" for status, n in statuses.items())
    markdown = (
        f"# {name}\n\n"
        + (f"Test metrics at {scale_words(shown, scales)}: " if scales else "Inference cost: ")
        + "mean ± half-width of the 95% t-interval over n seeds (n/a with one seed); the best of each column in bold."
        + "\n\n"
        + compact_table(
            rows, metrics, notes, columns, scales, {row: tags_of(g[0]).get("data_root") for row, g in groups.items()}
        )
        + "".join(orderings(stated, groups, at, scales) for at in [shown, *(s for s in scales if s != shown)])
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
