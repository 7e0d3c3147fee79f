"""Fixtures of the data tests."""

from __future__ import annotations

import pytest

from wdss.data.layouts import Source


@pytest.fixture
def opened(monkeypatch) -> list[str]:
    """The names of every EXR file opened through a scene source."""
    names: list[str] = []
    original = Source.read

    def counting(self, name, channels, **options):
        names.append(name)
        return original(self, name, channels, **options)

    monkeypatch.setattr(Source, "read", counting)
    return names
