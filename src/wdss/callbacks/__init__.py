"""Lightning callbacks of wdss: what a run shows and records beside the module's own metrics.

The training module knows nothing of MLflow: these callbacks log its pictures and per-frame histories into the
trainer's MLflow run (:func:`~wdss.tracking.logged_run.logged_run`), and nothing where there is none.
"""

from __future__ import annotations

from lightning.pytorch.callbacks import Callback

__all__ = ["mlflow_callbacks"]


def mlflow_callbacks() -> list[Callback]:
    """What every wdss trainer that tests or validates a :class:`~wdss.training.module.SuperResolutionModule` logs to
    MLflow: the validation panels and first test frames (:mod:`wdss.callbacks.images`), and the per-frame metric
    histories (:mod:`wdss.callbacks.frame_metrics`)."""
    from wdss.callbacks.frame_metrics import FrameMetrics
    from wdss.callbacks.images import FirstTestFrames, ValidationPanels

    return [ValidationPanels(), FirstTestFrames(), FrameMetrics()]
