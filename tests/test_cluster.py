"""A cluster launcher: a sweep submitted through Hydra's submitit launcher (its local executor runs the same
submission code as SLURM's) nests under one parent run and reports; the SLURM preset's settings per job."""

from __future__ import annotations

import pytest

from tests.test_train import compose_train, run_module, run_sweep, sweep_client
from wdss.paths import PROJECT_ROOT

# Without the cluster extra Hydra cannot load the launchers (its error then blames a sweep value or the preset).
pytest.importorskip("hydra_plugins.hydra_submitit_launcher", reason="needs the cluster extra: make setup-cluster")


def test_the_slurm_preset_submits_one_gpu_job_per_configuration_of_a_paper_sweep():
    cfg = compose_train(
        ["experiment=paper", "hydra/launcher=slurm"], config_dir=PROJECT_ROOT / "sweeps", name="ablation_wavelet"
    )
    launcher = cfg.hydra.launcher
    assert launcher._target_ == "hydra_plugins.hydra_submitit_launcher.submitit_launcher.SlurmLauncher"
    assert (launcher.gpus_per_node, launcher.tasks_per_node, launcher.nodes) == (1, 1, 1)
    assert launcher.cpus_per_task == cfg.data.num_workers  # a loader process per CPU
    assert launcher.mem_gb >= 32 and launcher.timeout_min >= 60 * 12
    assert cfg.trainer.accelerator == "gpu" and cfg.trainer.devices == 1


@pytest.mark.slow
def test_a_two_job_sweep_through_submitit_nests_under_one_parent_and_reports(tmp_path):
    done = run_sweep(tmp_path, "ablation_wavelet", "variant=none,swt_haar", "seed=0", "hydra/launcher=submitit_local")
    assert done.returncode == 0, done.stderr[-3000:]
    [sweep_dir] = (tmp_path / "outputs" / "multirun").iterdir()
    assert len(list((sweep_dir / ".submitit").glob("*/*_result.pkl"))) == 2  # each job ran as a submitit job
    client, runs = sweep_client(tmp_path, "ablation_wavelet")
    [parent] = [r for r in runs if "mlflow.parentRunId" not in r.data.tags]
    jobs = [r for r in runs if r.data.tags.get("mlflow.parentRunId") == parent.info.run_id]
    assert sorted(r.data.tags["variant"] for r in jobs) == ["none", "swt_haar"] and len(runs) == 3
    assert all(r.info.status == "FINISHED" and "test/psnr_2x" in r.data.metrics for r in jobs)
    assert client.get_run(parent.info.run_id).data.tags["failed_jobs"] == "0"
    report = run_module(tmp_path, "wdss.report", "--sweep", "ablation_wavelet", "--out", str(tmp_path / "reports"))
    assert report.returncode == 0, report.stderr[-3000:]
    table = (tmp_path / "reports" / "ablation_wavelet" / "table.md").read_text()
    assert "| No wavelet |" in table and "| SWT-haar |" in table
