"""The runs a report reads from MLflow: a sweep's parent run and its jobs, runs by id or by filter, and the jobs of
a runtime sweep."""

from __future__ import annotations

import os
from collections import Counter
from collections.abc import Sequence

from wdss.report.rows import tags_of


def tracking_client(uri: str | None):
    """An MLflow client of ``uri``, else of $MLFLOW_TRACKING_URI, else of the project's SQLite store."""
    from mlflow import MlflowClient

    return MlflowClient(uri or os.environ.get("MLFLOW_TRACKING_URI", "sqlite:///mlflow.db"))


def find_parent(client, sweep: str | None = None, parent: str | None = None):
    """The parent run of a sweep: by id, or the newest parent run tagged with the sweep's name."""
    if parent:
        return client.get_run(parent)
    experiments = [e.experiment_id for e in client.search_experiments()]
    runs = client.search_runs(experiments, filter_string=f"tags.sweep = '{sweep}'", order_by=["start_time DESC"])
    parents = [r for r in runs if "mlflow.parentRunId" not in r.data.tags]
    if not parents:
        raise SystemExit(f"wdss.report: no sweep named {sweep!r} in {client.tracking_uri}")
    return parents[0]


def collect(client, parent_id: str) -> list:
    experiment = client.get_run(parent_id).info.experiment_id
    return client.search_runs([experiment], filter_string=f"tags.mlflow.parentRunId = '{parent_id}'")


def runtime_runs(client, runtime: str) -> list:
    """The jobs of a runtime sweep, by sweep name or parent run id."""
    from mlflow.exceptions import MlflowException

    try:
        parent = client.get_run(runtime)
    except MlflowException:
        parent = find_parent(client, sweep=runtime)
    jobs = collect(client, parent.info.run_id)
    if not any("bench/ms_per_frame" in run.data.metrics for run in jobs):
        raise SystemExit(f"wdss.report: the runtime sweep {runtime!r} ({parent.info.run_id}) has no timed job")
    return jobs


def _reported(run) -> bool:
    """A run with something to report: test metrics or a benchmark (not a sweep's parent, not a bare training)."""
    return any(key.startswith(("test/", "bench/")) for key in run.data.metrics)


def find_runs(client, ids: Sequence[str] = (), experiment: str | None = None, filter_string: str = "") -> list:
    """The runs named by id, or those of an experiment that match an MLflow filter; runs without test or bench
    metrics (sweep parents, trainings stopped before testing) are left out."""
    from mlflow.exceptions import MlflowException

    if ids:
        runs = []
        for run_id in ids:
            try:
                runs.append(client.get_run(run_id))
            except MlflowException:
                raise SystemExit(f"wdss.report: no run {run_id} in {client.tracking_uri}") from None
    else:
        found = client.get_experiment_by_name(experiment)
        if found is None:
            names = ", ".join(e.name for e in client.search_experiments())
            raise SystemExit(f"wdss.report: no experiment {experiment!r} in {client.tracking_uri} (it has: {names})")
        runs = client.search_runs([found.experiment_id], filter_string=filter_string, max_results=5000)
    reported = [run for run in runs if _reported(run)]
    if not reported:
        raise SystemExit("wdss.report: none of these runs has test or bench metrics")
    return reported


def check_one_dataset(parent_run, runs: Sequence) -> None:
    """Refuse to average a parent's children as seeds when they evaluated different data (a training run whose
    evaluations read other scenes): ``--runs`` reports them with a row per data root."""
    roots = Counter(tags_of(run).get("data_root", "unknown") for run in runs)
    if len(roots) > 1:
        listed = ", ".join(f"{root} ({n} run{'s' * (n > 1)})" for root, n in sorted(roots.items()))
        ids = " ".join(run.info.run_id for run in runs)
        raise SystemExit(
            f"wdss.report: the runs under {parent_run.info.run_id} read different data ({listed}); they are not "
            f"seeds of one row: python -m wdss.report --runs {ids}"
        )
