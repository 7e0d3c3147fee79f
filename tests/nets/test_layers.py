"""The networks are pure ``nn.Module``s (DESIGN): nothing in wdss.nets reaches up into training, tracking or MLflow."""

from __future__ import annotations

import ast
from pathlib import Path

import pytest

import wdss.nets

PACKAGE = Path(wdss.nets.__file__).parent
SOURCES = sorted(PACKAGE.rglob("*.py"))
ABOVE = ("wdss.training", "wdss.tracking", "wdss.callbacks", "mlflow", "lightning")


def imported(source: str) -> set[str]:
    """Every module an ``import`` or ``from ... import`` in ``source`` names, at any depth (lazy imports included)."""
    names = set()
    for node in ast.walk(ast.parse(source)):
        if isinstance(node, ast.Import):
            names |= {alias.name for alias in node.names}
        elif isinstance(node, ast.ImportFrom) and node.module:
            names.add(node.module)
    return names


def reaches_up(names: set[str]) -> list[str]:
    return sorted(n for n in names if any(n == a or n.startswith(a + ".") for a in ABOVE))


def test_the_scan_sees_every_network_module_and_would_catch_a_lazy_import():
    assert {"network.py", "joint_bilateral.py", "rrdbnet.py", "base.py"} <= {p.name for p in SOURCES}
    assert reaches_up(imported("def f():\n    from wdss.training.module import M\n")) == ["wdss.training.module"]
    assert reaches_up(imported("import mlflow.pytorch\nimport lightning.pytorch as pl\n")) == [
        "lightning.pytorch",
        "mlflow.pytorch",
    ]
    assert reaches_up(imported("import wdss.trainingish\n")) == []


@pytest.mark.parametrize("path", SOURCES, ids=lambda path: str(path.relative_to(PACKAGE)))
def test_no_network_module_imports_training_tracking_or_mlflow(path):
    found = reaches_up(imported(path.read_text()))
    assert not found, f"{path.relative_to(PACKAGE)} imports {found}"
