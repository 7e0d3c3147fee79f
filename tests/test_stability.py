"""Stiff and extreme cases (wdss.stability): every case finite and within its tolerance."""

from __future__ import annotations

import pytest

from wdss.stability import CASES


@pytest.mark.parametrize("make", CASES, ids=lambda f: f.__name__.strip("_"))
def test_extreme_cases_stay_finite_and_exact(make):
    for case in make():
        assert case.finite, f"{case.group}: {case.name} became non-finite"
        assert case.error <= case.tolerance, f"{case.group}: {case.name}: {case.error:.3g} > {case.tolerance:.1g}"
