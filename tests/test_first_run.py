"""``make train`` on a fresh clone: ``python -m wdss.train`` renders its dataset into an empty data folder,
trains, tests and exits 0 (with the tiny preset, conf/render/tiny.yaml, to take seconds rather than minutes)."""

from __future__ import annotations

import os
import subprocess
import sys

import pytest

from wdss.paths import PROJECT_ROOT

pytest.importorskip("bpy", reason="needs the render extra: make setup-render")
pytestmark = pytest.mark.slow


def test_training_renders_its_dataset_on_first_use_then_trains_and_tests(tmp_path):
    data = tmp_path / "data"
    data.mkdir()
    uri = f"sqlite:///{tmp_path}/mlflow.db"
    env = {**os.environ, "MLFLOW_DISABLE_TELEMETRY": "true"}
    env.pop("MLFLOW_TRACKING_URI", None)
    args = ["experiment=smoke", "data=tiny", f"paths.data_dir={data}", f"paths.log_dir={tmp_path}/outputs"]
    done = subprocess.run(
        [sys.executable, "-m", "wdss.train", *args, f"logger.tracking_uri={uri}"],
        cwd=PROJECT_ROOT,
        env=env,
        capture_output=True,
        text=True,
        timeout=600,
    )
    assert done.returncode == 0, done.stderr[-3000:]
    for name in ("train_000", "val_000", "test_000"):
        assert sorted(p.name for p in (data / "tiny" / name).iterdir() if p.is_dir()) == ["12P", "16P", "24P", "48P"]
    # Not a terminal: the render reports each frame as a plain line.
    assert "render train_000: frame 3/3 (" in done.stdout and "render test_000: frame 2/2 (" in done.stdout
    # Training reports plain lines too, and the metrics once, in full: not Lightning's table cut to 80 columns.
    assert "epoch 1/" in done.stdout and "\r" not in done.stdout
    assert "  test/psnr_2x = " in done.stdout and "Test metric" not in done.stdout
    # The run's folder (training runs only: outputs/runs) keeps what it printed in its log file, an MLflow artifact.
    [log] = (tmp_path / "outputs" / "runs").glob("*/train.log")
    assert "][wdss.train][INFO] - epoch 1/" in log.read_text() and "  test/psnr_2x = " in log.read_text()
    assert "  MLflow runs: http://127.0.0.1:5000/#/experiments/" in done.stdout  # the UI's runs table, not GenAI
    from mlflow import MlflowClient

    client = MlflowClient(uri)
    [run] = client.search_runs([client.get_experiment_by_name("wdss").experiment_id])
    assert run.info.status == "FINISHED" and "train.log" in {a.path for a in client.list_artifacts(run.info.run_id)}
    assert {"test/psnr_2x", "test/psnr_4x", "val/psnr", "train/loss"} <= set(run.data.metrics)


def test_a_typo_in_the_data_root_is_one_line_and_creates_nothing(tmp_path):
    data = tmp_path / "data"
    data.mkdir()
    env = {**os.environ, "MLFLOW_DISABLE_TELEMETRY": "true"}
    env.pop("MLFLOW_TRACKING_URI", None)
    args = [f"paths.data_dir={data}", f"paths.log_dir={tmp_path}/outputs", f"data.root={data}/mnii"]
    done = subprocess.run(
        [sys.executable, "-m", "wdss.train", *args, f"logger.tracking_uri=sqlite:///{tmp_path}/mlflow.db"],
        cwd=PROJECT_ROOT,
        env=env,
        capture_output=True,
        text=True,
        timeout=600,
    )
    assert done.returncode == 2, done.stderr[-3000:]
    [line] = [line for line in done.stderr.splitlines() if line.strip()]
    assert line.startswith(f"wdss.train: data root {data}/mnii does not exist (the 'mini' dataset renders on first")
    assert "Traceback" not in done.stderr
    # Nothing rendered, no MLflow store, and no run folder (Hydra's own record of a refused command is removed).
    assert not any(data.iterdir()) and not (tmp_path / "mlflow.db").exists()
    assert not any((tmp_path / "outputs").rglob("*.yaml"))
