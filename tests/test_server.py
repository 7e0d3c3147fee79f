"""A team tracking server: ``make server``'s command on a free loopback port; a smoke training and a two-job smoke
sweep log to it over HTTP, their artifacts proxied into the server's folder, and the report reads them back."""

from __future__ import annotations

import os
import shlex
import shutil
import signal
import socket
import subprocess
import sys
import time
import urllib.request
from collections.abc import Iterator
from pathlib import Path

import pytest

from tests.test_train import run_module
from wdss.paths import PROJECT_ROOT

pytestmark = [pytest.mark.slow, pytest.mark.skipif(shutil.which("make") is None, reason="needs make")]


def free_port() -> int:
    with socket.socket() as probe:
        probe.bind(("127.0.0.1", 0))
        return probe.getsockname()[1]


@pytest.fixture
def server(tmp_path: Path) -> Iterator[str]:
    """``make server`` with this test's store, artifact folder and port; stopped by its pid at the end."""
    port = free_port()
    variables = [
        f"SERVER_PORT={port}",
        f"SERVER_STORE=sqlite:///{tmp_path}/server.db",
        f"SERVER_ARTIFACTS={tmp_path}/artifacts",
        "SERVER_WORKERS=1",
    ]
    make = subprocess.run(["make", "-n", "server", *variables], cwd=PROJECT_ROOT, capture_output=True, text=True)
    assert make.returncode == 0, make.stderr
    [command] = [line for line in make.stdout.splitlines() if "mlflow server" in line]
    log = (tmp_path / "server.log").open("w")
    env = {**os.environ, "MLFLOW_DISABLE_TELEMETRY": "true"}
    # A session of its own: the server's pid is also the group of the workers it starts, stopped together.
    process = subprocess.Popen(
        shlex.split(command), cwd=PROJECT_ROOT, env=env, stdout=log, stderr=subprocess.STDOUT, start_new_session=True
    )
    url = f"http://127.0.0.1:{port}"
    try:
        deadline = time.monotonic() + 180
        while True:
            assert process.poll() is None, (tmp_path / "server.log").read_text()[-3000:]
            try:
                with urllib.request.urlopen(f"{url}/health", timeout=5) as answer:
                    if answer.status == 200:
                        break
            except OSError:
                assert time.monotonic() < deadline, "the server did not answer in 180 s"
                time.sleep(0.5)
        yield url
    finally:
        os.killpg(process.pid, signal.SIGTERM)
        try:
            process.wait(timeout=60)
        except subprocess.TimeoutExpired:
            os.killpg(process.pid, signal.SIGKILL)
            process.wait()
        log.close()


def test_runs_sweeps_artifacts_and_the_report_through_a_tracking_server(server, tmp_path):
    from mlflow import MlflowClient

    outputs = f"paths.log_dir={tmp_path}/outputs"
    env = {**os.environ, "MLFLOW_TRACKING_URI": server, "MLFLOW_DISABLE_TELEMETRY": "true"}
    training = subprocess.Popen(  # beside the sweep: two clients of the server at once
        [sys.executable, "-m", "wdss.train", "experiment=smoke", "test=false", "bench=null", outputs],
        cwd=PROJECT_ROOT,
        env=env,
        stdout=subprocess.DEVNULL,
        stderr=subprocess.PIPE,
        text=True,
    )
    done = run_module(
        tmp_path,
        "wdss.train",
        "-cd",
        "sweeps",
        "-cn",
        "ablation_wavelet",
        "experiment=smoke",
        "variant=none,swt_haar",
        "seed=0",
        outputs,
        tracking=server,
    )
    assert done.returncode == 0, done.stderr[-3000:]
    _, errors = training.communicate(timeout=600)
    assert training.returncode == 0, errors[-3000:]
    report = run_module(
        tmp_path, "wdss.report", "--sweep", "ablation_wavelet", "--out", f"{tmp_path}/reports", tracking=server
    )
    assert report.returncode == 0, report.stderr[-3000:]
    assert "| SWT-haar |" in (tmp_path / "reports" / "ablation_wavelet" / "table.md").read_text()

    client = MlflowClient(server)
    experiments = {name: client.get_experiment_by_name(name) for name in ("wdss", "ablation_wavelet")}
    for experiment in experiments.values():  # the UI opens them on their runs, not on the GenAI overview
        assert experiment.tags["mlflow.experimentKind"] == "custom_model_development"
        assert experiment.artifact_location.startswith("mlflow-artifacts:")  # proxied by the server
    [training] = client.search_runs([experiments["wdss"].experiment_id])
    sweep = client.search_runs([experiments["ablation_wavelet"].experiment_id])
    [parent] = [r for r in sweep if "mlflow.parentRunId" not in r.data.tags]
    jobs = [r for r in sweep if r.data.tags.get("mlflow.parentRunId") == parent.info.run_id]
    assert sorted(r.data.tags["variant"] for r in jobs) == ["none", "swt_haar"] and len(sweep) == 3
    assert parent.info.status == "FINISHED" and parent.data.tags["jobs"] == "2"
    assert all(r.info.status == "FINISHED" and "test/psnr_2x" in r.data.metrics for r in jobs)
    for run in [training, *jobs]:
        assert run.data.tags["experiment"] == "smoke" and run.data.tags["seed"] == "0"
        artifacts = {a.path for a in client.list_artifacts(run.info.run_id)}
        assert {"config.yaml", ".hydra", "images"} <= artifacts, artifacts
        assert ".hydra/overrides.yaml" in {a.path for a in client.list_artifacts(run.info.run_id, ".hydra")}
        assert "images/val_epoch000.png" in {a.path for a in client.list_artifacts(run.info.run_id, "images")}
    assert "report/table.md" in {a.path for a in client.list_artifacts(parent.info.run_id, "report")}
    # The bytes live in the server's artifact folder, under the training run's id.
    assert list((tmp_path / "artifacts").glob(f"*/{training.info.run_id}/artifacts/images/val_epoch000.png"))
