"""Per-frame metric histories (wdss.callbacks.frame_metrics), and every MLflow callback against a real SQLite run."""

from __future__ import annotations

import math
from types import SimpleNamespace

import lightning as L
import pytest
import torch
from torch.utils.data import DataLoader

import wdss.callbacks.frame_metrics as frame_metrics
from tests.helpers import batch
from tests.training.test_module import module
from wdss.callbacks import mlflow_callbacks
from wdss.callbacks.frame_metrics import FrameMetrics, frame_histories
from wdss.tracking.logged_run import LoggedRun
from wdss.training.temporal_metrics import TemporalStability, _Sums


def test_histories_step_by_frame_leave_out_non_finite_values_and_name_sequences_as_mlflow_allows():
    stability = TemporalStability()
    stability.add(
        {"scene:a/b": _Sums(frames=[(0, 30.0, math.nan, math.nan), (1, 31.5, 0.02, 0.01), (2, math.inf, 0.03, 0.01)])}
    )
    metrics = frame_histories("2.5x", stability, timestamp=7)
    assert [(m.key, m.step, m.value) for m in metrics] == [
        ("frames/scene_a_b/psnr_2.5x", 0, 30.0),
        ("frames/scene_a_b/psnr_2.5x", 1, 31.5),
        ("frames/scene_a_b/twe_2.5x", 1, 0.02),
        ("frames/scene_a_b/twe_target_2.5x", 1, 0.01),
        ("frames/scene_a_b/twe_2.5x", 2, 0.03),
        ("frames/scene_a_b/twe_target_2.5x", 2, 0.01),
    ]
    assert {m.timestamp for m in metrics} == {7}


def test_histories_go_to_mlflow_in_batches_of_a_thousand_per_scale(monkeypatch):
    batches = []
    client = SimpleNamespace(log_batch=lambda run_id, metrics: batches.append((run_id, len(metrics))))
    monkeypatch.setattr(frame_metrics, "logged_run", lambda trainer: LoggedRun(client, "run"))
    long, short = TemporalStability(), TemporalStability()
    long.add({"s": _Sums(frames=[(frame, 30.0, 0.1, 0.1) for frame in range(400)])})  # 1200 metrics
    short.add({"s": _Sums(frames=[(0, 30.0, math.nan, math.nan)])})
    FrameMetrics().on_test_end(None, SimpleNamespace(temporal_stability={"2x": long, "3x": short}))
    assert batches == [("run", 1000), ("run", 200), ("run", 1)]
    monkeypatch.setattr(frame_metrics, "logged_run", lambda trainer: None)  # logging off
    FrameMetrics().on_test_end(None, SimpleNamespace(temporal_stability={"2x": long}))
    assert len(batches) == 3


def frames(sequence: str, first: int, scale: float, motion: bool = True) -> dict:
    """Two consecutive frames of ``sequence``, a static plane (history valid everywhere) when ``motion``."""
    step = batch(n=2, size=(16, 16), scale=scale, seed=first)
    step["sequence"], step["frame"] = [sequence] * 2, torch.tensor([first, first + 1])
    if motion:
        step["motion"] = torch.zeros(2, 2, 16, 16)
        step["gbuffer"] = torch.full((2, 11, 16, 16), 0.5)
    return step


@pytest.fixture
def mlflow_logger(tmp_path, monkeypatch):
    from lightning.pytorch.loggers import MLFlowLogger

    monkeypatch.setenv("MLFLOW_DISABLE_TELEMETRY", "true")
    return MLFlowLogger(experiment_name="wdss", tracking_uri=f"sqlite:///{tmp_path}/mlflow.db")


def fit_and_test(tmp_path, model, logger) -> L.Trainer:
    trainer = L.Trainer(
        max_epochs=2,
        logger=logger,
        callbacks=mlflow_callbacks(),
        enable_checkpointing=False,
        enable_progress_bar=False,
        enable_model_summary=False,
        default_root_dir=tmp_path,
    )
    train = DataLoader([batch(n=2, size=(16, 16))], batch_size=None)
    trainer.fit(model, train, DataLoader([batch(n=2, size=(16, 16), seed=1)] * 2, batch_size=None))
    tests = [DataLoader([frames("seq", 0, 2.0), frames("seq", 2, 2.0), frames("other", 0, 2.0)], batch_size=None)]
    tests.append(DataLoader([frames("seq", 0, 3.0)], batch_size=None))
    trainer.test(model, tests, verbose=False)
    return trainer


def test_a_fit_and_test_log_panels_test_frames_and_frame_histories_into_the_run(tmp_path, mlflow_logger):
    torch.manual_seed(0)
    model = module(image_every_n_epochs=2)
    fit_and_test(tmp_path, model, mlflow_logger)
    client, run_id = mlflow_logger.experiment, mlflow_logger.run_id
    # epoch 0 only (every 2nd epoch of 2), its panel and the subbands of the wavelet network
    assert {a.path for a in client.list_artifacts(run_id, "images")} == {
        "images/val_epoch000.png",
        "images/subbands_epoch000.png",
    }
    names = ("2x", "2x_t1", "2x_t2", "3x", "3x_t1")  # the first sequence of each scale, three frames at most
    expected = {f"test/{kind}_{name}.png" for kind in ("pred", "target") for name in names}
    assert {a.path for a in client.list_artifacts(run_id, "test")} == expected
    for label in ("2x", "3x"):
        stability = model.temporal_stability[label]
        for sequence in stability.sequences:
            values = stability.frames(sequence)
            for index, name in enumerate(("psnr", "twe", "twe_target"), start=1):
                history = client.get_metric_history(run_id, f"frames/{sequence}/{name}_{label}")
                expected = [(f[0], f[index]) for f in values if math.isfinite(f[index])]
                got = sorted((m.step, m.value) for m in history)
                assert expected and [s for s, _ in got] == [s for s, _ in expected], name
                assert [v for _, v in got] == pytest.approx([v for _, v in expected], rel=1e-6), name
    assert [m.step for m in client.get_metric_history(run_id, "frames/seq/psnr_2x")] == [0, 1, 2, 3]
    assert sorted(m.step for m in client.get_metric_history(run_id, "frames/seq/twe_2x")) == [1, 2, 3]
    assert {"test/twe_2x", "test/tpsnr_3x", "test/psnr_2x"} <= set(client.get_run(run_id).data.metrics)


def test_without_an_mlflow_logger_the_callbacks_log_nothing_and_the_module_still_pools(tmp_path):
    torch.manual_seed(0)
    model = module()
    trainer = fit_and_test(tmp_path, model, False)
    assert trainer.loggers == [] and set(model.temporal_stability) == {"2x", "3x"}
    assert "test/twe_2x" in trainer.callback_metrics
