"""DDP on two CPU processes (trainer=ddp_cpu, gloo): rank 0 alone logs and writes the run's records, rank 1 runs in
rank 0's folder (also in a sweep: no second sweep, folder or parent run), validation and test metrics are those of
one process seeing every frame, and ckpt_path=last resumes under DDP. The sampler's shares: tests/data."""

from __future__ import annotations

import math
from pathlib import Path

import pytest
from hydra.core.hydra_config import HydraConfig

from tests.test_train import compose_train, run_module
from wdss.paths import CONF_DIR, PROJECT_ROOT


def test_other_ranks_run_the_job_alone_in_its_folder_and_paths_survive_hydra_quoting(tmp_path, monkeypatch):
    from hydra.conf import ConfigSourceInfo
    from hydra.core.override_parser.overrides_parser import OverridesParser
    from omegaconf import open_dict, read_write

    from wdss.distributed import rank_command

    cfg = compose_train(["experiment=smoke", "seed=1"], config_dir=PROJECT_ROOT / "sweeps", name="ablation_wavelet")
    folder = str(tmp_path / "it's a job, = 0")
    with read_write(cfg.hydra), open_dict(cfg.hydra):  # what Hydra sets when it runs the job
        cfg.hydra.runtime.output_dir = folder
        cfg.hydra.runtime.config_sources = [  # as a run of `-cd sweeps -cn ablation_wavelet` records them
            ConfigSourceInfo(path="hydra.conf", schema="pkg", provider="hydra"),
            ConfigSourceInfo(path=str(CONF_DIR), schema="file", provider="main"),
            ConfigSourceInfo(path=str(PROJECT_ROOT / "sweeps"), schema="file", provider="command-line"),
        ]
        cfg.hydra.runtime.cwd = str(tmp_path)
    HydraConfig.instance().set_config(cfg)
    command, cwd = rank_command("wdss.train", 1)
    assert command[1:3] == ["-m", "wdss.train"] and cwd == str(tmp_path) and "--multirun" not in command
    assert command[command.index("--config-path") + 1] == str(CONF_DIR)
    assert command[command.index("--config-dir") + 1] == str(PROJECT_ROOT / "sweeps")
    assert command[command.index("--config-name") + 1] == "ablation_wavelet"
    assert {"experiment=smoke", "seed=1", "hydra.mode=RUN", "hydra.output_subdir=null"} <= set(command)
    [run_dir] = [arg for arg in command if arg.startswith("hydra.run.dir=")]
    assert OverridesParser.create().parse_overrides([run_dir])[0].value() == folder


def one_process_metrics(tmp_path: Path, ckpt: Path) -> dict[str, float]:
    """Validation and test of ``ckpt`` in this process, on every frame the DDP ranks shared."""
    import lightning as L

    from wdss.config.targets import instantiate
    from wdss.training.module import SuperResolutionModule

    cfg = compose_train(["experiment=smoke"], tmp_path / "single")
    module = SuperResolutionModule.load_from_checkpoint(ckpt, map_location="cpu", weights_only=True)
    datamodule = instantiate(cfg.data, inputs=list(module.inputs), test_inputs=list(module.test_inputs))
    trainer = L.Trainer(accelerator="cpu", devices=1, logger=False, enable_progress_bar=False)
    metrics = trainer.validate(module, datamodule=datamodule)[0]
    for per_loader in trainer.test(module, datamodule=datamodule):
        metrics.update(per_loader)
    return metrics


@pytest.mark.slow
def test_ddp_on_two_cpu_processes_logs_once_reduces_over_ranks_and_resumes(tmp_path):
    from mlflow import MlflowClient

    outputs = tmp_path / "outputs"
    every_frame = ["trainer.limit_val_batches=1.0", "trainer.limit_test_batches=1.0"]  # 4: two per rank
    ddp = ["experiment=smoke", "trainer=ddp_cpu", "run_name=ddp", f"paths.log_dir={outputs}"]
    done = run_module(tmp_path, "wdss.train", *ddp, *every_frame)
    assert done.returncode == 0, done.stderr[-3000:]
    assert "Initializing distributed: GLOBAL_RANK: 1, MEMBER: 2/2" in done.stderr
    [folder] = (outputs / "runs").iterdir()  # rank 1 ran in rank 0's folder, with a log file of its own
    names = sorted(p.name for p in folder.iterdir())
    assert names == [".hydra", "checkpoints", "mlflow_run_id", "run_key", "run_name", "train.log", "train_rank1.log"]
    client = MlflowClient(f"sqlite:///{tmp_path}/mlflow.db")
    experiment = client.get_experiment_by_name("wdss")
    [run] = client.search_runs([experiment.experiment_id])  # rank 1 made no run
    assert run.info.status == "FINISHED" and run.data.tags["trainer"] == "ddp_cpu"
    assert (folder / "mlflow_run_id").read_text() == run.info.run_id
    # sync_dist: each rank evaluated two of the four frames; the logged means are those of one process seeing all.
    single = one_process_metrics(tmp_path, folder / "checkpoints" / "epoch000.ckpt")
    for key in ("val/psnr", "val/ssim", "test/psnr_2x", "test/ssim_3x", "test/psnr_4x"):
        assert math.isclose(run.data.metrics[key], single[key], rel_tol=1e-5), (key, run.data.metrics[key], single)
    frames = [m.value for m in client.get_metric_history(run.info.run_id, "frames/fixture_000/psnr_2x")]
    assert len(frames) == 4 and not math.isclose(sum(frames[:2]) / 2, single["test/psnr_2x"], rel_tol=1e-5)
    assert "test/twe_ratio_2x" in run.data.metrics  # pooled over the ranks' frame pairs

    # Resume under DDP, in a sweep: rank 1 must run this job only, in its folder, under the one parent run.
    done = run_module(
        tmp_path, "wdss.train", "-m", *ddp, "trainer.max_epochs=2", "ckpt_path=last", "test=false", "bench=null"
    )
    assert done.returncode == 0, done.stderr[-3000:]
    assert done.stdout.count(f"resuming {folder}/checkpoints/last.ckpt in MLflow run {run.info.run_id}") == 2
    assert [p.name for p in (outputs / "runs").iterdir()] == [folder.name]
    [sweep] = (outputs / "multirun").iterdir()
    assert sorted(p.name for p in sweep.iterdir()) == ["0", "mlflow_parent_run_id", "multirun.yaml"]
    assert {"train.log", "train_rank1.log"} <= {p.name for p in (sweep / "0").iterdir()}
    runs = client.search_runs([experiment.experiment_id])
    assert sorted(r.info.run_name for r in runs) == ["ddp", "sweep train"]
    steps = [m.step for m in client.get_metric_history(run.info.run_id, "train/loss")]
    assert steps == [0, 1]  # one step per epoch (a frame per rank): epoch 0 restored, epoch 1 trained
