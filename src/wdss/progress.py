"""Progress of an entry point's work items (frames): a rich bar on a terminal, plain flushed lines otherwise.

A pipe or log file shows no bar, so off a terminal a line ``<label>: <count>/<total> <text>`` is printed for
every item that comes with a text, and, with ``every_s``, one every ``every_s`` seconds and at the end.
Training's counterpart is :mod:`wdss.callbacks.progress_bar`.
"""

from __future__ import annotations

import sys
import time

__all__ = ["Progress", "duration"]


class Progress:
    """Used as a context manager: ``with Progress("pack seq", 12, every_s=5) as progress: progress.advance()``."""

    def __init__(self, label: str, total: int, *, every_s: float | None = None, unit: str = "") -> None:
        self.label, self.total, self.count, self.every_s, self.unit = label, total, 0, every_s, unit
        self._bar = None
        self._last = time.monotonic()
        if sys.stdout.isatty():
            from rich.progress import BarColumn, MofNCompleteColumn, TextColumn, TimeRemainingColumn
            from rich.progress import Progress as Bar

            columns = (TextColumn("[bold]{task.description}"), BarColumn(), MofNCompleteColumn(), TimeRemainingColumn())
            self._bar = Bar(*columns)
            self._task = self._bar.add_task(label, total=total)

    def __enter__(self) -> Progress:
        if self._bar is not None:
            self._bar.start()
        return self

    def __exit__(self, *exc: object) -> None:
        if self._bar is not None:
            self._bar.stop()

    def advance(self, count: int = 1, text: str | None = None) -> None:
        """``count`` items more; ``text`` describes them (printed above the bar, or in the plain line)."""
        self.count += count
        if self._bar is not None:
            if text is not None:
                self._bar.console.print(text)
            self._bar.advance(self._task, count)
            return
        due = self.every_s is not None and (self.count == self.total or time.monotonic() - self._last >= self.every_s)
        if text is not None or due:
            self._last = time.monotonic()
            words = " ".join(w for w in (self.unit, text) if w)
            print(f"{self.label}: {self.count}/{self.total}{' ' + words if words else ''}", flush=True)


def duration(seconds: float) -> str:
    """``1h02m``, ``1m32s`` or ``45s``."""
    minutes, secs = divmod(round(seconds), 60)
    hours, minutes = divmod(minutes, 60)
    return f"{hours}h{minutes:02d}m" if hours else f"{minutes}m{secs:02d}s" if minutes else f"{secs}s"
