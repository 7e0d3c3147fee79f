"""Where the project's files are: the Hydra config folder beside the package source (editable installs), and
the ``${run_suffix:}`` resolver that makes each run's output folder its own."""

from __future__ import annotations

import os
import secrets
from pathlib import Path

from omegaconf import OmegaConf

PROJECT_ROOT = Path(os.environ.get("WDSS_ROOT", Path(__file__).resolve().parents[2]))
CONF_DIR = PROJECT_ROOT / "conf"
SWEEPS_DIR = PROJECT_ROOT / "sweeps"  # a file per paper table or figure, its report facts as data

# conf/hydra/default.yaml names run folders by the second they start and this random suffix: two runs started
# in the same second (parallel shells, job arrays) would otherwise share a folder and overwrite each other's
# checkpoints and records. Cached per config, so every reference within one run (and, through Hydra's cache
# copy, every job of a sweep) resolves to the same suffix.
OmegaConf.register_new_resolver("run_suffix", lambda: secrets.token_hex(3), use_cache=True, replace=True)
