"""Every command's record folder is its own: named by the second it starts and a random suffix (wdss.paths), so two
commands started in the same second never share one; and by its command (training runs in outputs/runs, evaluations,
upscales and exports in outputs/eval, outputs/upscale and outputs/export), so that outputs/runs holds trainings only."""

from __future__ import annotations

import pytest
from hydra import compose, initialize_config_dir
from omegaconf import OmegaConf

import wdss.paths  # noqa: F401  (registers the run_suffix resolver)
from wdss.paths import CONF_DIR


@pytest.mark.parametrize(
    ("conf_dir", "name", "kind", "folder"),
    [
        (CONF_DIR, "train", "run", "runs"),
        (CONF_DIR, "train", "sweep", "multirun"),
        (CONF_DIR, "eval", "run", "eval"),
        (CONF_DIR / "render", "default", "run", "render"),
        (CONF_DIR / "inference", "upscale", "run", "upscale"),
        (CONF_DIR / "inference", "export", "run", "export"),
    ],
)
def test_a_record_folder_carries_its_command_and_a_random_suffix(conf_dir, name, kind, folder):
    with initialize_config_dir(config_dir=str(conf_dir), version_base="1.3"):
        cfg = compose(name, return_hydra_config=True)
    raw = OmegaConf.to_container(cfg.hydra[kind], resolve=False)["dir"]
    assert raw.endswith("_${run_suffix:}"), raw
    assert raw.split("/")[-2] == folder, raw
