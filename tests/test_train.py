"""Configs compose for every option of every group; train(cfg) runs end to end with MLflow; resume; sweeps."""

from __future__ import annotations

import os
import shutil
import subprocess
import sys
from pathlib import Path

import pytest
from hydra import compose, initialize_config_dir
from hydra.core.hydra_config import HydraConfig
from hydra.utils import instantiate
from omegaconf import OmegaConf, open_dict

from wdss.paths import CONF_DIR, PROJECT_ROOT
from wdss.train import ConfigError, train, validate

GROUPS = (
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
    "callbacks",
    "logger",
    "experiment",
    "variant",
    "debug",
)
SWEEPS = PROJECT_ROOT / "sweeps"


def options(group: str) -> list[str]:
    return sorted(p.stem for p in (CONF_DIR / group).glob("*.yaml"))


def compose_train(overrides: list[str], tmp_path: Path | None = None, config_dir: Path = CONF_DIR, name="train"):
    with initialize_config_dir(config_dir=str(config_dir), version_base="1.3"):
        cfg = compose(name, overrides=overrides, return_hydra_config=True)
    HydraConfig.instance().set_config(cfg)
    if tmp_path is not None:
        with open_dict(cfg):
            cfg.paths.root_dir = str(PROJECT_ROOT)
            cfg.paths.output_dir = str(tmp_path / "run")
            cfg.paths.log_dir = str(tmp_path)
    return cfg


def run_module(
    tmp_path: Path, module: str, *args: str, timeout: int = 600, tracking: str | None = None
) -> subprocess.CompletedProcess:
    """``python -m <module> args`` in the project root, tracking to ``tracking``, else a temporary SQLite file."""
    uri = tracking or f"sqlite:///{tmp_path}/mlflow.db"
    env = {**os.environ, "MLFLOW_TRACKING_URI": uri, "MLFLOW_DISABLE_TELEMETRY": "true"}
    return subprocess.run(
        [sys.executable, "-m", module, *args],
        cwd=PROJECT_ROOT,
        env=env,
        capture_output=True,
        text=True,
        timeout=timeout,
    )


def run_sweep(tmp_path: Path, name: str, *args: str, timeout: int = 600) -> subprocess.CompletedProcess:
    """A sweep of ``sweeps/<name>.yaml`` at smoke scale, its outputs and tracking under ``tmp_path``."""
    return run_module(
        tmp_path,
        "wdss.train",
        "-cd",
        "sweeps",
        "-cn",
        name,
        "experiment=smoke",
        f"paths.log_dir={tmp_path}/outputs",
        *args,
        timeout=timeout,
    )


def sweep_client(tmp_path: Path, experiment: str):
    from mlflow import MlflowClient

    client = MlflowClient(f"sqlite:///{tmp_path}/mlflow.db")
    return client, client.search_runs([client.get_experiment_by_name(experiment).experiment_id])


def invalid(cfg) -> str | None:
    try:
        validate(cfg)
    except ConfigError as err:
        return str(err)
    return None


@pytest.mark.parametrize("group", GROUPS)
def test_every_option_of_every_group_composes(group, tmp_path):
    assert options(group), group
    for option in options(group):
        cfg = compose_train([f"{group}={option}"], tmp_path)
        OmegaConf.to_container(cfg.model, resolve=True)  # every interpolation resolves
        OmegaConf.to_container(cfg.data, resolve=True)
        message = invalid(cfg)
        assert message is None, f"{group}={option}: {message}"


@pytest.mark.parametrize(
    "overrides, message",
    [
        (["transform=none", "head=fusion_ll"], "head=fusion_ll needs wavelet subbands"),
        (["transform=none", "head=multi_inr"], "head=multi_inr needs wavelet subbands"),
        (["scale=fixed", "scale.train=[2,3]"], "scale=fixed takes one number"),
        (["scale=arbitrary", "scale.train=2.0"], "scale=arbitrary takes"),
        (["data.test_scales=[2,9]"], r"test_scales must lie in \[1, 8\]"),
        (["loss.weights.temporal=0.3"], "needs temporal=recurrent"),
        (["ckpt_path=/no/such.ckpt"], "is not a file"),
        (["model.optimizer._target_=os.system"], r"model.optimizer._target_=os.system is not on wdss's allowlist"),
        (["model.optimizer._target_=torch.os.system"], r"model.optimizer._target_=torch.os.system is not on"),
        (["transform._target_=torch.save"], r"transform._target_=torch.save is not on"),  # model.net.wavelet
        (
            ["++data.prepare={_target_: torch.load, f: evil.pkl, weights_only: false}"],
            r"data.prepare._target_=torch.load is not on wdss's allowlist",
        ),
        (["data.batch_size=abc"], r"data.batch_size must be an integer >= 1, got 'abc'"),
        (["data.patch_size=-1"], r"data.patch_size must be an integer >= 1, got -1"),
        (["scale=fixed", "scale.train=9"], r"scale.train must lie in \[1, 8\], got 9"),
        (["scale=arbitrary", "scale.train=[0.5,4]"], r"scale.train must lie in \[1, 8\], got 0.5"),
        (["scale=arbitrary", "scale.train=[4,2]"], r"scale.train takes \[low, high\] with low <= high"),
        (["data.val_scale=0"], r"data.val_scale must lie in \[1, 8\], got 0"),
        (["ckpt_path=/etc/passwd"], r"ckpt_path: /etc/passwd is not a checkpoint"),
        (["trainer=ddp_cpu", "trainer.use_distributed_sampler=true"], "trainer.use_distributed_sampler must be false"),
    ],
)
def test_invalid_combinations_are_one_clear_sentence(overrides, message, tmp_path):
    with pytest.raises(ConfigError, match=message):
        validate(compose_train(overrides, tmp_path))


def test_unknown_keys_and_options_are_hydra_errors(tmp_path):
    from hydra.errors import ConfigCompositionException

    with pytest.raises(ConfigCompositionException):
        compose_train(["transform=fft"], tmp_path)
    with pytest.raises(ConfigCompositionException):
        compose_train(["data.pach_size=3"], tmp_path)


@pytest.mark.parametrize("sweep", sorted(p.stem for p in SWEEPS.glob("*.yaml")))
def test_every_sweep_job_composes_and_validates(sweep, tmp_path, monkeypatch):
    """Expand each sweep's parameter grid as Hydra's basic sweeper would and validate every job."""
    import itertools

    monkeypatch.chdir(PROJECT_ROOT)
    base = compose_train([], tmp_path, config_dir=SWEEPS, name=sweep)
    params = base.hydra.sweeper.params
    axes = [[f"{k}={v.strip()}" for v in str(values).split(",")] for k, values in params.items()]
    jobs = list(itertools.product(*axes))
    assert jobs
    for job in jobs:
        cfg = compose_train(list(job), tmp_path, config_dir=SWEEPS, name=sweep)
        assert invalid(cfg) is None, job
        module = instantiate(cfg.model)  # the model, its optimiser and scheduler build for every job
        module.configure_optimizers()


@pytest.mark.parametrize(
    "residual, target",
    [
        ("none", None),
        ("bilinear", "wdss.nets.upsamplers.baselines.Upsample"),
        ("joint_bilateral", "wdss.nets.upsamplers.joint_bilateral.JointBilateralUpsample"),
        ("learned_bilateral", "wdss.nets.upsamplers.learned_bilateral.LearnedBilateralUpsample"),
    ],
)
def test_the_recipe_sweeps_residual_axis_chooses_the_upsampler_over_the_cpu_recipes(residual, target, tmp_path):
    """recipe=cpu (experiment=cpu) chooses residual=learned_bilateral; a residual= override (the ablation_recipe
    sweep's axis) still wins, and the run's params and tags say which residual it used."""
    from wdss.tracking import run_params, run_tags

    job = ["experiment=cpu", "variant=swt_db4", f"residual={residual}"]
    upsampler = compose_train(job, tmp_path, SWEEPS, "ablation_recipe").model.net.upsampler
    assert upsampler is None if target is None else upsampler._target_ == target
    cfg = compose_train(job, tmp_path)  # a single run of the same job (a sweep's config needs its job number)
    assert cfg.model.net.upsampler == upsampler
    assert run_params(cfg)["residual"] == run_tags(cfg)["residual"] == residual
    default = compose_train(["experiment=cpu"], tmp_path)
    assert default.model.net.upsampler._target_.endswith(".LearnedBilateralUpsample")
    assert run_params(default)["residual"] == "learned_bilateral"


def test_baseline_rows_replace_the_model_of_an_experiment(tmp_path):
    cfg = compose_train(["experiment=smoke", "variant=bicubic"], tmp_path)
    assert cfg.model.net._target_ == "wdss.nets.upsamplers.baselines.Upsample" and cfg.model.net.mode == "bicubic"


def test_joint_bilateral_is_a_baseline_row(tmp_path):
    from wdss.tracking import run_tags

    cfg = compose_train(["experiment=cpu", "variant=joint_bilateral"], tmp_path)
    assert invalid(cfg) is None and cfg.model.net.sigma_depth == 0.01 and cfg.model.net.radius == 2
    module = instantiate(cfg.model)
    assert not module.trainable and module.configure_optimizers() is None
    assert set(module.inputs) == {
        "lr",
        "gbuffer",
        "lr_guide",
        "lr_jitter",
        "brdf",
        "target",
        "emission",
    }  # no history: temporal none
    assert run_tags(cfg)["transform"] == run_tags(cfg)["temporal"] == "n/a (baseline)"


@pytest.fixture
def tracking(tmp_path, monkeypatch):
    uri = f"sqlite:///{tmp_path}/mlflow.db"
    monkeypatch.setenv("MLFLOW_TRACKING_URI", uri)
    monkeypatch.setenv("MLFLOW_DISABLE_TELEMETRY", "true")
    from mlflow import MlflowClient

    return MlflowClient(uri)


def test_smoke_training_end_to_end_in_process(tmp_path, tracking):
    cfg = compose_train(["experiment=smoke", "variant=swt_db4", "model.flip=true"], tmp_path)
    metrics = train(cfg)
    for key in ("val/psnr", "test/psnr_2x", "test/ssim_3x", "test/flip_4x", "bench/ms_per_frame", "bench/gflops"):
        assert key in metrics, key
    assert (tmp_path / "run" / "checkpoints" / "last.ckpt").exists()
    experiment = tracking.get_experiment_by_name("wdss")
    assert experiment.tags["mlflow.experimentKind"] == "custom_model_development"  # the UI opens on its runs
    runs = tracking.search_runs([experiment.experiment_id])
    assert len(runs) == 1
    run = runs[0]
    assert run.info.status == "FINISHED"
    assert {run.data.tags[k] for k in ("transform", "basis", "head", "variant")} == {
        "swt",
        "db4",
        "shared_inr",
        "swt_db4",
    }
    artifacts = {a.path for a in tracking.list_artifacts(run.info.run_id)}
    assert {"config.yaml", "images", "test"} <= artifacts
    assert "time/train_s" in run.data.metrics
    # Named variant first; the overrides a report reads are a tag; a score of params, none an absolute path.
    assert run.info.run_name == "swt_db4 · smoke · flip=true · seed0 · rendered"
    assert run.data.tags["overrides"] == "experiment=smoke,model.flip=true,variant=swt_db4"
    assert run.data.tags["data_root"] == "tests/fixtures/rendered"
    params = run.data.params
    assert 15 <= len(params) <= 30, sorted(params)
    assert params["head"] == "shared_inr" and params["variant"] == "swt_db4" and params["seed"] == "0"
    assert params["data.root"] == "tests/fixtures/rendered" and params["model.flip"] == "True"
    assert {"model.optimizer.lr", "trainer.max_epochs", "data.batch_size", "data.patch_size", "scale.train"} <= set(
        params
    )
    assert not [k for k, v in params.items() if str(tmp_path) in v or v.startswith("/")], params
    assert not any(k.startswith(("net/", "optimizer/", "size.", "paths.")) for k in params)  # no autologged copies
    assert (tmp_path / "run" / "run_name").read_text() == run.info.run_name
    assert (tmp_path / "run" / "run_key").read_text() == run.data.tags["overrides"]


def test_resume_from_last_continues_the_same_run(tmp_path, tracking):
    first = compose_train(["experiment=smoke", "transform=dwt", "trainer.max_epochs=1", "test=false"], tmp_path)
    train(first)
    assert (tmp_path / "run" / "checkpoints" / "last.ckpt").exists()
    assert not (tmp_path / "run" / "training.pid").exists()  # held while it trained, released at its end
    second = compose_train(
        ["experiment=smoke", "transform=dwt", "trainer.max_epochs=2", "test=false", "ckpt_path=last"],
        tmp_path / "again",
    )
    with open_dict(second):
        second.paths.log_dir = str(tmp_path)  # where the first run lives
    metrics = train(second)
    assert metrics["trainer/global_step"] == 4  # two batches per epoch: epoch 0 restored, epoch 1 trained
    runs = tracking.search_runs([tracking.get_experiment_by_name("wdss").experiment_id])
    assert len(runs) == 1  # the resumed training logged into the same MLflow run
    steps = sorted(m.step for m in tracking.get_metric_history(runs[0].info.run_id, "train/loss"))
    assert steps == [0, 1, 2, 3]  # steps 0-1 from the first run, 2-3 after resuming: nothing trained twice


def test_a_resume_that_fails_before_training_a_step_leaves_the_run_as_it_was(tmp_path, tracking, monkeypatch):
    """A killed run resumed with ckpt_path=last whose resume fails (here: the fit raises at once) stays KILLED, with
    the error in a tag: it was not the run that failed, and ckpt_path=last can still resume it."""
    import lightning

    first = compose_train(["experiment=smoke", "trainer.max_epochs=1", "test=false"], tmp_path)
    train(first)
    [run] = tracking.search_runs([tracking.get_experiment_by_name("wdss").experiment_id])
    tracking.set_terminated(run.info.run_id, "KILLED")  # as a SIGKILL leaves it (reaped)
    second = compose_train(["experiment=smoke", "trainer.max_epochs=2", "test=false", "ckpt_path=last"], tmp_path / "b")
    with open_dict(second):
        second.paths.log_dir = str(tmp_path)

    def broken_fit(*args, **kwargs):
        raise RuntimeError("the data moved")

    monkeypatch.setattr(lightning.Trainer, "fit", broken_fit)
    with pytest.raises(RuntimeError, match="the data moved"):
        train(second)
    again = tracking.get_run(run.info.run_id)
    assert again.info.status == "KILLED" and again.data.tags["resume_error"] == "RuntimeError: the data moved"


def test_video_under_ddp_is_refused_before_any_run(tmp_path, tracking):
    with pytest.raises(ConfigError, match="video=true needs one process"):
        train(compose_train(["experiment=smoke", "trainer=ddp_cpu", "video=true"], tmp_path))
    assert not (tmp_path / "run" / "mlflow_run_id").exists() and tracking.get_experiment_by_name("wdss") is None


def test_runs_started_in_the_same_second_get_folders_of_their_own(monkeypatch):
    import datetime

    import hydra.core.utils

    class Frozen(datetime.datetime):  # Hydra's ${now:} sees one instant for both runs
        @classmethod
        def now(cls, tz=None):
            return cls(2025, 1, 2, 3, 4, 5)

    monkeypatch.setattr(hydra.core.utils, "datetime", Frozen)
    first, second = (compose_train(["experiment=smoke"]) for _ in range(2))
    for key in ("run", "sweep"):
        folders = {str(OmegaConf.select(cfg, f"hydra.{key}.dir")) for cfg in (first, second)}
        assert len(folders) == 2 and all("2025-01-02_03-04-05_" in folder for folder in folders), folders


def fake_run(log_dir: Path, folder: str, key: str, started: float, checkpointed: float, old=False) -> Path:
    """A run folder as wdss.train leaves it: its configuration's key, name and MLflow id (written at the start) and
    a last.ckpt; ``old``: as folders were before names led with the variant (the key in ``run_name``)."""
    run_dir = log_dir / "runs" / folder
    (run_dir / "checkpoints").mkdir(parents=True)
    (run_dir / "run_name").write_text(key if old else "swt_db4 · smoke · seed0 · rendered")
    if not old:
        (run_dir / "run_key").write_text(key)
    (run_dir / "mlflow_run_id").write_text(f"id-{folder}")
    (run_dir / "checkpoints" / "last.ckpt").write_bytes(b"")
    os.utime(run_dir / ("run_name" if old else "run_key"), (started, started))
    os.utime(run_dir / "checkpoints" / "last.ckpt", (checkpointed, checkpointed))
    return run_dir / "checkpoints" / "last.ckpt"


def test_ckpt_path_last_refuses_runs_of_one_name_that_trained_at_the_same_time(tmp_path):
    from wdss.train import _resume

    cfg = compose_train(["experiment=smoke", "ckpt_path=last"], tmp_path)
    key = "experiment=smoke"
    earlier = fake_run(tmp_path, "a", key, started=1000, checkpointed=1100, old=True)  # before run_key existed
    later = fake_run(tmp_path, "b", key, started=2000, checkpointed=2100)
    fake_run(tmp_path, "c", "experiment=smoke,seed=1", started=3000, checkpointed=3100)  # another configuration
    fake_run(tmp_path, "d", "experiment=smoke,seed=1", started=3000, checkpointed=3100, old=True)
    assert _resume(cfg) == (str(later), "id-b")  # one after the other: the newest is the one started last
    os.utime(earlier, (2050, 2050))  # a still checkpointed after b started: both trained at once
    with pytest.raises(ConfigError, match="ckpt_path=last is ambiguous: 2 runs of 'experiment=smoke'") as err:
        _resume(cfg)
    assert f"{later} (MLflow run id-b)" in str(err.value) and f"{earlier} (MLflow run id-a)" in str(err.value)


def test_ckpt_path_last_refuses_a_run_that_is_still_training_naming_its_pid(tmp_path, monkeypatch):
    """Two processes must never write one MLflow run: the run folder, or a later folder that resumed the same run,
    holds the pid of the process training it; a lock whose process is gone holds nothing."""
    import subprocess
    import sys

    from wdss.train import LOCK_FILE, _resume

    cfg = compose_train(["experiment=smoke", "ckpt_path=last"], tmp_path)
    last = fake_run(tmp_path, "a", "experiment=smoke", started=1000, checkpointed=1100)
    other = subprocess.Popen([sys.executable, "-c", "import time; time.sleep(60)"])
    try:
        (last.parent.parent / LOCK_FILE).write_text(str(other.pid))
        with pytest.raises(
            ConfigError, match=rf"ckpt_path=last: .* is still training \(pid {other.pid}\) into MLflow run id-a"
        ):
            _resume(cfg)
        (last.parent.parent / LOCK_FILE).unlink()
        resumed = tmp_path / "runs" / "resumed"  # resumed the same MLflow run, no checkpoint of its own yet
        resumed.mkdir(parents=True)
        (resumed / "mlflow_run_id").write_text("id-a")
        (resumed / LOCK_FILE).write_text(str(other.pid))
        with pytest.raises(ConfigError, match=rf"resumed is still training \(pid {other.pid}\)"):
            _resume(cfg)
        with monkeypatch.context() as env:  # DDP: rank 1 joins the job whose lock rank 0 holds
            env.setenv("LOCAL_RANK", "1")
            assert _resume(cfg) == (str(last), "id-a")
    finally:
        other.kill()
        other.wait()
    assert _resume(cfg) == (str(last), "id-a")  # its process has ended: the lock it left holds nothing


def test_the_test_after_a_resume_loads_only_a_checkpoint_of_its_own_run(tmp_path, capsys):
    """A resumed callback state names the best checkpoint: it is tested only from a checkpoints folder of the same
    MLflow run (this folder, or the one it resumed), never another run's file or any other path."""
    from wdss.train import _own_checkpoint

    cfg = compose_train(["experiment=smoke"], tmp_path)
    before = fake_run(tmp_path, "a", "experiment=smoke", started=1000, checkpointed=1100)  # MLflow run id-a
    other = fake_run(tmp_path, "b", "experiment=smoke", started=2000, checkpointed=2100)  # run id-b
    own = tmp_path / "run" / "checkpoints" / "epoch003.ckpt"
    assert str(cfg.paths.output_dir) == str(tmp_path / "run")
    assert _own_checkpoint(str(own), cfg, "id-a") == str(own)
    assert _own_checkpoint(str(before), cfg, "id-a") == str(before)  # the folder this run resumed
    assert _own_checkpoint("", cfg, "id-a") == ""
    for path in (other, Path("/etc/passwd")):
        assert _own_checkpoint(str(path), cfg, "id-a") == ""
        assert f"the best checkpoint the state names, {path}, is not one of this run's" in capsys.readouterr().err


def test_resuming_a_run_another_tracking_store_holds_is_refused_in_one_line(tmp_path, tracking):
    from tests.config.test_targets import UPSAMPLE, crafted_checkpoint

    last = fake_run(tmp_path, "a", "experiment=smoke", started=1000, checkpointed=1100)  # MLflow run id-a, elsewhere
    crafted_checkpoint(tmp_path, UPSAMPLE).replace(last)  # a readable checkpoint: what ckpt_path=last reads first
    cfg = compose_train(["experiment=smoke", "ckpt_path=last"], tmp_path)
    with pytest.raises(ConfigError, match=rf"ckpt_path=last: {last} was trained in MLflow run id-a, which the tracking "
                       r"store .* does not hold .*point logger.tracking_uri"):  # fmt: skip
        train(cfg)


def test_last_ckpt_is_written_every_epoch_and_when_sigterm_lands_in_validation(tmp_path, tracking, monkeypatch):
    """lr=0: val/psnr never improves after epoch 0, so only an every-epoch last.ckpt can hold epoch 1."""
    import signal

    import torch

    from wdss.training.module import SuperResolutionModule

    validation_step = SuperResolutionModule.validation_step

    def sigterm_in_epoch_1(self, batch, batch_idx):
        if self.current_epoch == 1:
            os.kill(os.getpid(), signal.SIGTERM)  # Lightning notes it and stops once the epoch has ended
        return validation_step(self, batch, batch_idx)

    monkeypatch.setattr(SuperResolutionModule, "validation_step", sigterm_in_epoch_1)
    overrides = ["experiment=smoke", "trainer.max_epochs=4", "model.optimizer.lr=0", "test=false", "bench=null"]
    with pytest.raises(SystemExit) as stop:
        train(compose_train(overrides, tmp_path))
    assert stop.value.code == 128 + signal.SIGTERM
    checkpoints = tmp_path / "run" / "checkpoints"
    assert sorted(p.name for p in checkpoints.iterdir()) == ["epoch000.ckpt", "last.ckpt"]  # epoch 1: no better
    assert torch.load(checkpoints / "last.ckpt", weights_only=True)["epoch"] == 1


def test_ctrl_c_ends_the_run_killed_with_the_resume_hint(tmp_path, tracking, monkeypatch, capsys):
    import signal

    from wdss.training.module import SuperResolutionModule

    training_step = SuperResolutionModule.training_step

    def ctrl_c_at_step_3(self, batch, batch_idx):
        if self.global_step == 3:
            os.kill(os.getpid(), signal.SIGINT)  # Python raises KeyboardInterrupt here
        return training_step(self, batch, batch_idx)

    monkeypatch.setattr(SuperResolutionModule, "training_step", ctrl_c_at_step_3)
    handler = signal.signal(signal.SIGINT, signal.default_int_handler)  # whatever the shell gave this process
    try:
        with pytest.raises(SystemExit) as stop:
            train(compose_train(["experiment=smoke", "trainer.max_epochs=3", "test=false", "bench=null"], tmp_path))
    finally:
        signal.signal(signal.SIGINT, handler)  # Lightning ignores further Ctrl-C while it shuts down
    assert stop.value.code == 128 + signal.SIGINT
    assert "stopped by SIGINT; resume with ckpt_path=last" in capsys.readouterr().out
    [run] = tracking.search_runs([tracking.get_experiment_by_name("wdss").experiment_id])
    assert run.info.status == "KILLED"


@pytest.mark.slow
def test_a_tiny_sweep_nests_its_runs_survives_a_failing_job_and_reports(tmp_path):
    """4 jobs, one of which fails (a patch larger than the frame): the others finish, the report marks it."""
    done = run_sweep(
        tmp_path,
        "ablation_wavelet",
        "variant=swt_haar,bilinear_demodulated",
        "data.patch_size=24,1000",
        "seed=0",
        "model.flip=true",
    )
    assert done.returncode != 0 and "patch size 1000 is larger than the frame" in done.stderr
    report = run_module(tmp_path, "wdss.report", "--sweep", "ablation_wavelet", "--out", str(tmp_path / "reports"))
    assert report.returncode == 0, report.stderr[-3000:]
    out = tmp_path / "reports" / "ablation_wavelet"
    table = (out / "table.md").read_text()
    # One row per value of the sweep's axes (variant, data.patch_size), named as the paper names its rows.
    assert "| SWT-haar, data.patch_size=24 |" in table and "| Bilinear (demod.), data.patch_size=24 |" in table
    failed = next(line for line in table.splitlines() if line.startswith("| SWT-haar, data.patch_size=1000 |"))
    assert "missing" in failed and failed.endswith("| 1 of 1 jobs FAILED |")
    assert (out / "tradeoff.png").stat().st_size > 0 and (out / "qualitative.png").stat().st_size > 0
    client, runs = sweep_client(tmp_path, "ablation_wavelet")
    parents = [r for r in runs if "mlflow.parentRunId" not in r.data.tags]
    children = [r for r in runs if r.data.tags.get("mlflow.parentRunId") == parents[0].info.run_id]
    assert len(parents) == 1 and len(children) == 4
    assert sorted(r.info.status for r in children) == ["FAILED", "FINISHED", "FINISHED", "FINISHED"]
    parent = client.get_run(parents[0].info.run_id)
    assert parent.info.status == "FINISHED" and parent.data.tags["failed_jobs"] == "1"
    assert parent.data.tags["data_root"] == "tests/fixtures/rendered"
    assert {r.info.run_name for r in children} == {  # variant first, then the sweep's other axis, seed, data
        f"{variant} · smoke · patch_size={size} · flip=True · seed0 · rendered"
        for variant in ("swt_haar", "bilinear_demodulated")
        for size in (24, 1000)
    }
    assert {a.path for a in client.list_artifacts(parents[0].info.run_id, "report")} >= {
        "report/table.md",
        "report/table.csv",
        "report/tradeoff.png",
    }


def eval_config(ckpt: Path, out: Path, *overrides: str):
    return compose_train(
        [f"ckpt_path={ckpt}", "data=fixture", "bench.height=48", "bench.width=96", "bench.repeats=1", *overrides],
        out,
        name="eval",
    )


def test_eval_rebuilds_from_the_checkpoint_and_logs_under_the_training_run(tmp_path, tracking, capsys):
    from wdss.eval import evaluate

    train(compose_train(["experiment=smoke", "variant=dwt_haar", "test=false"], tmp_path))
    ckpt = tmp_path / "run" / "checkpoints" / "last.ckpt"
    [trained] = tracking.search_runs([tracking.get_experiment_by_name("wdss").experiment_id])
    metrics = evaluate(eval_config(ckpt, tmp_path / "eval", "data.test_scales=[2.0,2.5]", "write_outputs=true"))
    assert "was trained on" not in capsys.readouterr().out  # the data it was trained on: nothing to say
    assert {"test/psnr_2x", "test/psnr_2.5x", "bench/ms_per_frame"} <= set(metrics)
    [evaluation] = tracking.search_runs(
        [trained.info.experiment_id], f"tags.mlflow.parentRunId = '{trained.info.run_id}'"
    )
    assert evaluation.info.status == "FINISHED" and "test/psnr_2.5x" in evaluation.data.metrics
    assert evaluation.data.tags["ckpt_path"] == str(ckpt.resolve())
    assert evaluation.info.run_name == "eval last.ckpt · tests/fixtures/rendered"  # named by checkpoint and data
    assert (
        evaluation.data.tags["overrides"]
        == trained.data.tags["overrides"]
        == "experiment=smoke,test=false,variant=dwt_haar"
    )
    assert evaluation.data.params == {
        "ckpt": "last.ckpt",
        "data.root": "tests/fixtures/rendered",
        "data.test_scales": "[2.0, 2.5]",
        "model.tonemap_name": "hable",
        "tonemap_exposure": "None",
    }  # what the evaluation chose, not the module's hyper-parameters again
    assert evaluation.data.tags["bench/resolution"] == "96x48 output, 2x"  # the report's runtime axis
    assert evaluation.data.tags["bench/device"].startswith("cpu: ") and evaluation.data.tags["bench/process"]
    assert tracking.get_run(trained.info.run_id).info == trained.info  # status and end time as training left them
    frames = sorted(p.name for p in (tmp_path / "eval" / "run" / "frames").iterdir())
    assert "fixture_000_0001_2.5x.exr" in frames and "fixture_000_0001_2.5x.png" in frames
    # eval tests on the data its own config names, which need not be the training run's: it says so
    shutil.copytree(Path("tests/fixtures/rendered"), tmp_path / "elsewhere")
    evaluate(eval_config(ckpt, tmp_path / "eval2", f"data.root={tmp_path / 'elsewhere'}", "data.test_scales=[2.0]"))
    assert "was trained on tests/fixtures/rendered" in capsys.readouterr().out


def test_eval_logs_temporal_metrics_per_frame_histories_and_videos_of_each_test_sequence(tmp_path, tracking):
    import av

    from wdss.eval import evaluate

    train(compose_train(["experiment=smoke", "variant=dwt_haar", "test=false", "bench=null"], tmp_path))
    ckpt = tmp_path / "run" / "checkpoints" / "last.ckpt"
    config = eval_config(ckpt, tmp_path / "eval", "data.test_scales=[2.0]", "bench=null", "video=true")
    with open_dict(config):
        config.trainer.limit_test_batches = None  # every frame of the sequence, in order
    metrics = evaluate(config)
    assert metrics["test/twe_2x"] > 0 and metrics["test/twe_ratio_2x"] > 0 and metrics["test/tpsnr_2x"] > 0
    [evaluation] = tracking.search_runs([tracking.get_experiment_by_name("wdss").experiment_id], "tags.ckpt_path != ''")
    run_id = evaluation.info.run_id
    assert {"test/twe_2x", "test/twe_target_2x", "test/twe_ratio_2x", "test/tpsnr_2x"} <= set(evaluation.data.metrics)
    # The temporal model skips the fixture's first frame (no history): frames 1-4, the PSNR of each by frame index.
    history = tracking.get_metric_history(run_id, "frames/fixture_000/psnr_2x")
    assert sorted(m.step for m in history) == [1, 2, 3, 4]
    assert {"test/pred_2x.png", "test/pred_2x_t1.png", "test/pred_2x_t2.png"} <= {
        a.path for a in tracking.list_artifacts(run_id, "test")
    }
    videos = {a.path for a in tracking.list_artifacts(run_id, "videos")}
    assert videos == {"videos/fixture_000_2x.mp4", "videos/fixture_000_2x_crop.gif"}
    mp4 = tracking.download_artifacts(run_id, "videos/fixture_000_2x.mp4", str(tmp_path))
    with av.open(mp4) as container:
        frames = [frame.to_ndarray(format="rgb24") for frame in container.decode(video=0)]
        assert container.streams.video[0].codec_context.name == "h264"
    # Four 96x48 tiles (LR | prediction | target | error) under a 14-pixel label strip, one frame per test frame,
    # the sequence played as often as it takes to last a few seconds.
    from wdss.video import loops

    assert len(frames) == 4 * loops(4, 30) and frames[0].shape == (48 + 14, 4 * 96, 3)


def test_a_failed_eval_leaves_the_training_run_as_it_was(tmp_path, tracking, monkeypatch):
    from wdss.eval import evaluate
    from wdss.training.module import SuperResolutionModule

    train(compose_train(["experiment=smoke", "variant=dwt_haar", "test=false", "bench=null"], tmp_path))
    [trained] = tracking.search_runs([tracking.get_experiment_by_name("wdss").experiment_id])

    def broken(self, batch, batch_idx, dataloader_idx=0):
        raise RuntimeError("evaluation broke")

    monkeypatch.setattr(SuperResolutionModule, "test_step", broken)
    with pytest.raises(RuntimeError, match="evaluation broke"):
        evaluate(eval_config(tmp_path / "run" / "checkpoints" / "last.ckpt", tmp_path / "eval"))
    assert tracking.get_run(trained.info.run_id).info == trained.info  # still FINISHED, same end time
    [evaluation] = tracking.search_runs(
        [trained.info.experiment_id], f"tags.mlflow.parentRunId = '{trained.info.run_id}'"
    )
    assert evaluation.info.status == "FAILED"


def test_eval_against_a_store_without_the_training_run_makes_a_tagged_run(tmp_path, tracking, monkeypatch, capsys):
    from mlflow import MlflowClient

    from wdss.eval import evaluate

    train(compose_train(["experiment=smoke", "variant=dwt_haar", "test=false", "bench=null"], tmp_path))
    [trained] = tracking.search_runs([tracking.get_experiment_by_name("wdss").experiment_id])
    other = f"sqlite:///{tmp_path}/other.db"
    monkeypatch.setenv("MLFLOW_TRACKING_URI", other)
    ckpt = tmp_path / "run" / "checkpoints" / "last.ckpt"
    evaluate(eval_config(ckpt, tmp_path / "eval"))
    assert f"the training run {trained.info.run_id} of {ckpt} is not in {other}" in capsys.readouterr().out
    client = MlflowClient(other)
    experiment = client.get_experiment_by_name("wdss")
    assert experiment.tags["mlflow.experimentKind"] == "custom_model_development"
    [evaluation] = client.search_runs([experiment.experiment_id])
    assert evaluation.info.status == "FINISHED" and "test/psnr_2x" in evaluation.data.metrics
    tags = evaluation.data.tags
    assert tags["training_run_id"] == trained.info.run_id and tags["ckpt_path"] == str(ckpt.resolve())
    assert "mlflow.parentRunId" not in tags


def test_ema_tests_the_averaged_weights_it_validated_and_checkpointed(tmp_path, tracking):
    import torch

    from wdss.eval import evaluate

    overrides = ["experiment=smoke", "callbacks=ema", "callbacks.ema.decay=0.5", "trainer.limit_train_batches=3"]
    metrics = train(compose_train([*overrides, "data.test_scales=[2.0]"], tmp_path))
    [best] = (tmp_path / "run" / "checkpoints").glob("epoch*.ckpt")
    checkpoint = torch.load(best, weights_only=True, map_location="cpu")
    raw, average = checkpoint["current_model_state"], checkpoint["state_dict"]
    assert any(not torch.equal(raw[k], average[k]) for k in average)  # the two weight sets differ
    # wdss.eval reads the checkpoint's state_dict (the average): the test after the fit must measure the same
    again = evaluate(eval_config(best, tmp_path / "eval", "data.test_scales=[2.0]", "+trainer.limit_test_batches=1"))
    assert metrics["test/psnr_2x"] == pytest.approx(again["test/psnr_2x"], abs=1e-4)


@pytest.mark.slow
def test_parallel_jobs_against_one_sqlite_file_lose_no_run(tmp_path):
    done = run_sweep(tmp_path, "ablation_wavelet", "variant=none,dwt_haar", "seed=0,1", "hydra/launcher=parallel")
    assert done.returncode == 0, done.stderr[-3000:]
    _, runs = sweep_client(tmp_path, "ablation_wavelet")
    children = [r for r in runs if "mlflow.parentRunId" in r.data.tags]
    assert len(children) == 4 and all(r.info.status == "FINISHED" for r in children)
    assert all({"test/psnr_2x", "val/psnr", "bench/gflops"} <= set(r.data.metrics) for r in children)


def test_evaluating_real_esrgan_without_weights_or_training_is_refused(tmp_path, tracking):
    cfg = compose_train(["experiment=smoke", "variant=real_esrgan", "fit=false"], tmp_path)
    with pytest.raises(ConfigError, match="RRDBNet has no weights: set model.net.weights"):
        train(cfg)


@pytest.mark.slow
def test_the_methods_sweep_runs_every_method_at_smoke_scale(tmp_path):
    done = run_sweep(tmp_path, "methods", "seed=0", timeout=900)
    assert done.returncode == 0, done.stderr[-3000:]
    client, runs = sweep_client(tmp_path, "methods")
    jobs = {r.data.tags.get("variant"): r for r in runs if "mlflow.parentRunId" in r.data.tags}
    methods = {"bicubic", "bilinear_demodulated", "joint_bilateral", "joint_bilateral_color", "learned_bilateral"}
    methods |= {"real_esrgan", "real_esrgan_demodulated", "nsrr", "fusesr", "dfasr"}
    assert set(jobs) == methods | {"none", "swt_db4"}
    assert all(r.info.status == "FINISHED" and "test/psnr_3x" in r.data.metrics for r in jobs.values())
    assert jobs["real_esrgan"].data.tags["weights"] == "trained-on-wdss-frames"
    assert jobs["dfasr"].data.tags["temporal"] == "recurrent"
    for variant, run in jobs.items():  # where flicker shows: a video of every method and baseline
        videos = {a.path for a in client.list_artifacts(run.info.run_id, "videos")}
        assert videos == {"videos/fixture_000_3x.mp4", "videos/fixture_000_3x_crop.gif"}, variant


def test_where_a_run_is_tracked_is_no_part_of_its_name(tmp_path, tracking):
    """A run logged to another store (logger.tracking_uri=...) is the same experiment: its name says what ran."""
    from wdss.tracking import run_name

    uri = f"sqlite:///{tmp_path}/other.db"
    cfg = compose_train(["experiment=smoke", "variant=swt_db4", f"logger.tracking_uri={uri}"], tmp_path)
    assert run_name(cfg) == "swt_db4 · smoke · seed0 · rendered"
