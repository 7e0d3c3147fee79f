"""Benchmarks: ``python -m wdss.bench wavelets|data|model|inference|stability|render|noise|learn|bandlimit|guidance``.

Every benchmark reports medians of repeated runs and ratios measured in the same process, never absolute
targets: timing on shared machines is noisy, so comparisons are only made within one run.
"""
