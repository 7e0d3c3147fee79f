"""Paired-seed comparisons between rows: the paper's orderings, and each row over the learned kernel alone."""

from __future__ import annotations

import math
import statistics
from collections import defaultdict
from collections.abc import Sequence

from wdss.report.facts import PaperFacts
from wdss.report.rows import overrides
from wdss.report.summary import interval


def _seed(run) -> str:
    """The seed a run's row pairs it by: its override, else its tag."""
    return overrides(run).get("seed", run.data.tags.get("seed", "?"))


def _psnr(run, scale: str, scales: Sequence[str]) -> float:
    """A run's test PSNR at ``scale``, or its mean over ``scales`` (``avg``)."""
    data = run.data.metrics
    if scale == "avg":
        values = [data.get(f"test/psnr_{s}", float("nan")) for s in scales]
        return statistics.fmean(values) if values else float("nan")
    return data.get(f"test/psnr_{scale}", float("nan"))


def orderings(facts: PaperFacts, groups: dict[str, list], scale: str, scales: Sequence[str]) -> str:
    """Which of the paper's orderings (the sweep file's ``report.orderings``) hold, by the PSNR difference of each
    claimed pair on the seeds both rows finished (paired by seed), with its 95% t-interval; empty for a sweep without
    claims.

    A strict claim holds when the interval lies above zero and is reversed when it lies below; a ``<=`` claim holds
    unless the interval lies below zero. Otherwise the difference is within the seeds' spread: not resolved.
    """
    claims, labels = facts.orderings, facts.labels
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
        claim = f"{labels.get(low, low)} {relation} {labels.get(high, high)}"
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
