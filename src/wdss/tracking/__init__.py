"""MLflow tracking: the logger of a run, its tags and artifacts, and one parent run per sweep.

Runs are named variant first (``swt_db4 · cpu · seed0 · mini``: what a name cut short by the UI still tells
apart), tagged with their Hydra overrides (``overrides``: ``experiment=cpu,seed=0,variant=swt_db4``, which the
report reads), every config-group choice (``transform``, ``basis``, ``head``, ``scale``, ``temporal``, ``model``,
``data``, ...), the seed, the data root and the git commit, and carry a score of params that say how the run was
set up (:func:`run_params`), so the MLflow UI can group and compare them. A multirun gets a parent run (created by
the Hydra callback :class:`SweepParentRun`) and every job is nested under it.
"""

from __future__ import annotations

import atexit
import fcntl
import os
import re
import socket
import subprocess
from functools import cache
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
    "run_key",
    "run_name",
    "run_overrides",
    "run_params",
    "run_tags",
    "split_overrides",
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
    "residual",
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


# Hydra's override_dirname joins ``key=value`` items with commas and does not escape list values ("[2.0,3.0]"):
# an item starts only where a key and "=" follow the comma.
_ITEM = re.compile(r",(?=[+~]*[\w.@/-]+=)")
NAME_SEPARATOR = " · "
# Config groups a baseline ignores (it has no wavelet, head, residual or temporal branch): neither named nor tagged
# for it.
_BASELINE_IGNORES = ("transform", "basis", "head", "residual", "temporal", "scale")


def split_overrides(text: str) -> list[tuple[str, str | None]]:
    """``override_dirname`` as (key, value) items, list values kept whole; a deletion (``~key``) has no value."""
    items = []
    for item in _ITEM.split(text) if text else []:
        key, sep, value = item.partition("=")
        items.append((key.lstrip("+~"), value if sep else None))
    return items


def run_overrides(cfg: DictConfig) -> str:
    """The job's overrides as Hydra joins them (``override_dirname``: ``basis=db4,transform=swt``), without the keys
    that do not change the configuration (``ckpt_path``, ``trainer.max_epochs``, ...: conf/hydra/default.yaml);
    empty outside a Hydra app or without overrides. Tagged ``overrides``: the report's axes."""
    hydra = _hydra()
    return str(hydra.job.override_dirname) if hydra is not None else ""


def run_key(cfg: DictConfig) -> str:
    """What ``ckpt_path=last`` matches a run folder by: ``cfg.run_name`` when given, else the overrides, else
    ``default`` (what runs were named before names led with the variant, so older folders still match)."""
    return str(cfg.run_name) if cfg.get("run_name") else (run_overrides(cfg) or "default")


@cache
def _default_choices() -> dict[str, str]:
    """conf/train.yaml's choice per group: an override that picks it again does not tell a run apart."""
    from wdss.paths import CONF_DIR

    defaults = OmegaConf.load(CONF_DIR / "train.yaml").get("defaults", [])
    return {str(k): str(v) for item in defaults if OmegaConf.is_dict(item) for k, v in item.items()}


def _baseline(cfg: DictConfig) -> bool:
    return str(OmegaConf.select(cfg, "model.net._target_", default="")).endswith("Upsample")


def _subject(cfg: DictConfig, choices: dict) -> tuple[str, set[str]]:
    """The first part of a run's name (the variant, else a baseline's or other model's choice, else the wavelet
    as ``transform_basis``) and the override keys it says."""
    if choices.get("variant"):
        said = {"variant", "model", "transform", "basis"}  # a variant picks them
        return ("no_wavelet" if choices["variant"] == "none" else str(choices["variant"])), said
    model = choices.get("model")
    if _baseline(cfg) or (model and model != _default_choices().get("model")):
        return str(model or "baseline"), {"model", *(_BASELINE_IGNORES if _baseline(cfg) else ())}
    transform = str(OmegaConf.select(cfg, "transform.transform", default=choices.get("transform", "")))
    if transform == "none":
        return "no_wavelet", {"transform", "basis"}
    basis = str(OmegaConf.select(cfg, "transform.wavelet", default=choices.get("basis", "")))
    return "_".join(p for p in (transform, basis) if p) or "default", {"transform", "basis"}


def _data_part(cfg: DictConfig) -> str:
    """The data root's folder name (``mini``), and the test root's after an arrow when the run tests on another."""
    root = OmegaConf.select(cfg, "data.root", default=None)
    if root is None:
        return ""
    test_root = OmegaConf.select(cfg, "data.test_root", default=None)
    name = Path(str(root)).name
    return f"{name}→{Path(str(test_root)).name}" if test_root is not None and test_root != root else name


def run_name(cfg: DictConfig) -> str:
    """``cfg.run_name``, else variant first, then the other overrides that tell this run apart, the seed and the
    data root's name: ``swt_db4 · cpu · lr=0.002 · seed0 · mini``. A group's choice is shown bare, a value by
    its last key (the full overrides are the tag ``overrides``)."""
    if cfg.get("run_name"):
        return str(cfg.run_name)
    hydra = _hydra()
    choices = dict(hydra.runtime.choices) if hydra is not None else {}
    subject, said = _subject(cfg, choices)
    said |= {"seed", "data", "data.root", "data.test_root", "run_name", "experiment_name"}
    defaults = _default_choices()
    items = []
    for key, value in split_overrides(run_overrides(cfg)):
        if key in said or key.startswith(("paths.", "hydra.", "tags.", "logger.")):  # where, not what, it ran
            continue
        if value is None:
            items.append((key, f"~{key}"))
        elif key in choices:  # a group: what ran, unless the default or replaced (a variant picks its model)
            if str(choices[key]) == value and value != defaults.get(key):
                items.append((key, value))
        else:
            items.append((key, value))
    items.sort(key=lambda item: item[0] not in choices)  # the choices of groups first, then single values
    short = [key.rsplit(".", 1)[-1] for key, _ in items]
    parts = [subject]
    for (key, value), last in zip(items, short, strict=True):
        if key in choices or value.startswith("~"):
            parts.append(value)
        else:  # the last key alone unless two items share it
            parts.append(f"{last if short.count(last) == 1 else key}={value}")
    parts.append(f"seed{cfg.get('seed')}")
    parts.append(_data_part(cfg))
    return NAME_SEPARATOR.join(p for p in parts if p)


# Config values logged as params beside the group choices: what a reader of the runs table compares. The run's own
# overrides are logged too (a sweep's axes); paths only relative to the project, never absolute.
PARAMS = (
    "seed",
    "model.optimizer.lr",
    "trainer.max_epochs",
    "trainer.max_steps",
    "data.batch_size",
    "data.patch_size",
    "data.patches_per_frame",
    "scale.train",
    "data.test_scales",
    "loss.space",
    "model.tonemap_name",  # the report's metric path
    "tonemap_exposure",
)
PARAM_GROUPS = (
    "variant",
    "model",
    "transform",
    "basis",
    "head",
    "residual",
    "scale",
    "temporal",
    "size",
    "data",
    "trainer",
    "callbacks",
    "experiment",
)
_MISSING = object()


def _param_value(value: Any) -> str:
    if OmegaConf.is_config(value):
        value = OmegaConf.to_container(value, resolve=True)
    return str(value)


def run_params(cfg: DictConfig) -> dict[str, str]:
    """About twenty params of a training run: the group choices (``n/a`` where a baseline ignores them), the learning
    rate, epochs, batch and patch size, scales, seed, the data roots relative to the project, the tone map, and
    the run's own overrides; no absolute path. The full config is the artifact ``config.yaml``."""
    params = _group_choices(cfg, PARAM_GROUPS)
    for key in PARAMS:
        value = OmegaConf.select(cfg, key, default=_MISSING)
        if value is not _MISSING:
            params[key] = _param_value(value)
    root = OmegaConf.select(cfg, "data.root", default=None)
    if root is not None:
        params["data.root"] = _shown_path(root, cfg, "name")
        test_root = OmegaConf.select(cfg, "data.test_root", default=None)
        if test_root is not None:
            params["data.test_root"] = _shown_path(test_root, cfg, "name")
    for key, value in split_overrides(run_overrides(cfg)):
        if value is None or key in params or key.startswith(("paths.", "hydra.")) or key == "ckpt_path":
            continue
        if key in PARAM_GROUPS:
            continue  # the choice that ran is logged above (a variant may have replaced the override)
        selected = OmegaConf.select(cfg, key, default=_MISSING)
        shown = _param_value(selected) if selected is not _MISSING else value
        if key.endswith(("root", "dir", "path")) and shown not in ("None", ""):
            shown = _shown_path(shown, cfg, "name")
        params[key] = shown
    return params


def _group_choices(cfg: DictConfig, groups: tuple[str, ...] = GROUPS) -> dict[str, str]:
    """The choice of each config group that has one; ``n/a (...)`` where the run ignores the group."""
    hydra = _hydra()
    choices = {g: str(c) for g in groups if hydra is not None and (c := hydra.runtime.choices.get(g)) is not None}
    if choices.get("transform") == "none" and "basis" in choices:
        choices["basis"] = "n/a (transform=none)"  # the basis is ignored without a wavelet transform
    if _baseline(cfg):  # baselines have no wavelet, head or temporal branch
        choices.update({key: "n/a (baseline)" for key in _BASELINE_IGNORES if key in groups})
    return choices


def run_tags(cfg: DictConfig) -> dict[str, str]:
    """A tag per config-group choice, the overrides, the seed, the data root, the git commit, and the sweep parent
    when there is one."""
    tags = _group_choices(cfg)
    hydra = _hydra()
    if hydra is not None and hydra.mode == RunMode.MULTIRUN:
        parent = Path(hydra.sweep.dir) / PARENT_FILE
        if parent.exists():
            tags["mlflow.parentRunId"] = parent.read_text().strip()
        tags["sweep"] = hydra.job.config_name
        tags["job"] = str(hydra.job.num)
    tags["overrides"] = run_overrides(cfg)  # present even when empty: the report never parses the name
    tags["seed"] = str(cfg.get("seed"))
    tags.update(data_tags(cfg))
    tags["git_commit"] = git_commit(OmegaConf.select(cfg, "paths.root_dir", default="."))
    tags["host"], tags["pid"] = socket.gethostname(), str(os.getpid())  # lets reap_dead_runs find killed runs
    tags.update({str(k): str(v) for k, v in (cfg.get("tags") or {}).items()})
    return tags


def _shown_path(path: Any, cfg: DictConfig, outside: str = "as given") -> str:
    """A data folder as a tag shows it: relative to the project when it lies inside, else as given (``outside=
    "name"``: its name, as params show it: no absolute path)."""
    folder = Path(str(path))
    root = Path(str(OmegaConf.select(cfg, "paths.root_dir", default=".")))
    try:
        return str(folder.resolve().relative_to(root.resolve()))
    except ValueError:
        return folder.name if outside == "name" and folder.is_absolute() else str(folder)


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
        """End the parent run once, noting how many jobs failed (their cells are marked in the report) and the data
        roots its jobs read."""
        from mlflow import MlflowClient

        client = MlflowClient(uri)
        if client.get_run(run_id).info.status != "RUNNING":
            return
        experiment = client.get_run(run_id).info.experiment_id
        jobs = client.search_runs([experiment], filter_string=f"tags.mlflow.parentRunId = '{run_id}'")
        failed = sum(j.info.status != "FINISHED" for j in jobs)
        roots = sorted({j.data.tags["data_root"] for j in jobs if "data_root" in j.data.tags})
        if roots:  # the sweep's row in the runs table shows its data too
            client.set_tag(run_id, "data_root", roots[0] if len(roots) == 1 else f"several: {', '.join(roots)}")
        client.set_tag(run_id, "jobs", str(len(jobs)))
        client.set_tag(run_id, "failed_jobs", str(failed))
        client.set_terminated(run_id, "FINISHED")


def _tracking_uri(config: DictConfig) -> str:
    root = OmegaConf.select(config, "paths.root_dir", default=".")
    return os.environ.get("MLFLOW_TRACKING_URI", f"sqlite:///{root}/mlflow.db")
