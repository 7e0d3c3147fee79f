"""Faults: a training killed mid-run (SIGTERM, SIGKILL) resumes with ckpt_path=last to the same metrics as an
uninterrupted run, its checkpoint survives, and MLflow never keeps it RUNNING."""

from __future__ import annotations

import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import pytest

from wdss.paths import PROJECT_ROOT

pytestmark = pytest.mark.slow

OVERRIDES = [
    "experiment=smoke",
    "variant=dwt_haar",
    "trainer.max_epochs=8",
    "trainer.deterministic=true",
    "test=false",
    "bench=null",
    "model.image_every_n_epochs=0",
]


def last_epoch(tmp_path: Path) -> int | None:
    """The epoch that a run's last.ckpt holds, or None before there is one."""
    import torch

    found = list((tmp_path / "outputs").glob("runs/*/checkpoints/last.ckpt"))
    try:
        return int(torch.load(found[0], map_location="cpu", weights_only=True)["epoch"]) if found else None
    except (OSError, RuntimeError):  # Lightning moves a whole file into place, but a poll may land on the move
        return None


def run(
    tmp_path: Path, *extra: str, kill: int | None = None, after_epoch: int = 0
) -> subprocess.CompletedProcess | int:
    env = {**os.environ, "MLFLOW_TRACKING_URI": f"sqlite:///{tmp_path}/mlflow.db", "MLFLOW_DISABLE_TELEMETRY": "true"}
    command = [
        sys.executable,
        "-m",
        "wdss.train",
        *OVERRIDES,
        f"paths.log_dir={tmp_path}/outputs",
        f"hydra.run.dir={tmp_path}/outputs/runs/{time.time_ns()}",
        *extra,
    ]
    if kill is None:
        return subprocess.run(command, cwd=PROJECT_ROOT, env=env, capture_output=True, text=True, timeout=600)
    process = subprocess.Popen(command, cwd=PROJECT_ROOT, env=env, stdout=subprocess.DEVNULL, stderr=subprocess.PIPE)
    deadline = time.time() + 300
    while not list((tmp_path / "outputs").glob("runs/*/checkpoints/last.ckpt")):  # killed after epoch 0 or later
        assert process.poll() is None and time.time() < deadline, "training ended before it could be killed"
        time.sleep(0.02)
    while after_epoch and (last_epoch(tmp_path) or 0) < after_epoch:
        assert process.poll() is None and time.time() < deadline, f"no last.ckpt of epoch {after_epoch} or later"
        time.sleep(0.1)
    process.send_signal(kill)
    return process.wait(timeout=120)


def runs(tmp_path: Path):
    from mlflow import MlflowClient

    client = MlflowClient(f"sqlite:///{tmp_path}/mlflow.db")
    experiment = client.get_experiment_by_name("wdss")
    return client, client.search_runs([experiment.experiment_id], order_by=["start_time ASC"])


@pytest.fixture(scope="module")
def uninterrupted(tmp_path_factory):
    tmp = tmp_path_factory.mktemp("uninterrupted")
    done = run(tmp)
    assert done.returncode == 0, done.stderr[-2000:]
    _, (only,) = runs(tmp)
    return only.data.metrics


@pytest.mark.parametrize("kill", [signal.SIGTERM, signal.SIGKILL], ids=["SIGTERM", "SIGKILL"])
def test_a_killed_training_resumes_to_the_same_metrics(kill, tmp_path, uninterrupted):
    code = run(tmp_path, kill=kill)
    assert code != 0
    assert list((tmp_path / "outputs").glob("runs/*/checkpoints/last.ckpt"))  # the checkpoint is kept
    client, (killed,) = runs(tmp_path)
    if kill == signal.SIGTERM:
        assert code == 128 + signal.SIGTERM and killed.info.status == "KILLED"  # it said so on its way out
    resumed = run(tmp_path, "ckpt_path=last")
    assert resumed.returncode == 0, resumed.stderr[-2000:]
    assert "resuming" in resumed.stdout
    _, after = runs(tmp_path)
    assert len(after) == 1 and after[0].info.status == "FINISHED"  # the same MLflow run, closed
    for key in ("val/psnr", "val/ssim", "val/loss", "train/loss"):
        assert after[0].data.metrics[key] == pytest.approx(uninterrupted[key], rel=1e-6, abs=1e-7), key


def test_a_run_killed_without_a_chance_to_report_is_marked_killed(tmp_path):
    assert run(tmp_path, kill=signal.SIGKILL) != 0
    client, (killed,) = runs(tmp_path)
    assert killed.info.status == "RUNNING"  # nothing could close it...
    other = run(tmp_path, "variant=none")  # ...until the next training on this machine looks
    assert other.returncode == 0, other.stderr[-2000:]
    assert client.get_run(killed.info.run_id).info.status == "KILLED"


def test_sigkill_after_non_improving_epochs_resumes_from_the_last_epoch(tmp_path):
    """lr=0: val/psnr never improves after epoch 0, yet last.ckpt follows every epoch and the resume starts
    after the epoch it holds (2 steps per epoch at experiment=smoke), nothing trained twice."""
    frozen = ("model.optimizer.lr=0", "trainer.max_epochs=60")
    assert run(tmp_path, *frozen, kill=signal.SIGKILL, after_epoch=2) == -signal.SIGKILL
    [checkpoints] = (tmp_path / "outputs").glob("runs/*/checkpoints")
    assert sorted(p.name for p in checkpoints.iterdir()) == ["epoch000.ckpt", "last.ckpt"]  # the best is epoch 0
    saved = last_epoch(tmp_path)
    assert saved >= 2
    started_ms = time.time() * 1000
    resumed = run(tmp_path, *frozen[:1], "ckpt_path=last", f"trainer.max_epochs={saved + 2}")
    assert resumed.returncode == 0, resumed.stderr[-2000:]
    client, [only] = runs(tmp_path)
    history = client.get_metric_history(only.info.run_id, "train/loss")
    assert sorted(m.step for m in history if m.timestamp >= started_ms) == [2 * saved + 2, 2 * saved + 3]
