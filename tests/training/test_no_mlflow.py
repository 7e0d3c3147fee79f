"""The training package knows nothing of MLflow (DESIGN): callbacks (wdss.callbacks) log what it shows."""

from __future__ import annotations

import ast
from pathlib import Path

import pytest

import wdss.training

SOURCES = sorted(Path(wdss.training.__file__).parent.glob("*.py"))
TRACKING = ("mlflow", "wdss.tracking", "lightning.pytorch.loggers")


def imported(tree: ast.AST) -> set[str]:
    """Every module an ``import`` or ``from ... import`` of ``tree`` names (its own and its from-imported names)."""
    names = set()
    for node in ast.walk(tree):
        if isinstance(node, ast.Import):
            names |= {alias.name for alias in node.names}
        elif isinstance(node, ast.ImportFrom) and node.module:
            names |= {node.module} | {f"{node.module}.{alias.name}" for alias in node.names}
    return names


@pytest.mark.parametrize("source", SOURCES, ids=lambda path: path.name)
def test_training_modules_import_no_mlflow_and_touch_no_logger_experiment(source):
    tree = ast.parse(source.read_text(), str(source))
    tracking = sorted(n for n in imported(tree) if n.startswith(TRACKING) or n.split(".")[0] == "mlflow")
    assert not tracking, f"{source.name} imports {tracking}"
    touched = [
        node.lineno
        for node in ast.walk(tree)
        if isinstance(node, ast.Attribute) and node.attr in ("logger", "loggers", "experiment")
    ]
    assert not touched, f"{source.name} reaches for a logger at lines {touched}"


def test_the_scan_sees_the_modules_and_would_catch_an_import():
    assert {"module.py", "metrics.py", "temporal_metrics.py"} <= {path.name for path in SOURCES}
    assert "mlflow.entities.Metric" in imported(ast.parse("def f():\n    from mlflow.entities import Metric"))
    assert "wdss.tracking" in imported(ast.parse("import wdss.tracking as t"))
