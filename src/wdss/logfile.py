"""The run's log file: what a ``python -m wdss.*`` command prints also goes into its Hydra log file.

Hydra's job logging writes ``<run folder>/<job>.log`` (``train.log``, ``eval.log``, ...) through a file handler on
the root logger, which sees only :mod:`logging` records, while wdss prints its progress lines, metrics and errors and
Python prints warnings. While an entry point runs, :func:`teed_output` makes ``sys.stdout`` and ``sys.stderr`` tees:
the console gets exactly what it got, and each complete line is also handed to the root logger's file handlers (not
its console handler) as a record of the command (stdout at INFO, stderr at WARNING). In a sweep Hydra gives every job
a handler of its own, so each job's file holds only its own lines.

On a terminal, a rich progress bar draws with control sequences and carriage returns: those are stripped and a
redrawn line is logged as it ends. Lightning's rich bar writes to the terminal itself, :func:`console` (its rows
would be logged at every redraw), and :mod:`wdss.callbacks.progress_bar` logs its plain lines instead; what is printed
while that bar is live reaches the terminal only.
"""

from __future__ import annotations

import contextlib
import logging
import re
import sys
import threading
import traceback
from collections.abc import Iterator
from contextlib import contextmanager
from pathlib import Path
from typing import Any, TextIO

__all__ = ["console", "log_exception", "log_files", "log_files_to_mlflow", "teed_output", "to_log_file"]

# Terminal control sequences (CSI: colours, cursor moves, erasing; OSC: titles, links).
_CONTROL = re.compile(r"\x1b\[[0-?]*[ -/]*[@-~]|\x1b\][^\x07\x1b]*(?:\x07|\x1b\\)|\x1b[@-_]")
_LOGGED = "_wdss_logged"  # set on an exception whose traceback is in the log file
_running = ["wdss"]  # the command that teed_output runs: what records are named by default


def _file_handlers() -> list[logging.FileHandler]:
    return [h for h in logging.getLogger().handlers if isinstance(h, logging.FileHandler)]


def log_files() -> list[Path]:
    """This job's log files: those of the root logger's file handlers (Hydra's ``<job>.log``)."""
    return [Path(h.baseFilename) for h in _file_handlers()]


def log_files_to_mlflow(client: Any, run_id: str | None, name: str | None = None) -> None:
    """This job's log files as they stand, artifacts of an MLflow run (``client``: an ``MlflowClient``, or a logger's
    experiment, which on ranks but 0 logs nothing). A log the store cannot take is reported, not raised: the run
    it belongs to has done its work."""
    for handler in _file_handlers():
        handler.flush()
    for path in log_files():
        try:
            client.log_artifact(run_id, str(path))
        except Exception as err:  # noqa: BLE001 - any store's error
            print(f"{name or _running[-1]}: could not log {path} to MLflow: {err}", file=sys.stderr)


def to_log_file(text: str, level: int = logging.INFO, name: str | None = None) -> None:
    """Write ``text`` to this job's log file only (the root logger's file handlers, not its console), as a record
    of ``name`` (default: the running command)."""
    handlers = _file_handlers()
    if not handlers:
        return
    record = logging.LogRecord(name or _running[-1], level, "", 0, text, None, None)
    for handler in handlers:
        if level >= handler.level:
            handler.handle(record)


def log_exception(error: BaseException, name: str | None = None) -> None:
    """Write ``error``'s traceback to this job's log file, once however many callers report it."""
    if getattr(error, _LOGGED, False):
        return
    to_log_file("".join(traceback.format_exception(error)).rstrip(), logging.ERROR, name)
    with contextlib.suppress(AttributeError):  # an exception type with __slots__ may be logged twice
        setattr(error, _LOGGED, True)


class _Tee:
    """A text stream that writes to ``stream`` and hands each complete line to :func:`to_log_file`."""

    def __init__(self, stream: TextIO, name: str, level: int) -> None:
        self.stream, self.name, self.level = stream, name, level
        self._partial = ""
        self._lock = threading.Lock()

    def write(self, text: str) -> int:
        written = self.stream.write(text)
        with self._lock:
            *lines, partial = (self._partial + text).split("\n")
            _, cr, redrawn = partial.rpartition("\r")
            self._partial = redrawn if cr and redrawn else partial  # a bar redrawn in place: keep its last state
        for line in lines:
            self._log(line)
        return written

    def _log(self, line: str) -> None:
        line = _CONTROL.sub("", line.rstrip("\r").rpartition("\r")[2]).rstrip()
        if line.strip():
            to_log_file(line, self.level, self.name)

    def close_line(self) -> None:
        """Log what was written after the last newline."""
        with self._lock:
            partial, self._partial = self._partial, ""
        self._log(partial)

    def flush(self) -> None:
        self.stream.flush()

    def __getattr__(self, name: str) -> Any:  # isatty, fileno, encoding, buffer, ...: the stream's
        return getattr(self.stream, name)


def console(stream: TextIO) -> TextIO:
    """The stream behind a tee of :func:`teed_output`: what reaches the terminal without reaching the log file."""
    return stream.stream if isinstance(stream, _Tee) else stream


@contextmanager
def teed_output(name: str) -> Iterator[None]:
    """While inside, what is printed to stdout and stderr also goes to this job's log file, as records of ``name``
    (the command)."""
    if isinstance(sys.stdout, _Tee) or isinstance(sys.stderr, _Tee):  # an entry point called by another
        yield
        return
    saved = sys.stdout, sys.stderr
    tees = _Tee(sys.stdout, name, logging.INFO), _Tee(sys.stderr, name, logging.WARNING)
    sys.stdout, sys.stderr = tees
    _running.append(name)
    try:
        yield
    finally:
        sys.stdout, sys.stderr = saved
        _running.pop()
        for tee in tees:
            tee.close_line()
