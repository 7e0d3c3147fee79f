"""Each test frame's PSNR and warping errors as MLflow metric histories, the frame index as step.

After a test, for every scale ``<s>x`` and test sequence: ``frames/<sequence>/psnr_<s>x``,
``frames/<sequence>/twe_<s>x`` and ``frames/<sequence>/twe_target_<s>x`` (the report plots the PSNR along each
sequence). A frame without a valid pair for the warping error (the first of a sequence) has no ``twe`` point.
The values come from the module's ``temporal_stability`` (:class:`~wdss.training.temporal_metrics.TemporalStability`
per scale label, pooled over the DDP ranks), logged from rank 0 (:func:`~wdss.tracking.logged_run.logged_run`).
"""

from __future__ import annotations

import math
import re
import time
from typing import Any

import lightning as L

from wdss.tracking.logged_run import logged_run
from wdss.training.temporal_metrics import TemporalStability

__all__ = ["BATCH", "FrameMetrics", "frame_histories"]

BATCH = 1000  # MLflow's limit of metrics per log_batch


def frame_histories(label: str, stability: TemporalStability, timestamp: int) -> list[Any]:
    """The MLflow metrics (``mlflow.entities.Metric``) of every frame of every sequence of one scale ``label``,
    the frame index as step, the non-finite values left out."""
    from mlflow.entities import Metric

    metrics = []
    for sequence in stability.sequences:
        key = re.sub(r"[^\w\-. ]", "_", sequence)  # the characters MLflow allows in metric names
        for frame, psnr, twe, twe_target in stability.frames(sequence):
            values = {"psnr": psnr, "twe": twe, "twe_target": twe_target}
            metrics += [
                Metric(f"frames/{key}/{name}_{label}", value, timestamp, frame)
                for name, value in values.items()
                if math.isfinite(value)
            ]
    return metrics


class FrameMetrics(L.Callback):
    """Log the per-frame histories of a test (module docstring) into the trainer's MLflow run.

    Runs at ``on_test_end``: after the module's ``on_test_epoch_end`` (which Lightning calls after the callbacks'
    own) has pooled the ranks' sums into ``temporal_stability``.
    """

    def on_test_end(self, trainer: L.Trainer, pl_module: Any) -> None:
        stability: dict[str, TemporalStability] = getattr(pl_module, "temporal_stability", {})
        run = logged_run(trainer) if stability else None
        if run is None:
            return
        for label, scale_stability in stability.items():
            metrics = frame_histories(label, scale_stability, int(time.time() * 1000))
            for start in range(0, len(metrics), BATCH):
                run.client.log_batch(run.run_id, metrics=metrics[start : start + BATCH])
