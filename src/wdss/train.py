"""Training entry point: ``python -m wdss.train [group=option ...]`` (config: ``conf/train.yaml``).

``train(cfg)`` is a plain function that the entry point and the tests both call: it validates the
configuration, seeds everything, builds the LightningModule, the DataModule (asking it for exactly the
batch keys the model consumes), the MLflow logger and the Trainer, fits (unless the model is a baseline),
tests on every test scale, and logs the inference cost. ``ckpt_path=last`` resumes the newest run of the
same configuration (its overrides, or its ``run_name``), in the same MLflow run.
"""

from __future__ import annotations

import os
import signal
import sys
import textwrap
import time
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import lightning as L
from hydra.core.hydra_config import HydraConfig
from hydra.experimental.callback import Callback
from hydra.types import RunMode
from lightning.pytorch.utilities.exceptions import SIGTERMException
from omegaconf import DictConfig, OmegaConf

from wdss.callbacks import mlflow_callbacks
from wdss.callbacks.progress_bar import model_line, progress_callbacks
from wdss.checkpoint import CheckpointError, read_checkpoint
from wdss.config.targets import TargetRefused, check_targets, instantiate, resolve
from wdss.distributed import use_rank_command
from wdss.errors import ConfigError, entry_point
from wdss.logfile import log_exception, log_files_to_mlflow
from wdss.nets.wdss.heads import Head
from wdss.paths import CONF_DIR
from wdss.tracking import (
    RUN_ID_FILE,
    ensure_experiment,
    prepare_store,
    reap_dead_runs,
    run_key,
    run_links,
    run_name,
    run_params,
    run_tags,
)

__all__ = ["ConfigError", "log_noise_ceilings", "main", "train", "validate"]


def _check_numbers(cfg: DictConfig) -> None:
    """Sizes are positive integers and scales lie in [1, 8]: a typo fails before any MLflow run or wdss output."""
    for key, least, optional in (
        ("data.batch_size", 1, False),
        ("data.eval_batch_size", 1, False),
        ("data.patches_per_frame", 1, False),
        ("data.patch_size", 1, True),  # null: whole frames
        ("data.num_workers", 0, False),
        ("data.cache_mb", 0, True),  # absent: the data module's default
    ):
        value = OmegaConf.select(cfg, key, default=None)
        if value is None and optional:
            continue
        if isinstance(value, bool) or not isinstance(value, int) or value < least:
            raise ConfigError(f"{key} must be an integer >= {least}, got {value!r}")
    for key in ("scale.train", "data.val_scale"):
        value = OmegaConf.select(cfg, key)
        choices = OmegaConf.is_dict(value)
        if choices and (set(value) != {"choices"} or not OmegaConf.is_list(value.choices) or not value.choices):
            raise ConfigError(f"{key} as a mapping is {{choices: [s1, s2, ...]}}, got {OmegaConf.to_container(value)}")
        value = value.choices if choices else value
        values = list(value) if OmegaConf.is_list(value) else [value]
        for number in values:
            if isinstance(number, bool) or not isinstance(number, int | float) or not 1.0 <= number <= 8.0:
                raise ConfigError(f"{key} must lie in [1, 8], got {number!r}")
        if not choices and values != sorted(values):
            raise ConfigError(f"{key} takes [low, high] with low <= high, got {values}")


def validate(cfg: DictConfig) -> None:
    """Reject invalid combinations with one clear sentence each."""
    _check_allowlisted(cfg)
    _check_numbers(cfg)
    _check_head(cfg)
    _check_scales(cfg)
    _check_wavelet_loss(cfg)
    _check_sampler(cfg)
    _check_temporal_loss(cfg)
    _check_ckpt_path(cfg)
    # transform=none with a basis other than db4 is not an error: the basis is ignored and tagged "n/a"
    # (see wdss.tracking.run_tags).


def _check_allowlisted(cfg: DictConfig) -> None:
    """A config builds only allowlisted callables (wdss.config.targets): a config file is not a way to run code."""
    try:
        check_targets(OmegaConf.masked_copy(cfg, [k for k in cfg if k != "hydra"]))
    except TargetRefused as err:
        raise ConfigError(str(err)) from err


def _check_head(cfg: DictConfig) -> None:
    """A head that predicts wavelet subbands needs a wavelet transform (baselines have no head)."""
    transform = OmegaConf.select(cfg, "transform.transform")
    # The head the network builds (conf/head, allowlisted above; none for a baseline) says whether it needs subbands.
    head = resolve(str(OmegaConf.select(cfg, "model.net.head._target_", default="")))
    if transform == "none" and isinstance(head, type) and issubclass(head, Head) and head.needs_subbands:
        raise ConfigError(f"head={head.name} needs wavelet subbands: it cannot be combined with transform=none")


def _check_scales(cfg: DictConfig) -> None:
    """The training scale has the shape its ``scale`` option takes; the test scales lie in [1, 8]."""
    scale = OmegaConf.select(cfg, "scale.train")
    scale_name = OmegaConf.select(cfg, "scale.name")
    if scale_name == "fixed" and OmegaConf.is_list(scale):
        raise ConfigError(f"scale=fixed takes one number, got the list {list(scale)}: use scale=arbitrary for ranges")
    if scale_name == "arbitrary" and not (OmegaConf.is_list(scale) and len(scale) == 2):
        raise ConfigError(f"scale=arbitrary takes [low, high], got {scale}: use scale=fixed for one scale")
    if scale_name == "native" and not OmegaConf.is_dict(scale):
        raise ConfigError(f"scale=native takes {{choices: [...]}}, got {scale}: use scale=arbitrary for ranges")
    for value in OmegaConf.to_container(cfg.data, resolve=True).get("test_scales", []):
        if not 1.0 <= float(value) <= 8.0:
            raise ConfigError(f"data.test_scales must lie in [1, 8], got {value}")


def _check_wavelet_loss(cfg: DictConfig) -> None:
    """A wavelet loss term in a non-linear loss space needs subbands predicted in log space."""
    space, wavelet_weight = (
        OmegaConf.select(cfg, "loss.space"),
        OmegaConf.select(cfg, "loss.weights.wavelet", default=0),
    )
    output_space = OmegaConf.select(cfg, "model.net.output_space", default="linear")
    head_transform = OmegaConf.select(cfg, "model.net.wavelet.transform", default=None)  # WDSS-family networks
    if head_transform in ("dwt", "swt") and space != "linear" and wavelet_weight and output_space == "linear":
        raise ConfigError(
            f"loss.space={space} compares images in {space} space, but the wavelet term would compare linear "
            "subbands (LL up to ~100x the image terms): set model.net.output_space=log (the head then predicts "
            "log1p-irradiance subbands) or loss.weights.wavelet=0"
        )


def _check_sampler(cfg: DictConfig) -> None:
    """Lightning's distributed sampler is off: wdss's EpochSampler shares an epoch out itself."""
    if OmegaConf.select(cfg, "trainer") is not None and OmegaConf.select(
        cfg, "trainer.use_distributed_sampler", default=True
    ):
        raise ConfigError(
            "trainer.use_distributed_sampler must be false: under DDP wdss's EpochSampler gives each rank its share "
            "of an epoch, and Lightning's sampler would share the shares out again"
        )


def _check_temporal_loss(cfg: DictConfig) -> None:
    """A temporal loss term needs consecutive outputs of a recurrent model."""
    temporal = OmegaConf.select(cfg, "temporal.name")
    if temporal != "recurrent" and OmegaConf.select(cfg, "loss.weights.temporal", default=0):
        raise ConfigError("loss.weights.temporal > 0 needs temporal=recurrent (consecutive outputs of the model)")


def _check_ckpt_path(cfg: DictConfig) -> None:
    """``ckpt_path``, unless ``last`` or unset, is a wdss checkpoint whose model config builds only allowlisted
    callables."""
    if cfg.get("ckpt_path") not in (None, "last"):
        if not Path(str(cfg.ckpt_path)).is_file():
            raise ConfigError(f"ckpt_path {cfg.ckpt_path} is not a file (use a checkpoint path or 'last')")
        try:
            read_checkpoint(str(cfg.ckpt_path))
        except CheckpointError as err:
            raise ConfigError(f"ckpt_path: {err}") from err


RUN_KEY_FILE = "run_key"  # in a run's output directory: what ckpt_path=last matches (wdss.tracking.run_key)


def _resume(cfg: DictConfig) -> tuple[str | None, str | None]:
    """``ckpt_path=last``: the ``last.ckpt`` of the newest run of the same configuration, and that run's MLflow id.

    A run folder records its configuration at the start (``run_key``: its ``run_name`` when given, else its
    overrides; folders from before the names led with the variant recorded it as ``run_name``). The newest run is
    the one started last. Runs of that configuration still checkpointing after it started trained at the same time:
    then no run is "the newest", and guessing would resume one run's weights into another's record, so the choice
    is refused, listing them.
    """
    if cfg.get("ckpt_path") != "last":
        return (str(cfg.ckpt_path) if cfg.get("ckpt_path") else None), None
    key = run_key(cfg)
    log_dir = Path(str(cfg.paths.log_dir))
    candidates = sorted(
        (_key_file(ckpt.parent.parent).stat().st_mtime, ckpt)
        for ckpt in log_dir.glob("**/checkpoints/last.ckpt")
        if _key_file(ckpt.parent.parent).is_file() and _key_file(ckpt.parent.parent).read_text().strip() == key
    )
    if not candidates:
        print(f"wdss.train: no last.ckpt of a run of {key!r} under {log_dir}: starting from scratch")
        return None, None
    started, ckpt = candidates[-1]
    concurrent = [other for _, other in candidates[:-1] if other.stat().st_mtime > started]
    if concurrent:
        listing = "\n".join(
            f"  {path} (MLflow run {_recorded(path.parent.parent, RUN_ID_FILE)})" for path in [ckpt, *concurrent]
        )
        raise ConfigError(
            f"ckpt_path=last is ambiguous: {len(concurrent) + 1} runs of {key!r} trained at the same time:\n"
            f"{listing}\nresume one of them with ckpt_path=PATH"
        )
    run_id = _recorded(ckpt.parent.parent, RUN_ID_FILE)
    # A run still training (in its own folder, or resumed into a later one) keeps its MLflow run: two writers would
    # interleave their metrics and each end it with its own status.
    writers = [ckpt.parent.parent] + _folders_of_run(log_dir, run_id)
    for run_dir in dict.fromkeys(writers) if not _other_rank() else ():  # rank 0 checked it for the job
        pid = training_pid(run_dir)
        if pid is not None:
            raise ConfigError(
                f"ckpt_path=last: {run_dir} is still training (pid {pid})"
                + (f" into MLflow run {run_id}" if run_id else "")
                + "; resuming it now would make two writers of one run: wait for it to end, stop it (kill "
                f"{pid}), or resume another checkpoint with ckpt_path=PATH"
            )
    print(f"wdss.train: resuming {ckpt}" + (f" in MLflow run {run_id}" if run_id else ""))
    return str(ckpt), run_id


def _folders_of_run(log_dir: Path, run_id: str | None) -> list[Path]:
    """The run folders under ``log_dir`` that logged to MLflow run ``run_id`` (it started there, or resumed)."""
    if not run_id:
        return []
    return [f.parent for f in log_dir.glob(f"**/{RUN_ID_FILE}") if _recorded(f.parent, RUN_ID_FILE) == run_id]


def _own_checkpoint(path: str, cfg: DictConfig, run_id: str | None) -> str:
    """``path`` (the best checkpoint a resumed callback state names) if it lies in a checkpoints folder of this MLflow
    run (this folder, or one it resumed), else "" with a warning: the test never loads another run's file."""
    if not path:
        return ""
    log_dir = Path(str(cfg.paths.log_dir))
    folders = {Path(str(cfg.paths.output_dir)).resolve() / "checkpoints"}
    folders |= {folder.resolve() / "checkpoints" for folder in _folders_of_run(log_dir, run_id)}
    if Path(path).resolve().parent in folders:
        return path
    print(f"wdss.train: WARNING: the best checkpoint the state names, {path}, is not one of this run's: testing the "
          "weights as they are", file=sys.stderr, flush=True)  # fmt: skip
    return ""


def _check_resumable(client: Any, run_id: str, uri: str, ckpt: str | None) -> str:
    """The status of the run to resume (KILLED, FAILED, ...); refused, in one line, when this tracking store does not
    hold it (it was logged to another store: MLflow would say only "Run not found")."""
    from mlflow.exceptions import MlflowException

    try:
        return str(client.get_run(run_id).info.status)
    except MlflowException as err:
        raise ConfigError(
            f"ckpt_path=last: {ckpt} was trained in MLflow run {run_id}, which the tracking store {uri} does not hold "
            f"({err.error_code}): point logger.tracking_uri (or MLFLOW_TRACKING_URI) at the store it was logged to, or "
            f"resume into a new run with ckpt_path={ckpt}"
        ) from err


def _other_rank() -> bool:
    """Whether this process is a rank other than 0 of a DDP job (started by rank 0, or by SLURM): rank 0 holds the
    job's lock, which a rank must not take for another writer."""
    for name in ("LOCAL_RANK", "RANK", "SLURM_PROCID"):
        try:
            if int(os.environ.get(name, "0")) > 0:
                return True
        except ValueError:
            continue
    return False


LOCK_FILE = "training.pid"  # in a run's output directory while it trains: whose process writes its MLflow run


def training_pid(run_dir: Path) -> int | None:
    """The pid of another live process training in ``run_dir`` (its :data:`LOCK_FILE`), else None: a lock left by
    a killed process, or by this one, holds nothing."""
    try:
        pid = int((run_dir / LOCK_FILE).read_text().strip())
    except (OSError, ValueError):
        return None
    if pid == os.getpid():
        return None
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return None
    except PermissionError:  # alive, another user's
        return pid
    return pid


def _key_file(run_dir: Path) -> Path:
    """The file that holds a run folder's configuration key: ``run_key``, or ``run_name`` in older folders."""
    return run_dir / RUN_KEY_FILE if (run_dir / RUN_KEY_FILE).is_file() else run_dir / "run_name"


def _recorded(run_dir: Path, name: str) -> str | None:
    """What a run folder recorded at its start (``run_key``, ``mlflow_run_id``), if it did."""
    file = run_dir / name
    return file.read_text().strip() if file.exists() else None


def train(cfg: DictConfig) -> dict[str, float]:
    """Fit and test one configuration; returns the final metrics (``val/*``, ``test/*``, ``bench/*``)."""
    validate(cfg)
    L.seed_everything(int(cfg.seed), workers=True, verbose=False)
    output_dir = Path(str(cfg.paths.output_dir))
    output_dir.mkdir(parents=True, exist_ok=True)
    ckpt_path, resume_run = _resume(cfg)
    resumed_step = _resumed_step(cfg, ckpt_path)
    module, datamodule, fitting = _model_and_data(cfg)
    trainer = _trainer(cfg, module, output_dir)
    logger, status_before = _tracked_run(cfg, trainer, module, output_dir, resume_run, ckpt_path)
    run = _Run(trainer, module, datamodule, logger, fitting, ckpt_path, output_dir, status_before, resumed_step)
    return _fit_and_test(cfg, run)


def _resumed_step(cfg: DictConfig, ckpt_path: str | None) -> int:
    """The global step a resumed run's checkpoint holds (-1 without one): a failure before passing it is the
    resume's, not the run's."""
    if ckpt_path is None or cfg.get("ckpt_path") != "last":  # an explicit path was read in validate()
        return -1
    try:
        return int(read_checkpoint(ckpt_path).get("global_step", 0))  # data, checked as any other
    except CheckpointError as err:
        raise ConfigError(f"ckpt_path=last: {err}") from err


def _model_and_data(cfg: DictConfig) -> tuple[Any, Any, bool]:
    """The module, the data module reading what it needs, and whether this run fits; refused before any run
    starts when the model has no weights to report or a split's data is missing."""
    module = instantiate(cfg.model, tonemap_exposure=cfg.get("tonemap_exposure"))
    fitting = bool(module.trainable and cfg.get("fit", True))
    if module.net.needs_training and not fitting and cfg.get("test"):
        raise ConfigError(
            f"{type(module.net).__name__} has no weights: set model.net.weights to the published file, or train it "
            "on these frames (fit=true); numbers from random weights are never reported"
        )
    datamodule = instantiate(cfg.data, inputs=list(module.inputs), test_inputs=list(module.test_inputs))
    # A missing data root or sequence of the splits this run reads: refused before any run starts.
    datamodule.check(["train", "val"] * fitting + ["test"] * bool(cfg.get("test")))
    return module, datamodule, fitting


def _trainer(cfg: DictConfig, module: Any, output_dir: Path) -> L.Trainer:
    """The Trainer with the config's callbacks, progress, what is logged to MLflow beside the metrics (panels, test
    frames, per-frame histories) and (with video) the test videos."""
    multirun = HydraConfig.initialized() and HydraConfig.get().mode == RunMode.MULTIRUN
    callbacks = [instantiate(c) for c in (cfg.callbacks or {}).values()] + progress_callbacks(multirun=multirun)
    callbacks += mlflow_callbacks()
    if cfg.get("video") and cfg.get("test"):
        from wdss.callbacks.videos import SequenceVideos

        callbacks.append(SequenceVideos(output_dir / "videos"))
    # Under DDP this function runs once per rank (rank 0 starts the others: wdss.distributed). The Trainer knows
    # which rank this is, so it comes first: only rank 0 touches MLflow and writes the run's records.
    use_rank_command("wdss.train")
    # No autologged hyper-parameters: the module's would repeat the config (run_params says what matters).
    # No model summary table either: one line says what it had to say (model_line).
    trainer = instantiate(
        cfg.trainer, logger=False, callbacks=callbacks, enable_autolog_hparams=False, enable_model_summary=False
    )
    if trainer.is_global_zero:
        print(model_line(module), flush=True)
    if cfg.get("video") and cfg.get("test") and trainer.world_size > 1:
        raise ConfigError(
            "video=true needs one process (under DDP each rank tests a share of the frames): test the checkpoint "
            "with python -m wdss.eval ckpt_path=PATH video=true"
        )
    return trainer


def _tracked_run(
    cfg: DictConfig, trainer: L.Trainer, module: Any, output_dir: Path, resume_run: str | None, ckpt_path: str | None
) -> tuple[Any, str | None]:
    """The MLflow run this training logs to (a new one, or the one it resumes), with its tags, params, config and
    Hydra record, and the run's files in its folder; and the status of a resumed run before this process."""
    uri = OmegaConf.select(cfg, "logger.tracking_uri")
    status_before = None  # of the run a resume continues
    if uri and trainer.is_global_zero:
        from mlflow import MlflowClient

        prepare_store(uri)
        reap_dead_runs(uri, str(cfg.experiment_name))
        ensure_experiment(MlflowClient(uri), str(cfg.experiment_name))
        if resume_run:
            status_before = _check_resumable(MlflowClient(uri), resume_run, str(uri), ckpt_path)
    tags = run_tags(cfg)
    if module.net.loads_published_weights:  # which weights it reports with (wdss.nets.base)
        tags["weights"] = f"published:{module.net.weights}" if module.net.weights else "trained-on-wdss-frames"
    name = run_name(cfg)
    # Other ranks get the logger too, but MLFlowLogger creates its run and logs on rank 0 only.
    trainer.logger = logger = instantiate(cfg.logger, run_name=name, tags=tags, run_id=resume_run)
    if trainer.is_global_zero:
        if resume_run:  # a resumed run is this process's now
            logger.experiment.set_tag(resume_run, "pid", str(os.getpid()))
        (output_dir / "run_name").write_text(name)
        (output_dir / RUN_KEY_FILE).write_text(run_key(cfg))
        (output_dir / RUN_ID_FILE).write_text(logger.run_id)
        (output_dir / LOCK_FILE).write_text(str(os.getpid()))

    resolved = OmegaConf.to_container(OmegaConf.masked_copy(cfg, [k for k in cfg if k != "hydra"]), resolve=True)
    if resume_run is None:  # params are immutable in MLflow: a resumed run keeps those it started with
        logger.log_hyperparams(run_params(cfg))
    experiment, run_id = logger.experiment, logger.run_id
    experiment.log_text(run_id, OmegaConf.to_yaml(resolved), "config.yaml")
    hydra_dir = output_dir / ".hydra"
    if hydra_dir.is_dir():
        experiment.log_artifacts(run_id, str(hydra_dir), ".hydra")
    return logger, status_before


@dataclass
class _Run:
    """What a training run fits and tests with, and what its failure handling needs to know."""

    trainer: L.Trainer
    module: Any
    datamodule: Any
    logger: Any
    fitting: bool
    ckpt_path: str | None
    output_dir: Path
    status_before: str | None  # of the run a resume continues
    resumed_step: int


def _fit_and_test(cfg: DictConfig, run: _Run) -> dict[str, float]:
    """Fit (unless the model trains nothing), test the best checkpoint of this run, bench; a failure finalises the
    MLflow run as FAILED (or as it was, when a resume failed before its first step), a signal as KILLED."""
    trainer, module, datamodule, logger = run.trainer, run.module, run.datamodule, run.logger
    experiment, run_id = logger.experiment, logger.run_id
    metrics: dict[str, float] = {}
    try:
        start = time.perf_counter()
        if run.fitting:
            trainer.fit(module, datamodule=datamodule, ckpt_path=run.ckpt_path, weights_only=True)
            experiment.log_metric(run_id, "time/train_s", time.perf_counter() - start)
            metrics.update({k: float(v) for k, v in trainer.callback_metrics.items()})
            metrics["trainer/global_step"] = float(trainer.global_step)
        if cfg.get("test"):
            best = getattr(trainer.checkpoint_callback, "best_model_path", "") if run.fitting else ""
            best = _own_checkpoint(best, cfg, run_id)
            if best:
                read_checkpoint(best)  # a file of this run is still data: checked before Lightning loads it
            # Lightning's results table is for a terminal: in a log it cuts every cell to fit 80 columns, and the
            # metrics are printed in full when the run ends
            trainer.test(
                module, datamodule=datamodule, ckpt_path=best or None, weights_only=True, verbose=sys.stdout.isatty()
            )
            metrics.update({k: float(v) for k, v in trainer.callback_metrics.items() if k.startswith("test/")})
            if trainer.is_global_zero:
                metrics.update(log_noise_ceilings(module, datamodule, logger))
        if trainer.is_global_zero:
            metrics.update(_bench(cfg, module, logger))
    except BaseException as error:
        stopped_by = _stopped_by(error)
        if stopped_by is None:
            log_exception(error, "wdss.train")
            log_files_to_mlflow(experiment, run_id, "wdss.train")
            if run.status_before is not None and trainer.global_step <= run.resumed_step:
                # The resume failed before training a step: the run stays what it was (KILLED, say), not FAILED.
                experiment.set_tag(run_id, "resume_error", f"{type(error).__name__}: {error}"[:500])
                logger.finalize(run.status_before)
            else:
                logger.finalize("FAILED")
            raise
        logger.finalize("KILLED")
        print(f"wdss.train: stopped by {stopped_by.name}; resume with ckpt_path=last (checkpoints in {run.output_dir})")
        log_files_to_mlflow(experiment, run_id, "wdss.train")
        raise SystemExit(128 + stopped_by) from error
    finally:
        if trainer.is_global_zero:
            (run.output_dir / LOCK_FILE).unlink(missing_ok=True)
    return metrics


def _log_run_log(cfg: DictConfig) -> None:
    """At the end of a training run: its log file, with the final metrics, an artifact of its MLflow run."""
    from lightning.pytorch.utilities import rank_zero_only

    uri = OmegaConf.select(cfg, "logger.tracking_uri")
    recorded = Path(str(cfg.paths.output_dir)) / RUN_ID_FILE
    if uri and recorded.is_file() and getattr(rank_zero_only, "rank", 0) == 0:
        from mlflow import MlflowClient

        log_files_to_mlflow(MlflowClient(str(uri)), recorded.read_text().strip(), "wdss.train")


def log_noise_ceilings(module: Any, datamodule: Any, logger: Any) -> dict[str, float]:
    """Log and return the test sequences' recorded noise ceilings: ``test/noise_ceiling_<sequence>`` and, when every
    test sequence has one, ``test/noise_ceiling`` (their mean weighted by frames): the PSNR no method can exceed on
    these targets. Only where the metrics' display transform is the one they were measured with (Hable at its
    default exposure, :mod:`wdss.render.noise`)."""
    from wdss.data.datamodule import SceneDataModule
    from wdss.ops.tonemap import DEFAULT_EXPOSURE

    tone = module.tone
    if not isinstance(datamodule, SceneDataModule) or tone.name != "hable":
        return {}
    if tone.exposure not in (None, DEFAULT_EXPOSURE["hable"]):
        return {}
    ceilings = datamodule.noise_ceilings("test")
    metrics = {f"test/noise_ceiling_{name}": value for name, (value, _) in ceilings.items()}
    if ceilings and len(ceilings) == len(datamodule.splits["test"][0]):
        frames = sum(n for _, n in ceilings.values())
        metrics["test/noise_ceiling"] = sum(value * n for value, n in ceilings.values()) / frames
    if metrics and logger is not None:
        logger.log_metrics(metrics)
    return metrics


def _stopped_by(error: BaseException) -> signal.Signals | None:
    """The signal that stopped a run on purpose: SIGTERM (Lightning finishes the step, then raises
    SIGTERMException) or SIGINT (Ctrl-C: a KeyboardInterrupt, which Lightning turns into ``sys.exit(1)``)."""
    if isinstance(error, SIGTERMException):
        return signal.SIGTERM
    if isinstance(error, KeyboardInterrupt) or (
        isinstance(error, SystemExit) and isinstance(error.__context__, KeyboardInterrupt)
    ):
        return signal.SIGINT
    return None


def _bench(cfg: DictConfig, module: Any, logger: Any) -> dict[str, float]:
    """Inference cost at ``cfg.bench``: median ms and GFLOPs of one forward, logged as ``bench/*``, and tagged with
    the device, the output size and the process that timed it (the report compares only timings of one process)."""
    from wdss.nets.profile import PROCESS, device_name, dummy_inputs, flops, forward_ms

    bench = cfg.get("bench")
    if not bench:
        return {}
    net = module.net.eval()
    scale = float(net.scale) if net.fixed_scale else float(bench.scale)
    inputs = dummy_inputs(net, int(bench.height), int(bench.width), scale, str(module.device))
    total, _ = flops(net, inputs)
    values = {
        "bench/ms_per_frame": forward_ms(net, inputs, repeats=int(bench.repeats)),
        "bench/gflops": total / 1e9,
        "bench/params_m": sum(p.numel() for p in net.parameters()) / 1e6,
    }
    for key, value in values.items():
        logger.experiment.log_metric(logger.run_id, key, value)
    tags = {
        "bench/device": device_name(module.device),
        "bench/resolution": f"{int(bench.width)}x{int(bench.height)} output, {scale:g}x",
        "bench/process": PROCESS,
    }
    for key, value in tags.items():
        logger.experiment.set_tag(logger.run_id, key, value)
    return values


class ValidateBeforeRun(Callback):
    """Hydra callback: :func:`validate` a single run's config before Hydra creates its output folder, so a bad
    config leaves nothing behind (sweeps validate each job in :func:`train`, after their folders exist)."""

    def on_run_start(self, config: DictConfig, **_: Any) -> None:
        HydraConfig.instance().set_config(config)  # validate() runs as in the job; Hydra sets it again for the job
        task = OmegaConf.masked_copy(config, [k for k in config if k != "hydra"])
        try:
            validate(task)
        except ConfigError as err:
            print(f"wdss.train: {err}", file=sys.stderr)
            raise SystemExit(2) from err


@entry_point("wdss.train", CONF_DIR, "train")
def main(cfg: DictConfig) -> float | None:
    metrics = train(cfg)
    output_dir = cfg.paths.output_dir
    print(f"wdss.train: run {run_name(cfg)!r} done; outputs in {output_dir}")
    uri = str(OmegaConf.select(cfg, "logger.tracking_uri"))
    run_id = Path(str(output_dir)) / RUN_ID_FILE
    if run_id.is_file():
        print(textwrap.indent(run_links(uri, run_id.read_text().strip()), "  "))
    shown = ("test/psnr", "test/ssim", "test/flip", "bench/")
    for key in sorted(k for k in metrics if k.startswith(shown) or k == "test/noise_ceiling"):
        print(f"  {key} = {metrics[key]:.4g}")
    _log_run_log(cfg)
    return metrics.get("val/psnr")


if __name__ == "__main__":
    main()
