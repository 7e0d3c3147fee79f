"""Configs and checkpoints build only allowlisted callables (wdss.targets), on every path that instantiates."""

from __future__ import annotations

import os
from pathlib import Path

import lightning
import pytest
import torch
from omegaconf import OmegaConf

from tests.test_train import compose_train
from wdss.checkpoint import CheckpointError, read_checkpoint
from wdss.model.module import SuperResolutionModule
from wdss.paths import CONF_DIR, PROJECT_ROOT
from wdss.targets import TargetRefused, check_targets, instantiate

YAML_FILES = sorted(CONF_DIR.rglob("*.yaml")) + sorted((PROJECT_ROOT / "sweeps").glob("*.yaml"))


def _named_targets(node) -> list[str]:
    if isinstance(node, dict):
        return ([node["_target_"]] if "_target_" in node else []) + [
            t for v in node.values() for t in _named_targets(v)
        ]
    if isinstance(node, list):
        return [t for v in node for t in _named_targets(v)]
    return []


@pytest.mark.parametrize("path", YAML_FILES, ids=lambda p: str(p.relative_to(PROJECT_ROOT)))
def test_every_target_of_wdss_configs_is_allowed(path):
    config = OmegaConf.to_container(OmegaConf.load(path), resolve=False)
    check_targets(config, path.stem)


def test_the_configs_name_targets_at_all():
    assert len({t for p in YAML_FILES for t in _named_targets(OmegaConf.to_container(OmegaConf.load(p)))}) >= 15


@pytest.mark.parametrize(
    "target",
    [
        "torch.save",
        "torch.load",
        "torch.os.system",
        "os.system",
        "builtins.eval",
        "torch.optim.Optimizer",
        "torch.optim.lr_scheduler.LambdaLR",
        "wdss.train.train",
        "no_such_package.thing",
        "torch.optim.Adam.step",
    ],
)
def test_targets_off_the_list_are_refused_wherever_they_are_nested(target):
    with pytest.raises(TargetRefused, match=rf"^model\.scheduler\[1\]\.inner\._target_={target} is not on"):
        check_targets({"scheduler": [{}, {"inner": {"_target_": target, "_partial_": True}}]}, "model")


def test_resolving_a_refused_target_imports_nothing():
    import sys

    with pytest.raises(TargetRefused):
        check_targets({"_target_": "json.tool.main"})  # an importable module off the list
    assert "json.tool" not in sys.modules


def test_instantiate_checks_before_building(tmp_path):
    victim = tmp_path / "written"
    with pytest.raises(TargetRefused, match="_target_=torch.save"):
        instantiate({"_target_": "torch.save", "obj": 1, "f": str(victim)})
    with pytest.raises(TargetRefused, match="_target_=torch.save"):  # a mapping passed as a kwarg is built too
        instantiate({"_target_": "torch.optim.SGD", "_partial_": True}, lr={"_target_": "torch.save", "f": "x"})
    assert not victim.exists()
    assert instantiate({"_target_": "torch.optim.SGD", "_partial_": True, "lr": 0.1}).func is torch.optim.SGD


def _payload(tmp_path: Path) -> Path:
    """A pickle that creates ``pwned`` when loaded with weights_only=False."""

    class Payload:
        def __reduce__(self):
            return (open, (str(tmp_path / "pwned"), "w"))

    torch.save(Payload(), tmp_path / "evil.pkl")
    return tmp_path / "evil.pkl"


NETS = {
    "save": lambda tmp: {"_target_": "torch.save", "obj": "owned", "f": str(tmp / "pwned")},
    "load": lambda tmp: {"_target_": "torch.load", "f": str(_payload(tmp)), "weights_only": False},
}


def crafted_checkpoint(tmp_path: Path, net: dict) -> Path:
    """A Lightning checkpoint, loadable weights-only, whose stored network config is ``net``."""
    honest = SuperResolutionModule({"_target_": "wdss.model.baselines.Upsample"}, flip=False)
    path = tmp_path / "crafted.ckpt"
    torch.save(
        {
            "pytorch-lightning_version": lightning.__version__,
            "state_dict": honest.state_dict(),
            "hyper_parameters": {**honest.hparams, "net": net},
        },
        path,
    )
    return path


@pytest.mark.parametrize("net", NETS)
def test_a_crafted_checkpoint_builds_nothing_when_loaded(net, tmp_path):
    ckpt = crafted_checkpoint(tmp_path, NETS[net](tmp_path))
    target = f"torch.{net}"
    with pytest.raises(TargetRefused, match=rf"^net\._target_={target} is not on wdss's allowlist"):
        SuperResolutionModule.load_from_checkpoint(ckpt, map_location="cpu", weights_only=True)
    with pytest.raises(CheckpointError, match=rf"{ckpt}: hyper_parameters\.net\._target_={target} is not on"):
        read_checkpoint(ckpt)
    assert not (tmp_path / "pwned").exists()


def test_the_module_refuses_an_optimizer_or_scheduler_off_the_list_when_built_not_when_fitted(tmp_path):
    net = {"_target_": "wdss.model.baselines.Upsample"}
    evil = {"_target_": "torch.save", "_partial_": True, "f": str(tmp_path / "pwned")}
    with pytest.raises(TargetRefused, match=r"^optimizer\._target_=torch\.save is not on"):
        SuperResolutionModule(net, optimizer=evil, flip=False)
    with pytest.raises(TargetRefused, match=r"^scheduler\._target_=torch\.save is not on"):
        SuperResolutionModule(net, scheduler=evil, flip=False)
    assert not (tmp_path / "pwned").exists()


def test_eval_refuses_a_crafted_checkpoint_before_any_run_or_file(tmp_path, monkeypatch):
    from wdss.eval import evaluate

    monkeypatch.setenv("MLFLOW_TRACKING_URI", f"sqlite:///{tmp_path}/mlflow.db")
    ckpt = crafted_checkpoint(tmp_path, NETS["save"](tmp_path))
    cfg = compose_train([f"ckpt_path={ckpt}", "data=fixture"], tmp_path / "eval", name="eval")
    with pytest.raises(CheckpointError, match=r"hyper_parameters\.net\._target_=torch\.save is not on"):
        evaluate(cfg)
    assert not (tmp_path / "pwned").exists() and not (tmp_path / "mlflow.db").exists()


def test_eval_refuses_targets_off_the_list_in_its_own_config(tmp_path):
    from wdss.eval import evaluate

    ckpt = crafted_checkpoint(tmp_path, {"_target_": "wdss.model.baselines.Upsample"})
    cfg = compose_train([f"ckpt_path={ckpt}", "data.prepare._target_=torch.load"], tmp_path / "eval", name="eval")
    with pytest.raises(TargetRefused, match=r"^data\.prepare\._target_=torch\.load is not on"):
        evaluate(cfg)


@pytest.mark.parametrize(
    "content, message",
    [
        (b"root:x:0:0:root:/root:/bin/bash\n", "is not a checkpoint: not a torch archive"),
        (os.urandom(4096), "is not a checkpoint: not a torch archive"),
        (None, r"cannot be read as a checkpoint \(UnpicklingError\)"),  # a pickle of code, in a torch archive
    ],
)
def test_a_file_that_is_not_a_checkpoint_is_named_without_suggesting_weights_only_false(content, message, tmp_path):
    from wdss.train import ConfigError, validate

    ckpt = tmp_path / "model.ckpt"
    if content is None:
        _payload(tmp_path).rename(ckpt)
    else:
        ckpt.write_bytes(content)
    with pytest.raises(ConfigError, match=rf"ckpt_path: {ckpt} {message}") as error:
        validate(compose_train([f"ckpt_path={ckpt}"], tmp_path))
    assert "weights_only" not in str(error.value) and not (tmp_path / "pwned").exists()


@pytest.mark.slow
def test_training_from_a_random_file_named_ckpt_fails_before_any_run_exists(tmp_path):
    from tests.test_train import run_module

    ckpt = tmp_path / "model.ckpt"
    ckpt.write_bytes(os.urandom(4096))
    done = run_module(tmp_path, "wdss.train", f"ckpt_path={ckpt}", f"paths.log_dir={tmp_path}/outputs")
    assert done.returncode != 0
    assert f"ckpt_path: {ckpt} is not a checkpoint" in done.stderr and "weights_only" not in done.stderr
    # Validated before Hydra makes the run's folder (wdss.train.ValidateBeforeRun): nothing is left behind.
    assert not (tmp_path / "outputs").exists(), sorted(p.name for p in (tmp_path / "outputs").rglob("*"))
    assert not (tmp_path / "mlflow.db").exists()
