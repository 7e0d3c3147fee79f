"""The costs of each row (ms/frame, GFLOPs) for the trade-off plot, and where they were measured."""

from __future__ import annotations

import math
from collections import defaultdict
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field

from wdss.report.facts import paper_labels
from wdss.report.rows import base_label, tags_of
from wdss.report.summary import Cell, interval


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


def costs(
    groups: dict[str, list],
    metrics,
    runtime: Sequence = (),
    runtime_name: str = "",
    labels: Mapping[str, str] | None = None,
) -> Costs:
    """The trade-off plot's ms/frame and GFLOPs per row: the rows' own ``bench/*``, or with ``runtime`` (the jobs of
    a runtime sweep, :file:`sweeps/runtime.yaml`) that sweep's, matched by configuration name (variant or model,
    named by ``labels``; default: every sweep file's, :func:`wdss.report.facts.paper_labels`).

    Timings compare only when one process took them (the runtime sweep runs its jobs one after another): the caption
    says how many processes did, on which device and at which size. Rows whose FLOPs were not counted (0 GFLOPs:
    torch's counter sees matrix products and convolutions, not the per-pixel arithmetic of parameter-free kernels)
    are left out of the FLOPs panel and named.
    """
    notes = []
    if runtime:
        labels = paper_labels() if labels is None else labels
        by_label: dict[str, list] = defaultdict(list)
        for run in runtime:
            if run.info.status == "FINISHED" and "bench/ms_per_frame" in run.data.metrics:
                by_label[base_label(tags_of(run), labels)[0]].append(run)
        sources = {row: by_label.get(base_label(tags_of(runs[0]), labels)[0], []) for row, runs in groups.items()}
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
