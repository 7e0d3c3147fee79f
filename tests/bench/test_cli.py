"""python -m wdss.bench: tables printed whole off a terminal, and the timing commands' restart under malloc tunables."""

from __future__ import annotations

import pytest
from rich.table import Table

from tests.bench.tables import table_rows
from wdss.bench import cli


def test_tables_print_whole_off_a_terminal(monkeypatch, capsys):
    """Off a terminal rich wraps at 80 columns: a wide table (as bench model's) kept one line per row."""
    table = Table(title="wide")
    for column in ("transform", "basis", "head", "params", "GFLOPs", "synthesis", "ms", "time / none", "FLOPs / none"):
        table.add_column(column)
    table.add_row("swt", "db4", "shared_inr", "0.575 M", "135.7", "0.33%", "3512", "1.135", "1.092")
    monkeypatch.setattr(cli, "bench_model", lambda *args: table)
    monkeypatch.setattr(cli, "memory_retained", lambda: False)
    cli.main(["model"])
    out = capsys.readouterr().out
    assert table_rows(out)["swt", "db4"] == ["shared_inr", "0.575 M", "135.7", "0.33%", "3512", "1.135", "1.092"]
    assert "the C library's default malloc" in out  # the timing tables say how memory was allocated


@pytest.mark.parametrize("argv,restarts", [([], True), (["--system-malloc"], False)])
def test_the_timing_command_starts_again_under_the_malloc_tunables(argv, restarts, monkeypatch, capsys):
    restarted = []
    monkeypatch.setattr(cli, "restart_with_retained_memory", lambda: restarted.append(True))
    table = Table("model", title="timed")
    monkeypatch.setattr(cli, "bench_inference", lambda *args, **kwargs: [table])
    cli.main(["inference", *argv], restart=True)
    cli.main(["inference"])  # called as a function (tests, notebooks): never
    assert restarted == [True] * restarts
    assert "timed" in capsys.readouterr().out


def test_every_subcommand_has_the_function_that_makes_its_tables():
    import argparse

    [sub] = [action for action in cli.parser()._actions if isinstance(action, argparse._SubParsersAction)]
    assert list(sub.choices) == list(cli.COMMANDS)
