"""What makes a dataset that does not exist yet: the data module's ``prepare`` (``data.prepare``), injected by the
config, so that the data layer never imports the renderer that implements it.

A :class:`Preparer` is called with the dataset's root to make (or resume making) it, and answers the data module's
questions before anything is created: whether it refuses a root (a typo renders nothing), whether an existing root
is its own to resume, and why frames it made earlier are out of date. :class:`wdss.render.RenderOnFirstUse` is the
one wdss ships; a plain callable (a test's, or ``wdss.render.render_preset``) is taken as one that refuses nothing,
resumes anywhere and judges nothing out of date (:func:`as_preparer`).
"""

from __future__ import annotations

from collections.abc import Callable, Mapping
from pathlib import Path
from typing import Any, Protocol, runtime_checkable

__all__ = ["Preparer", "as_preparer"]


@runtime_checkable
class Preparer(Protocol):
    """Makes the dataset at a root, and says before it is asked to what it would and would not do there."""

    def __call__(self, root: str | Path) -> object:
        """Make the dataset at ``root``, or resume making it."""

    def refusal(self, root: str | Path) -> str | None:
        """Why ``root``, which does not exist, is not made here (None: it is), in one sentence."""

    def resumes(self, root: str | Path) -> bool:
        """Whether a dataset stopped part-way in the existing folder ``root`` is this preparer's to resume."""

    def outdated(self, made: Mapping[str, Mapping[str, Any]]) -> str | None:
        """Why the sequences made earlier at the root (their ``sequence.json`` by name) are not what this preparer
        makes today, or None."""

    def stale(self, meta: Mapping[str, Any]) -> str | None:
        """Why one sequence made earlier (its ``sequence.json``) must be made again, or None."""


class _CallOnly:
    """A plain callable as a :class:`Preparer`: it refuses no root, resumes anywhere, judges nothing out of date."""

    def __init__(self, make: Callable[[Path], object]) -> None:
        self.make = make

    def __call__(self, root: str | Path) -> object:
        return self.make(root)

    def refusal(self, root: str | Path) -> str | None:
        return None

    def resumes(self, root: str | Path) -> bool:
        return True

    def outdated(self, made: Mapping[str, Mapping[str, Any]]) -> str | None:
        return None

    def stale(self, meta: Mapping[str, Any]) -> str | None:
        return None

    def __repr__(self) -> str:
        return f"_CallOnly({self.make!r})"


def as_preparer(prepare: Preparer | Callable[[Path], object] | None) -> Preparer | None:
    """``prepare`` as a :class:`Preparer` (None stays None: nothing makes a missing root)."""
    if prepare is None or isinstance(prepare, Preparer):
        return prepare
    return _CallOnly(prepare)
