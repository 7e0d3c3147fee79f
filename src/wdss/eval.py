"""Evaluation entry point: ``python -m wdss.eval ckpt_path=PATH [data=...] [write_outputs=true] [video=true]``.

Rebuilds the model from the checkpoint alone (``weights_only=True``), tests it on full frames of every test
scene at every scale of ``data.test_scales``, logs the metrics and the inference cost into an MLflow run of
its own (nested under the run that trained it, found beside the checkpoint, when the tracking store has it),
and optionally writes every prediction as linear EXR and tone-mapped PNG, and every test sequence as video
(:mod:`wdss.callbacks.videos`).
"""

from __future__ import annotations

import re
import sys
import textwrap
from pathlib import Path
from typing import Any

import lightning as L
import numpy as np
from omegaconf import DictConfig, OmegaConf, open_dict

from wdss.callbacks import mlflow_callbacks
from wdss.callbacks.progress_bar import progress_callbacks
from wdss.checkpoint import read_checkpoint, training_preprocessing
from wdss.config.targets import check_targets, instantiate
from wdss.data.exr import write_exr
from wdss.errors import entry_point
from wdss.logfile import log_files_to_mlflow
from wdss.paths import CONF_DIR
from wdss.tracking import GROUPS, RUN_ID_FILE, data_tags, ensure_experiment, prepare_store, run_links
from wdss.training.module import SuperResolutionModule

__all__ = ["WritePredictions", "evaluate", "main"]


class WritePredictions(L.Callback):
    """Write each test prediction as ``<scene>_<frame>_<scale>x.exr`` (linear) and ``.png`` (tone-mapped)."""

    def __init__(self, out_dir: str | Path) -> None:
        self.out_dir = Path(out_dir)

    def on_test_batch_end(
        self, trainer, pl_module, outputs: Any, batch: Any, batch_idx: int, dataloader_idx: int = 0
    ) -> None:
        from PIL import Image

        if not outputs or "color" not in outputs:
            return
        self.out_dir.mkdir(parents=True, exist_ok=True)
        scale = f"{float(batch['scale'][0]):g}x"
        for index, color in enumerate(outputs["color"].detach().float().cpu()):
            stem = f"{batch['sequence'][index]}_{int(batch['frame'][index]):04d}_{scale}"
            write_exr(self.out_dir / f"{stem}.exr", dict(zip("RGB", color.numpy(), strict=True)))
            # The module's display transform (its exposure, "auto" from the target): the PNG shows what the metric saw.
            ldr = pl_module.tone(color[None], batch["target"][index : index + 1].float().cpu())[0]
            ldr = ldr.permute(1, 2, 0).numpy()
            Image.fromarray((ldr * 255).round().astype(np.uint8)).save(self.out_dir / f"{stem}.png")


def training_run_id(ckpt_path: Path) -> str | None:
    """The MLflow run that wrote a checkpoint (``<run dir>/checkpoints/x.ckpt`` beside ``mlflow_run_id``)."""
    file = ckpt_path.resolve().parent.parent / RUN_ID_FILE
    if not file.exists():
        return None
    recorded = file.read_text(errors="replace").strip()
    if not re.fullmatch(r"[0-9a-f]{32}", recorded):  # a file anyone can edit: never passed to the store as an id
        print(
            f"wdss.eval: {file} holds no MLflow run id ({recorded[:40]!r}): the training run of {ckpt_path} is unknown"
        )
        return None
    return recorded


def _eval_logger(cfg: DictConfig, ckpt: Path) -> Any:
    """A logger with a run of its own for this evaluation, so that its status and end time are its own.

    Nested under the run that trained the checkpoint when this tracking store has it (that record keeps its
    status and end time, whatever the evaluation does); otherwise a top-level run, tagged with the checkpoint
    and the id of its training run, and the user is told why.
    """
    from mlflow import MlflowClient
    from mlflow.exceptions import MlflowException
    from mlflow.protos.databricks_pb2 import RESOURCE_DOES_NOT_EXIST, ErrorCode

    uri = str(cfg.logger.tracking_uri)
    prepare_store(uri)
    client = MlflowClient(uri)
    training = training_run_id(ckpt)
    tags = {"ckpt_path": str(ckpt.resolve()), **data_tags(cfg)}
    experiment_name = str(cfg.experiment_name)
    if training is None:
        folder = ckpt.resolve().parent.parent
        print(f"wdss.eval: no {RUN_ID_FILE} in {folder}: the training run of {ckpt} is unknown, logging a new run")
    else:
        tags["training_run_id"] = training
        try:
            run = client.get_run(training)
        except MlflowException as err:
            if err.error_code != ErrorCode.Name(RESOURCE_DOES_NOT_EXIST):
                raise
            print(
                f"wdss.eval: the training run {training} of {ckpt} is not in {uri}: logging a new run tagged "
                f"training_run_id={training} and ckpt_path"
            )
        else:
            tags["mlflow.parentRunId"] = training
            trained_on = run.data.tags.get("train_data_root") or run.data.tags.get("data_root")
            if trained_on and trained_on != tags.get("data_root"):  # eval's data is its own config's, not the run's
                print(
                    f"wdss.eval: testing on the test split of {tags.get('data_root')}; {ckpt} was trained on "
                    f"{trained_on} (data=... data.root=... choose what is tested)"
                )
            # What was trained (variant, model, seed, ...), so that a report groups evaluations as their trainings.
            tags.update({k: v for k, v in run.data.tags.items() if k in (*GROUPS, "seed") and k != "data"})
            # (runs from before the tag existed were named by their overrides)
            tags["overrides"] = run.data.tags.get("overrides", run.info.run_name or "")
            experiment_name = client.get_experiment(run.info.experiment_id).name  # the UI nests within one
    ensure_experiment(client, experiment_name)
    return instantiate(
        cfg.logger,
        experiment_name=experiment_name,
        run_name=f"eval {ckpt.name} · {tags.get('data_root', '')}",
        tags=tags,
    )


def _eval_params(cfg: DictConfig, ckpt: Path, module: SuperResolutionModule) -> dict[str, str]:
    """What an evaluation chose: the checkpoint's name, the data (root relative to the project), the test scales
    and the metrics' tone map (the report's metric path); no absolute path."""
    data = data_tags(cfg)
    params = {
        "ckpt": ckpt.name,
        "data.root": data.get("data_root", ""),
        "data.test_scales": str(OmegaConf.to_container(cfg.data.test_scales, resolve=True)),
        "model.tonemap_name": str(module.hparams.get("tonemap_name", "hable")),
        "tonemap_exposure": str(module.hparams.get("tonemap_exposure")),
    }
    if "train_data_root" in data:
        params["data.root"], params["data.test_root"] = data["train_data_root"], data["data_root"]
    return {k: v if not Path(v).is_absolute() else Path(v).name for k, v in params.items()}


def _command_line_keys() -> set[str]:
    """The dotted keys this run's command line set (empty outside a Hydra app)."""
    from hydra.core.hydra_config import HydraConfig

    if not HydraConfig.initialized():
        return set()
    return {item.split("=", 1)[0].lstrip("+~") for item in HydraConfig.get().overrides.task}


def _as_trained(cfg: DictConfig, ckpt: Path) -> None:
    """``data.preprocessing`` as the checkpoint's training run had it (a model must see its inputs demodulated and
    normalised as in training, whatever the defaults are now), but for the keys set on this command line."""
    given = _command_line_keys()
    with open_dict(cfg):
        for key, value in training_preprocessing(ckpt).items():
            if f"data.preprocessing.{key}" not in given and "data.preprocessing" not in given:
                cfg.data.preprocessing[key] = value


def evaluate(cfg: DictConfig) -> dict[str, float]:
    ckpt = Path(str(cfg.ckpt_path))
    # Both the config and the checkpoint's stored model config build only allowlisted callables (wdss.config.targets).
    check_targets(OmegaConf.masked_copy(cfg, [k for k in cfg if k != "hydra"]))
    read_checkpoint(ckpt)
    _as_trained(cfg, ckpt)
    module = SuperResolutionModule.load_from_checkpoint(ckpt, map_location="cpu", weights_only=True)
    datamodule = instantiate(cfg.data, inputs=list(module.inputs), test_inputs=list(module.test_inputs))
    datamodule.check(["test"])  # a missing data root or sequence: refused before any run starts
    logger = _eval_logger(cfg, ckpt)
    callbacks = progress_callbacks() + mlflow_callbacks()
    if cfg.get("write_outputs"):
        callbacks.append(WritePredictions(Path(str(cfg.paths.output_dir)) / "frames"))
    if cfg.get("video"):
        from wdss.callbacks.videos import SequenceVideos

        callbacks.append(SequenceVideos(Path(str(cfg.paths.output_dir)) / "videos"))
    # The module's hyper-parameters are its training run's params; this run logs what the evaluation chose.
    trainer = instantiate(
        cfg.trainer, logger=logger, callbacks=callbacks, enable_checkpointing=False, enable_autolog_hparams=False
    )
    logger.log_hyperparams(_eval_params(cfg, ckpt, module))
    from wdss.train import _bench, log_noise_ceilings

    try:
        trainer.test(module, datamodule=datamodule, verbose=sys.stdout.isatty())  # the metrics are printed below
        metrics = {k: float(v) for k, v in trainer.callback_metrics.items() if k.startswith("test/")}
        metrics.update(log_noise_ceilings(module, datamodule, logger))
        metrics.update(_bench(cfg, module, logger))
    except BaseException:
        logger.finalize("FAILED")  # the evaluation's own run; the training run is never touched
        raise
    print(f"wdss.eval: {ckpt} -> MLflow run {logger.run_id}")
    print(textwrap.indent(run_links(str(cfg.logger.tracking_uri), logger.run_id), "  "))
    for key in sorted(metrics):
        print(f"  {key} = {metrics[key]:.4g}")
    log_files_to_mlflow(logger.experiment, logger.run_id, "wdss.eval")  # eval.log, with the metrics
    return metrics


@entry_point("wdss.eval", CONF_DIR, "eval")
def main(cfg: DictConfig) -> None:
    evaluate(cfg)


if __name__ == "__main__":
    main()
