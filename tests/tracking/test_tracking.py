"""Tracking store: simultaneous first runs on a fresh SQLite file both reach MLflow; ``make ui`` shows the store
that training logs to."""

from __future__ import annotations

import os
import shutil
import subprocess
import sys
from pathlib import Path

import pytest

from wdss.paths import PROJECT_ROOT

# Each process opens the store through wdss.tracking.prepare_store once both are ready, then records a run.
FIRST_RUN = """
import sys, time
from pathlib import Path
from mlflow import MlflowClient
from wdss.tracking import prepare_store

uri, barrier, me = sys.argv[1], Path(sys.argv[2]), sys.argv[3]
(barrier / me).touch()
while len(list(barrier.iterdir())) < 2:  # start together: the race is on the first use of the file
    time.sleep(0.001)
prepare_store(uri)
client = MlflowClient(uri)
client.set_terminated(client.create_run("0").info.run_id)
"""


@pytest.mark.slow
def test_two_first_runs_on_a_fresh_sqlite_file_both_succeed(tmp_path: Path):
    uri = f"sqlite:///{tmp_path}/mlflow.db"
    barrier = tmp_path / "ready"
    barrier.mkdir()
    env = {**os.environ, "MLFLOW_DISABLE_TELEMETRY": "true"}
    processes = [
        subprocess.Popen(
            [sys.executable, "-c", FIRST_RUN, uri, str(barrier), name],
            cwd=PROJECT_ROOT,
            env=env,
            stdout=subprocess.PIPE,
            stderr=subprocess.PIPE,
            text=True,
        )
        for name in ("a", "b")
    ]
    for process in processes:
        _, err = process.communicate(timeout=300)
        assert process.returncode == 0, err[-3000:]
    from mlflow import MlflowClient

    runs = MlflowClient(uri).search_runs(["0"])
    assert len(runs) == 2 and {r.info.status for r in runs} == {"FINISHED"}


@pytest.mark.skipif(shutil.which("make") is None, reason="needs make")
@pytest.mark.parametrize("uri", [None, "sqlite:////elsewhere/team.db"])
def test_make_ui_opens_the_store_training_logs_to(uri):
    env = {k: v for k, v in os.environ.items() if k != "MLFLOW_TRACKING_URI"}
    if uri:
        env["MLFLOW_TRACKING_URI"] = uri
    done = subprocess.run(["make", "-n", "ui"], cwd=PROJECT_ROOT, env=env, capture_output=True, text=True, check=True)
    [command] = [line for line in done.stdout.splitlines() if "mlflow ui" in line]
    assert f"--backend-store-uri '{uri or 'sqlite:///mlflow.db'}' --host 127.0.0.1" in command


def test_run_links_open_the_runs_table_and_the_run(tmp_path):
    from mlflow import MlflowClient

    from wdss.tracking import run_links, runs_view_url

    uri = f"sqlite:///{tmp_path}/mlflow.db"
    client = MlflowClient(uri)
    experiment = client.create_experiment("wdss", artifact_location=(tmp_path / "a").as_uri())
    run = client.create_run(experiment).info.run_id
    runs = f"http://127.0.0.1:5000/#/experiments/{experiment}/runs"
    assert run_links(uri, run).splitlines() == [
        f"MLflow runs: {runs}?workflowType=machine_learning (make ui)",
        f"MLflow run:  {runs}/{run}",
    ]
    assert runs_view_url(uri) == f"{runs}?workflowType=machine_learning"
    assert runs_view_url(uri, "other") == "http://127.0.0.1:5000/#/experiments"
