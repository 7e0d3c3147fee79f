"""wdss.timing.timing: runners interleaved in rounds, paired ratios and the median's interval."""

from __future__ import annotations

from wdss.bench import timing


def test_runners_are_timed_in_interleaved_rounds_each_starting_one_later():
    calls = []
    runners = {key: (lambda k=key: calls.append(k)) for key in "abc"}
    times = timing.interleaved_ms(runners, repeats=4, warmup=1)
    assert "".join(calls) == "abc" + "abc" + "bca" + "cab" + "abc"
    assert {k: len(v) for k, v in times.items()} == {"a": 4, "b": 4, "c": 4}
    assert timing.paired_ratio([2.0, 9.0, 4.0], [1.0, 3.0, 4.0]) == 2.0  # per round: 2, 3, 1


def test_the_median_interval_is_the_order_statistics_that_cover_it():
    # n = 10: P(B <= 1) = 11 / 1024, so (2nd, 9th) covers 1 - 22 / 1024 = 97.9 %; (3rd, 8th) only 89.1 %.
    assert timing.median_interval(list(range(10, 0, -1))) == (2, 9)
    assert timing.median_interval(list(range(1, 11)), confidence=0.85) == (3, 8)
    # n = 6: only the extremes, 1 - 2 / 64 = 96.9 %; n = 5 cannot reach 95 % (1 - 2 / 32 = 93.8 %).
    assert timing.median_interval([3, 1, 2, 6, 5, 4]) == (1, 6)
    assert timing.median_interval([1, 2, 3, 4, 5]) is None
    assert timing.ratio_cell([2.0] * 5, [1.0] * 5) == "2.000"
    assert timing.ratio_cell([float(t) for t in range(1, 11)], [1.0] * 10) == "5.500 [2.000, 9.000]"
