"""Test-wide settings (no MLflow telemetry) and fixtures."""

import os

import pytest

os.environ.setdefault("MLFLOW_DISABLE_TELEMETRY", "true")


@pytest.fixture
def tail_calls(monkeypatch) -> list:
    """The shapes of ``merged`` each time the SWT network computes its tail on cells (wdss.nets.wdss.polyphase)."""
    import wdss.nets.wdss.network as network
    from wdss.nets.wdss.polyphase import swt_tail_on_cells

    calls = []

    def spy(*args):
        calls.append(args[0].shape)
        return swt_tail_on_cells(*args)

    monkeypatch.setattr(network, "swt_tail_on_cells", spy)
    return calls
