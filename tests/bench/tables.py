"""Printed rich tables read back by the bench tests."""

from __future__ import annotations

import re


def table_rows(text: str) -> dict[tuple[str, str], list[str]]:
    """The body rows of a printed rich table by their first two cells (rows wrapped over lines would split)."""
    rows = {}
    for line in text.splitlines():
        cells = [c.strip() for c in re.split(r"[│┃]", line)[1:-1]]
        if len(cells) > 2 and cells[0] and cells[1]:
            rows[cells[0], cells[1]] = cells[2:]
    return rows
