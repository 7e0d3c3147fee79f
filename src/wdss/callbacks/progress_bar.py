"""Lightning's progress bar for a process: rich on a terminal, plain flushed lines in logs, pipes and sweeps.

A tqdm bar written to a file is one endless line of carriage returns; :class:`LineProgressBar` prints a line per
training epoch with its metrics and ETA, one after each test, and one every ``every_s`` seconds within a loop that
takes longer. Printed under an entry point, the lines reach the run's log file too (:mod:`wdss.logfile`); beside a
terminal's rich bar, :class:`LogLines` writes the same lines to the log file only.
"""

from __future__ import annotations

import logging
import sys
import time
import warnings
from typing import Any

from lightning.pytorch.callbacks import Callback, ProgressBar

from wdss.logfile import console, to_log_file
from wdss.progress import duration

__all__ = ["LineProgressBar", "LogLines", "model_line", "progress_bar", "progress_callbacks", "quiet_lightning"]


def progress_bar(*, multirun: bool = False) -> Callback:
    """Lightning's progress bar for this process: rich on a terminal (not in a sweep, whose jobs share the
    terminal), plain lines otherwise."""
    if sys.stdout.isatty() and not multirun:
        from lightning.pytorch.callbacks import RichProgressBar

        # Straight to the terminal: redrawn in place, its rows are no lines for the log file (wdss.logfile)
        return RichProgressBar(console_kwargs={"file": console(sys.stdout)})
    return LineProgressBar()


# Lightning's info lines that say nothing about this run: advertisements, the absent accelerators, limits of 1.0.
_CHATTER = ("💡 Tip:", "GPU available:", "TPU available:", "HPU available:", "`Trainer(limit_")


class _Chatter(logging.Filter):
    def filter(self, record: logging.LogRecord) -> bool:
        return not str(record.getMessage()).startswith(_CHATTER)


def quiet_lightning() -> None:
    """Drop Lightning's chatter (:data:`_CHATTER`) and the deprecation warning its pytree helper raises under this
    torch on every fit; warnings and errors pass. Idempotent."""
    log = logging.getLogger("lightning.pytorch.utilities.rank_zero")
    if not any(isinstance(f, _Chatter) for f in log.filters):
        log.addFilter(_Chatter())
    warnings.filterwarnings("ignore", message=r".*isinstance\(treespec, LeafSpec\)` is deprecated")


def model_line(module: Any) -> str:
    """One line in place of Lightning's model summary table (whose FLOPs column reads 0 without an example input)."""
    net = getattr(module, "net", module)
    total = sum(p.numel() for p in net.parameters())
    trainable = sum(p.numel() for p in net.parameters() if p.requires_grad)
    return f"model: {type(net).__name__}, {total:,} parameters ({trainable:,} trainable)"


def progress_callbacks(*, multirun: bool = False) -> list[Callback]:
    """:func:`progress_bar`, and beside a rich bar :class:`LogLines`: the run's log file gets the plain lines.
    Lightning's chatter is dropped from then on (:func:`quiet_lightning`)."""
    quiet_lightning()
    bar = progress_bar(multirun=multirun)
    return [bar] if isinstance(bar, LineProgressBar) else [bar, LogLines()]


class LogLines(Callback):
    """The plain progress lines of :class:`LineProgressBar`, written to the run's log file only (beside a terminal's
    rich bar, which draws them on screen).

    ``epoch 3/16: 30 batches in 11s, ETA 2m26s, train/loss=0.0715 val/psnr=32.3`` after every training epoch
    (validation included), ``validate: ...`` / ``test: ...`` after those loops, and ``epoch 3/16: batch 120/400 ...``
    every ``every_s`` seconds within a loop that takes longer.
    """

    def __init__(self, every_s: float = 60.0) -> None:
        super().__init__()
        self.every_s = every_s
        self._enabled = True
        self._start = self._last = time.monotonic()
        self._train_batches = self._val_batches = self._test_batches = 0

    def setup(self, trainer: Any, pl_module: Any, stage: str) -> None:
        self._enabled = trainer.is_global_zero  # as Lightning's bars: rank 0 reports

    def _print(self, text: str) -> None:
        if self._enabled:
            to_log_file(text)

    def _metrics(self, trainer: Any, pl_module: Any) -> str:
        items = trainer.progress_bar_metrics.items()
        return " ".join(f"{k}={v:.4g}" if isinstance(v, float) else f"{k}={v}" for k, v in items if k != "v_num")

    def _epoch(self, trainer: Any) -> str:
        total = f"/{trainer.max_epochs}" if trainer.max_epochs and trainer.max_epochs > 0 else ""
        return f"epoch {trainer.current_epoch + 1}{total}"

    def _restart(self) -> None:
        self._start = self._last = time.monotonic()

    def _tick(self, label: str, done: int, total: float, trainer: Any, pl_module: Any) -> None:
        now = time.monotonic()
        if now - self._last >= self.every_s:
            self._last = now
            of = f"/{total}" if total != float("inf") else ""
            self._print(
                f"{label}: batch {done}{of} ({duration(now - self._start)}) {self._metrics(trainer, pl_module)}"
            )

    def on_train_epoch_start(self, trainer: Any, pl_module: Any) -> None:
        self._restart()
        self._train_batches = 0

    def on_train_batch_end(self, trainer: Any, pl_module: Any, *args: Any, **kwargs: Any) -> None:
        self._train_batches += 1
        self._tick(self._epoch(trainer), self._train_batches, trainer.num_training_batches, trainer, pl_module)

    def on_train_epoch_end(self, trainer: Any, pl_module: Any) -> None:
        elapsed = time.monotonic() - self._start
        batches = self._train_batches
        eta = ""
        if trainer.max_epochs and trainer.max_epochs > 0:
            eta = f", ETA {duration((trainer.max_epochs - trainer.current_epoch - 1) * elapsed)}"
        text = f"{self._epoch(trainer)}: {batches} batches in {duration(elapsed)}{eta}"
        self._print(f"{text}, {self._metrics(trainer, pl_module)}")

    def on_validation_start(self, trainer: Any, pl_module: Any) -> None:
        self._val_batches = 0
        if trainer.state.fn == "validate":
            self._restart()  # inside fit, a validation keeps its epoch's clock

    def on_validation_batch_end(self, trainer: Any, pl_module: Any, *args: Any, **kwargs: Any) -> None:
        self._val_batches += 1
        label = "validate" if trainer.state.fn == "validate" else f"{self._epoch(trainer)} validation"
        if not trainer.sanity_checking:
            total = trainer.num_val_batches
            self._tick(label, self._val_batches, sum(total) if isinstance(total, list) else total, trainer, pl_module)

    def on_validation_end(self, trainer: Any, pl_module: Any) -> None:
        if trainer.state.fn == "validate":
            elapsed = duration(time.monotonic() - self._start)
            self._print(f"validate: {self._val_batches} batches in {elapsed}, {self._metrics(trainer, pl_module)}")

    def on_test_start(self, trainer: Any, pl_module: Any) -> None:
        self._restart()
        self._test_batches = 0

    def on_test_batch_end(self, trainer: Any, pl_module: Any, *args: Any, **kwargs: Any) -> None:
        self._test_batches += 1
        self._tick("test", self._test_batches, sum(trainer.num_test_batches), trainer, pl_module)

    def on_test_end(self, trainer: Any, pl_module: Any) -> None:
        self._print(f"test: {self._test_batches} batches in {duration(time.monotonic() - self._start)}")


class LineProgressBar(LogLines, ProgressBar):
    """A progress bar of plain flushed lines (:class:`LogLines`), printed: for logs and pipes."""

    def setup(self, trainer: Any, pl_module: Any, stage: str) -> None:
        ProgressBar.setup(self, trainer, pl_module, stage)  # disables it on ranks but 0

    def disable(self) -> None:
        self._enabled = False

    def enable(self) -> None:
        self._enabled = True

    def _print(self, text: str) -> None:
        if self._enabled:
            print(text, flush=True)
