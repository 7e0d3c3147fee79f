"""The transform/ and basis/ config groups compose and instantiate for every option."""

from __future__ import annotations

from pathlib import Path

import pytest
from hydra import compose, initialize_config_dir
from hydra.utils import instantiate

from wdss.wavelets import WaveletTransform

CONF = Path(__file__).resolve().parents[2] / "conf"


def options(group: str) -> list[str]:
    return sorted(p.stem for p in (CONF / group).glob("*.yaml"))


def test_groups_list_the_paper_options():
    assert options("transform") == ["dwt", "none", "swt"]
    assert options("basis") == ["db4", "haar", "sym4"]


@pytest.mark.parametrize("basis", options("basis"))
@pytest.mark.parametrize("transform", options("transform"))
def test_transform_and_basis_compose_and_instantiate(transform, basis):
    with initialize_config_dir(config_dir=str(CONF), version_base="1.3"):
        cfg = compose(overrides=[f"+transform={transform}", f"+basis={basis}"])
    module = instantiate(cfg.transform)
    assert isinstance(module, WaveletTransform)
    assert (module.transform, module.wavelet, module.level) == (transform, basis, 1)
