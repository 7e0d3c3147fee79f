"""The MLflow run a trainer logs to (wdss.tracking.logged_run): one helper for every callback that logs."""

from __future__ import annotations

from types import SimpleNamespace

import lightning as L
from lightning.pytorch.loggers import CSVLogger, MLFlowLogger

from wdss.tracking.logged_run import logged_run


def test_the_run_of_the_trainers_mlflow_logger_on_rank_zero_only(tmp_path, monkeypatch):
    monkeypatch.setenv("MLFLOW_DISABLE_TELEMETRY", "true")
    mlflow = MLFlowLogger(experiment_name="wdss", tracking_uri=f"sqlite:///{tmp_path}/mlflow.db")
    csv = CSVLogger(tmp_path)
    trainer = L.Trainer(logger=[csv, mlflow], enable_progress_bar=False, default_root_dir=tmp_path)
    run = logged_run(trainer)
    assert run is not None and run.client is mlflow.experiment and run.run_id == mlflow.run_id
    assert mlflow.experiment.get_run(run.run_id).info.status == "RUNNING"
    # Set after the trainer is built, as wdss.train sets its logger once the run is known: found too.
    later = L.Trainer(logger=False, enable_progress_bar=False, default_root_dir=tmp_path)
    later.logger = mlflow
    assert logged_run(later) == run
    # Another DDP rank: MLFlowLogger logs on rank 0 only, so nothing is handed out there.
    assert logged_run(SimpleNamespace(is_global_zero=False, loggers=[mlflow])) is None


def test_no_run_without_an_mlflow_logger(tmp_path):
    assert logged_run(L.Trainer(logger=False, enable_progress_bar=False, default_root_dir=tmp_path)) is None
    assert logged_run(L.Trainer(logger=CSVLogger(tmp_path), enable_progress_bar=False)) is None
