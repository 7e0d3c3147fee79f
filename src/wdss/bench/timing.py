"""How the benchmarks time: runners interleaved in rounds, medians, paired ratios and the median's interval.

Timing on shared machines is noisy: every comparison is made within one run, each runner timed in the same rounds
as the ones it is compared with.
"""

from __future__ import annotations

import math
import statistics
import time
from collections.abc import Callable, Sequence

import torch


def median_ms(fn: Callable[[], object], *, repeats: int, warmup: int = 1) -> float:
    """Median wall-clock milliseconds of ``fn()`` over ``repeats`` runs after ``warmup`` runs."""
    return statistics.median(interleaved_ms({"fn": fn}, repeats, warmup)["fn"])


def _synchronize() -> None:
    if torch.cuda.is_available():
        torch.cuda.synchronize()


def interleaved_ms(runners: dict, repeats: int, warmup: int = 1) -> dict:
    """Wall-clock milliseconds of every zero-argument runner over ``repeats`` rounds, each round running every
    runner once (A B C A B C ...), so that a slow spell of a shared machine hits them alike rather than one of them.
    Each round starts one runner later: none always runs right after the same one (whose freed memory and caches
    it would inherit)."""
    order = list(runners)
    times: dict = {key: [] for key in order}
    for _ in range(warmup):
        for run in runners.values():
            run()
    for round_ in range(repeats):
        shift = round_ % len(order)
        for key in order[shift:] + order[:shift]:
            _synchronize()
            start = time.perf_counter()
            runners[key]()
            _synchronize()
            times[key].append((time.perf_counter() - start) * 1e3)
    return times


def median_interval(values: Sequence[float], confidence: float = 0.95) -> tuple[float, float] | None:
    """A distribution-free interval of the median: the order statistics ``(j, n + 1 - j)`` (1-based) for the largest
    ``j`` whose coverage ``1 - 2 P(Binomial(n, 1/2) < j)`` is at least ``confidence``; None when even the extremes
    cover less (fewer than 6 values at 95 %)."""
    n = len(values)
    ordered = sorted(values)
    below, j = 0.0, 0  # below = P(B < j + 1) as j grows
    while j < n // 2:
        below += math.comb(n, j) / 2**n
        if 2 * below > 1 - confidence:
            break
        j += 1
    return (ordered[j - 1], ordered[n - j]) if j else None


def ratio_cell(times: Sequence[float], reference: Sequence[float]) -> str:
    """The paired ratio and, when the rounds allow one, its 95 % interval (of the per-round ratios' median)."""
    ratios = [t / r for t, r in zip(times, reference, strict=True)]
    interval = median_interval(ratios)
    tail = f" [{interval[0]:.3f}, {interval[1]:.3f}]" if interval and interval[0] != interval[1] else ""
    return f"{statistics.median(ratios):.3f}{tail}"


def paired_ratio(times: Sequence[float], reference: Sequence[float]) -> float:
    """The median over rounds of ``times / reference`` in the same round."""
    return statistics.median(t / r for t, r in zip(times, reference, strict=True))
