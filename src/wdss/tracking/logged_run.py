"""The MLflow run a Lightning trainer logs to: where wdss's callbacks put their images, histories and videos."""

from __future__ import annotations

from typing import TYPE_CHECKING, NamedTuple

import lightning as L
from lightning.pytorch.loggers import MLFlowLogger

if TYPE_CHECKING:
    from mlflow import MlflowClient

__all__ = ["LoggedRun", "logged_run"]


class LoggedRun(NamedTuple):
    """An MLflow client and the id of the run to log into."""

    client: MlflowClient
    run_id: str


def logged_run(trainer: L.Trainer) -> LoggedRun | None:
    """The client and run of the trainer's first :class:`~lightning.pytorch.loggers.MLFlowLogger`; None where nothing
    is logged: no such logger (``logger=False``, logging off), or a DDP rank other than 0 (MLFlowLogger logs on
    rank 0 only)."""
    if not trainer.is_global_zero:
        return None
    for logger in trainer.loggers:
        if isinstance(logger, MLFlowLogger) and logger.run_id is not None:  # run_id starts the run if it is new
            return LoggedRun(logger.experiment, logger.run_id)
    return None
