"""MLflow tracking: the logger of a run, its tags and artifacts, and one parent run per sweep.

Runs are named by their overrides (``basis=db4,transform=swt``) and tagged with every config-group choice
(``transform``, ``basis``, ``head``, ``scale``, ``temporal``, ``model``, ``data``, ...), the seed and the git
commit, so the MLflow UI can group and compare them. A multirun gets a parent run (created by the Hydra
callback :class:`SweepParentRun`) and every job is nested under it.
"""

from __future__ import annotations

import atexit
import fcntl
import os
import socket
import subprocess
from pathlib import Path
from typing import Any

from hydra.core.hydra_config import HydraConfig
from hydra.experimental.callback import Callback
from hydra.types import RunMode
from omegaconf import DictConfig, OmegaConf

__all__ = [
    "PARENT_FILE",
    "RUN_ID_FILE",
    "SweepParentRun",
    "ensure_experiment",
    "git_commit",
    "prepare_store",
    "reap_dead_runs",
    "data_tags",
    "run_name",
    "run_tags",
    "runs_view_url",
    "run_links",
]

PARENT_FILE = "mlflow_parent_run_id"  # in the sweep directory
# MLflow 3's UI opens an experiment on its GenAI overview unless this tag says it holds model training runs.
EXPERIMENT_KIND = ("mlflow.experimentKind", "custom_model_development")
RUN_ID_FILE = "mlflow_run_id"  # in a run's output directory: lets ckpt_path=last resume the same run
GROUPS = (
    "variant",
    "transform",
    "basis",
    "head",
    "scale",
    "temporal",
    "model",
    "size",
    "loss",
    "data",
    "trainer",
    "experiment",
)


def git_commit(root: str | Path = ".") -> str:
    """The commit of the working tree (with ``-dirty`` when it has changes), or ``unknown``."""
    try:
        commit = subprocess.run(["git", "rev-parse", "HEAD"], cwd=root, capture_output=True, text=True, check=True)
        dirty = subprocess.run(
            ["git", "status", "--porcelain", "--untracked-files=no"],
            cwd=root,
            capture_output=True,
            text=True,
            check=True,
        )
    except (OSError, subprocess.CalledProcessError):
        return "unknown"
    return commit.stdout.strip() + ("-dirty" if dirty.stdout.strip() else "")


def _hydra() -> Any | None:
    return HydraConfig.get() if HydraConfig.initialized() else None


def run_name(cfg: DictConfig) -> str:
    """``cfg.run_name``, else the job's overrides (without seeds and paths), else ``default``."""
    if cfg.get("run_name"):
        return str(cfg.run_name)
    hydra = _hydra()
    name = hydra.job.override_dirname if hydra is not None else ""
    return name or "default"


def run_tags(cfg: DictConfig) -> dict[str, str]:
    """A tag per config-group choice, the seed, the git commit, and the sweep parent when there is one."""
    tags: dict[str, str] = {}
    hydra = _hydra()
    if hydra is not None:
        for group in GROUPS:
            choice = hydra.runtime.choices.get(group)
            if choice is not None:
                tags[group] = str(choice)
        if hydra.mode == RunMode.MULTIRUN:
            parent = Path(hydra.sweep.dir) / PARENT_FILE
            if parent.exists():
                tags["mlflow.parentRunId"] = parent.read_text().strip()
            tags["sweep"] = hydra.job.config_name
            tags["job"] = str(hydra.job.num)
    if tags.get("transform") == "none":
        tags["basis"] = "n/a (transform=none)"  # the basis is ignored without a wavelet transform
    net_target = str(OmegaConf.select(cfg, "model.net._target_", default=""))
    if net_target.endswith("Upsample"):  # baselines have no wavelet, head or temporal branch
        for key in ("transform", "basis", "head", "temporal", "scale"):
            tags[key] = "n/a (baseline)"
    tags["seed"] = str(cfg.get("seed"))
    tags.update(data_tags(cfg))
    tags["git_commit"] = git_commit(OmegaConf.select(cfg, "paths.root_dir", default="."))
    tags["host"], tags["pid"] = socket.gethostname(), str(os.getpid())  # lets reap_dead_runs find killed runs
    tags.update({str(k): str(v) for k, v in (cfg.get("tags") or {}).items()})
    return tags


def _shown_path(path: Any, cfg: DictConfig) -> str:
    """A data folder as a tag shows it: relative to the project when it lies inside, else as given."""
    folder = Path(str(path))
    root = Path(str(OmegaConf.select(cfg, "paths.root_dir", default=".")))
    try:
        return str(folder.resolve().relative_to(root.resolve()))
    except ValueError:
        return str(folder)


def data_tags(cfg: DictConfig) -> dict[str, str]:
    """``data_root`` (the folder the test split is read from: ``data.test_root`` when set), and ``train_data_root``
    where training read another: the report puts runs of different data in rows of their own."""
    root = OmegaConf.select(cfg, "data.root", default=None)
    if root is None:
        return {}
    test_root = OmegaConf.select(cfg, "data.test_root", default=None)
    tags = {"data_root": _shown_path(test_root or root, cfg)}
    if test_root is not None:
        tags["train_data_root"] = _shown_path(root, cfg)
    return tags


UI_ADDRESS = "http://127.0.0.1:5000"  # where `make ui` serves a local store


def _ui_base(tracking_uri: str) -> tuple[str, str]:
    """The UI's address (a tracking server serves its own; a local store is served by ``make ui``) and a hint."""
    if tracking_uri.startswith(("http://", "https://")):
        return tracking_uri.rstrip("/"), ""
    return UI_ADDRESS, " (make ui)"


def run_links(tracking_uri: str, run_id: str) -> str:
    """Two lines: where the MLflow UI shows the run's experiment as a table of training runs (MLflow 3 opens an
    experiment on its GenAI overview; ``workflowType=machine_learning`` is the runs table), and the run itself."""
    from mlflow import MlflowClient

    experiment_id = MlflowClient(tracking_uri).get_run(run_id).info.experiment_id
    base, hint = _ui_base(tracking_uri)
    return (
        f"MLflow runs: {base}/#/experiments/{experiment_id}/runs?workflowType=machine_learning{hint}\n"
        f"MLflow run:  {base}/#/experiments/{experiment_id}/runs/{run_id}"
    )


def runs_view_url(tracking_uri: str, experiment_name: str = "wdss") -> str:
    """The runs table of ``experiment_name`` in the UI (``make ui`` prints it); the experiments list when the store
    has no such experiment yet."""
    from mlflow import MlflowClient

    base, _ = _ui_base(tracking_uri)
    experiment = MlflowClient(tracking_uri).get_experiment_by_name(experiment_name)
    if experiment is None:
        return f"{base}/#/experiments"
    return f"{base}/#/experiments/{experiment.experiment_id}/runs?workflowType=machine_learning"


def prepare_store(tracking_uri: str) -> None:
    """Create and migrate a SQLite tracking store once, under a lock on ``<db>.lock``, before any run uses it.

    MLflow builds the schema of an empty SQLite file on first use; two processes doing that at once collide in
    its alembic migration ("Online migration expected to match one row") and one of them dies. Under the lock
    the first builds the schema and the others find it finished. MLflow keeps the store for the process, so
    the logger reuses it. Other stores (an ``mlflow server``, a database) are migrated by their operator.
    """
    from mlflow import MlflowClient
    from sqlalchemy.engine import make_url

    if not tracking_uri.startswith("sqlite:"):
        return
    database = make_url(tracking_uri).database
    if not database or database == ":memory:":
        return
    lock = Path(f"{database}.lock")
    lock.parent.mkdir(parents=True, exist_ok=True)
    with lock.open("a") as handle:
        fcntl.flock(handle, fcntl.LOCK_EX)  # released when the file closes
        MlflowClient(tracking_uri)  # opens the store: creates and migrates the schema if the file is new


def ensure_experiment(client: Any, name: str) -> str:
    """The id of the experiment ``name``, created if it is new, tagged so that the UI opens it on its runs."""
    from mlflow.exceptions import MlflowException

    experiment = client.get_experiment_by_name(name)
    if experiment is None:
        try:
            experiment_id = client.create_experiment(name)
        except MlflowException:  # another job of the sweep created it first
            experiment = client.get_experiment_by_name(name)
            if experiment is None:
                raise
            experiment_id = experiment.experiment_id
    else:
        experiment_id = experiment.experiment_id
    key, kind = EXPERIMENT_KIND
    if experiment is None or experiment.tags.get(key) != kind:
        client.set_experiment_tag(experiment_id, key, kind)
    return experiment_id


def _alive(pid: int) -> bool:
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    except PermissionError:
        return True
    return True


def reap_dead_runs(tracking_uri: str, experiment_name: str) -> list[str]:
    """Mark KILLED the RUNNING runs of this host whose process is gone (SIGKILL leaves no chance to say so)."""
    from mlflow import MlflowClient

    client = MlflowClient(tracking_uri)
    experiment = client.get_experiment_by_name(experiment_name)
    if experiment is None:
        return []
    host = socket.gethostname()
    reaped = []
    for run in client.search_runs([experiment.experiment_id], filter_string="attributes.status = 'RUNNING'"):
        tags = run.data.tags
        if tags.get("host") == host and tags.get("pid", "").isdigit() and not _alive(int(tags["pid"])):
            client.set_tag(run.info.run_id, "killed", "process ended without closing the run")
            client.set_terminated(run.info.run_id, "KILLED")
            reaped.append(run.info.run_id)
    return reaped


class SweepParentRun(Callback):
    """Hydra callback: one MLflow parent run per multirun; jobs nest under it (``mlflow.parentRunId``)."""

    def on_multirun_start(self, config: DictConfig, **kwargs: Any) -> None:
        from mlflow import MlflowClient

        uri = _tracking_uri(config)
        prepare_store(uri)
        client = MlflowClient(uri)
        experiment_id = ensure_experiment(client, str(OmegaConf.select(config, "experiment_name", default="wdss")))
        sweep_dir = Path(config.hydra.sweep.dir)
        sweep_dir.mkdir(parents=True, exist_ok=True)
        sweep_name = config.hydra.job.config_name
        run = client.create_run(
            experiment_id,
            run_name=f"sweep {sweep_name}",
            tags={
                "sweep": sweep_name,
                "sweep_dir": str(sweep_dir),
                "git_commit": git_commit(),
                "overrides": " ".join(config.hydra.overrides.task),
            },
        )
        (sweep_dir / PARENT_FILE).write_text(run.info.run_id)
        # Hydra skips on_multirun_end when a job failed (it re-raises after running the others): close then too.
        atexit.register(self._close, uri, run.info.run_id)

    def on_multirun_end(self, config: DictConfig, **kwargs: Any) -> None:
        parent = Path(config.hydra.sweep.dir) / PARENT_FILE
        if parent.exists():
            uri, run_id = _tracking_uri(config), parent.read_text().strip()
            self._close(uri, run_id)
            print(f"wdss: sweep done (parent run {run_id})\n" + run_links(uri, run_id), flush=True)

    @staticmethod
    def _close(uri: str, run_id: str) -> None:
        """End the parent run once, noting how many jobs failed (their cells are marked in the report)."""
        from mlflow import MlflowClient

        client = MlflowClient(uri)
        if client.get_run(run_id).info.status != "RUNNING":
            return
        experiment = client.get_run(run_id).info.experiment_id
        jobs = client.search_runs([experiment], filter_string=f"tags.mlflow.parentRunId = '{run_id}'")
        failed = sum(j.info.status != "FINISHED" for j in jobs)
        client.set_tag(run_id, "jobs", str(len(jobs)))
        client.set_tag(run_id, "failed_jobs", str(failed))
        client.set_terminated(run_id, "FINISHED")


def _tracking_uri(config: DictConfig) -> str:
    root = OmegaConf.select(config, "paths.root_dir", default=".")
    return os.environ.get("MLFLOW_TRACKING_URI", f"sqlite:///{root}/mlflow.db")
