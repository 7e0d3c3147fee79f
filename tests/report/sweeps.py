"""Fake MLflow sweeps in a temporary SQLite store, and the report's table read back, for the report tests."""

from __future__ import annotations

import math

import numpy as np
from scipy import stats

SEEDS = (0, 1, 2)

# Three seeds of three configurations of the wavelet ablation at 2x, 3x, 4x; SWT-db4 is best in PSNR and
# SSIM, DWT-haar in FLIP; one No-wavelet job failed.
PSNR = {"none": (28.91, 29.12, 28.77), "dwt_haar": (29.40, 29.61, 29.35), "swt_db4": (30.43, 30.58, 30.21)}
FLIP = {"none": (0.1401, 0.1388, 0.1420), "dwt_haar": (0.1102, 0.1121, 0.1095), "swt_db4": (0.1200, 0.1189, 0.1211)}


def fake_sweep(root, name: str, jobs: list[tuple[dict[str, str], dict[str, float], str]], tags=None, old=True) -> str:
    """A parent run tagged ``sweep=name`` and one nested run per job (overrides, metrics, status), as
    ``wdss.train`` logs them: the variant and seed tags (and ``tags[i]``), the tone-map params, and the run named
    by its overrides (``old``: as before the tag ``overrides``) or variant first with the tag ``overrides``."""
    from mlflow import MlflowClient

    uri = f"sqlite:///{root}/mlflow.db"
    client = MlflowClient(uri)
    experiment = client.create_experiment(name, artifact_location=(root / "artifacts").as_uri())
    parent = client.create_run(experiment, run_name=f"sweep {name}", tags={"sweep": name}, start_time=1)
    for i, (job, metrics, status) in enumerate(jobs):
        given = ",".join(f"{k}={v}" for k, v in sorted(job.items()))
        rest = [f"{k.rsplit('.', 1)[-1]}={v}" for k, v in sorted(job.items()) if k not in ("variant", "seed")]
        run = client.create_run(
            experiment,
            run_name=given if old else " · ".join([job["variant"], *rest, f"seed{job.get('seed', 0)}", "mini"]),
            tags={
                "mlflow.parentRunId": parent.info.run_id,
                "sweep": name,
                "variant": job["variant"],
                "seed": "0",
                **({} if old else {"overrides": given}),
                **(tags[i] if tags else {}),
            },
            start_time=10 + i,
        )
        client.log_param(run.info.run_id, "model.tonemap_name", "hable")
        client.log_param(run.info.run_id, "tonemap_exposure", "None")
        for key, value in metrics.items():
            client.log_metric(run.info.run_id, key, value)
        client.set_terminated(run.info.run_id, status)
    client.set_terminated(parent.info.run_id, "FINISHED")
    return uri


def body(markdown: str) -> tuple[list[str], dict[str, list[str]]]:
    """The table's header cells and its rows by configuration."""
    lines = [line for line in markdown.splitlines() if line.startswith("| ")]
    cells = [[c.strip() for c in line.strip("|").split("|")] for line in lines]
    return cells[0], {row[0]: row[1:] for row in cells[1:]}


def t_half_width(values) -> float:
    values = np.asarray(values, dtype=float)
    return float(stats.t.ppf(0.975, len(values) - 1) * values.std(ddof=1) / math.sqrt(len(values)))


def summary_of(uri, sweep):
    from mlflow import MlflowClient

    from wdss.report.rows import group
    from wdss.report.runs import collect, find_parent
    from wdss.report.summary import summarise

    client = MlflowClient(uri)
    groups = group(collect(client, find_parent(client, sweep).info.run_id))
    return client, groups, summarise(groups)[0]
