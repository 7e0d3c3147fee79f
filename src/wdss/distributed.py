"""DDP under Hydra: the command that starts the other ranks of a job.

On one node, Lightning's DDP starts ranks 1..N-1 by running the program again with ``LOCAL_RANK`` set; for a Hydra
app it re-runs ``sys.argv`` with ``hydra.run.dir`` set to the run's folder. That is right for a single run only: in
a sweep ``sys.argv`` is the whole multirun (``-m``, or a sweep config with ``hydra.mode: MULTIRUN``), so every rank
would start the sweep again (new sweep folders, a new MLflow parent run, every other job) and ``hydra.run.dir`` is
not the job's folder; and a job that a launcher runs (joblib, submitit) has the launcher's worker as ``sys.argv``.

:func:`rank_command` starts the same job instead, composed from what Hydra recorded of it: its config sources and
name, the Hydra overrides and the job's own task overrides (one value of each swept key), as a single run
(``hydra.mode=RUN``) in the job's folder, writing no second ``.hydra`` (``hydra.output_subdir=null``) and logging
to a file of its own. The task overrides make the rank's ``run_key`` the job's, so ``ckpt_path=last`` finds the
same checkpoint on every rank (the job's new folder has none before all ranks have met). :func:`use_rank_command`
makes Lightning use it. Under SLURM, SLURM starts every rank itself (one task per GPU) and none of this runs.
"""

from __future__ import annotations

import sys
from functools import partial
from typing import Any

from hydra.core.hydra_config import HydraConfig

__all__ = ["rank_command", "use_rank_command"]

# Hydra overrides that the rank's run sets itself.
_SET_HERE = ("hydra.mode", "hydra.run.dir", "hydra.output_subdir", "hydra.job.name")


def _source(source: Any) -> str:
    return str(source.path) if source.schema == "file" else f"{source.schema}://{source.path}"


def _quoted(value: str) -> str:
    """A Hydra override value that is read back verbatim (paths may hold spaces, commas, ``=``)."""
    return "'" + value.replace("\\", "\\\\").replace("'", "\\'") + "'"


def rank_command(module: str, local_rank: int) -> tuple[list[str], str]:
    """``python -m <module> ...`` running this Hydra job as rank ``local_rank``, and the folder to start it in."""
    from hydra.utils import get_original_cwd

    hydra = HydraConfig.get()
    command = [sys.executable, "-m", module]
    for source in hydra.runtime.config_sources:
        if source.provider == "main":
            command += ["--config-path", _source(source)]
        elif source.provider == "command-line":  # --config-dir
            command += ["--config-dir", _source(source)]
    command += ["--config-name", str(hydra.job.config_name)]
    command += [o for o in hydra.overrides.hydra if o.lstrip("+~").split("=", 1)[0] not in _SET_HERE]
    command += list(hydra.overrides.task)
    command += [
        "hydra.mode=RUN",
        f"hydra.run.dir={_quoted(str(hydra.runtime.output_dir))}",
        "hydra.output_subdir=null",
        f"hydra.job.name={hydra.job.name}_rank{local_rank}",
    ]
    return command, get_original_cwd()


def use_rank_command(module: str) -> None:
    """Make Lightning's DDP launcher start the other ranks of Hydra jobs with :func:`rank_command`.

    Lightning (2.6) has no option for it: its launcher calls ``_hydra_subprocess_cmd(local_rank)`` of its module,
    which is replaced here; a Lightning without that name fails loudly rather than start ranks that re-run a sweep.
    """
    from lightning.pytorch.strategies.launchers import subprocess_script

    if not hasattr(subprocess_script, "_hydra_subprocess_cmd"):
        raise RuntimeError(
            "this Lightning has no subprocess_script._hydra_subprocess_cmd: wdss.distributed cannot start DDP ranks "
            "under Hydra (use the Lightning version pinned in pyproject.toml)"
        )
    subprocess_script._hydra_subprocess_cmd = partial(rank_command, module)
