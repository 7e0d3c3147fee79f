"""``bench stability``: the stiff and extreme cases of :mod:`wdss.stability` as a table."""

from __future__ import annotations

from rich.table import Table


def bench_stability() -> Table:
    """The stiff and extreme cases of :mod:`wdss.stability`: worst relative error and finiteness."""
    from wdss.stability import run_cases

    table = Table(title="stability: worst relative error against float64 / analytic references")
    for column in ("group", "case", "worst rel. error", "tolerance", "finite"):
        table.add_column(column, justify="right" if "error" in column or column == "tolerance" else "left")
    for case in run_cases():
        ok = case.finite and case.error <= case.tolerance
        table.add_row(
            case.group,
            case.name,
            f"{case.error:.2e}",
            f"{case.tolerance:.0e}",
            ("yes" if case.finite else "[red]NO[/red]") + ("" if ok else " [red](fails)[/red]"),
        )
    return table
