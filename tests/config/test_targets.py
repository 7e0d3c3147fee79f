"""Configs and checkpoints build only allowlisted callables (wdss.config.targets), on every path that instantiates."""

from __future__ import annotations

import os
import re
from pathlib import Path

import lightning
import pytest
import torch
from omegaconf import OmegaConf

from tests.test_train import compose_train
from wdss.checkpoint import CheckpointError, read_checkpoint
from wdss.config.targets import InterpolationRefused, TargetRefused, check_targets, instantiate
from wdss.errors import check_built
from wdss.paths import CONF_DIR, PROJECT_ROOT
from wdss.training.module import SuperResolutionModule

YAML_FILES = sorted(CONF_DIR.rglob("*.yaml")) + sorted((PROJECT_ROOT / "sweeps").glob("*.yaml"))


def _named_targets(node) -> list[str]:
    if isinstance(node, dict):
        return ([node["_target_"]] if "_target_" in node else []) + [
            t for v in node.values() for t in _named_targets(v)
        ]
    if isinstance(node, list):
        return [t for v in node for t in _named_targets(v)]
    return []


def _package(path: Path) -> str:
    """The key a config file's nodes land at: its group's folder (conf/model -> model), or ``# @package``."""
    header = re.search(r"^# @package (\S+)", path.read_text(), re.MULTILINE)
    if header:
        return "" if header.group(1) == "_global_" else header.group(1)
    root = CONF_DIR if path.is_relative_to(CONF_DIR) else path.parent
    group = path.parent.relative_to(root).parts
    return "" if group in ((), ("inference",), ("render",)) else ".".join(group)  # config folders of their own


def _uninterpolated(node):
    """``node`` with its interpolations blanked: a file alone cannot resolve them."""
    if isinstance(node, dict):
        return {k: _uninterpolated(v) for k, v in node.items()}
    if isinstance(node, list):
        return [_uninterpolated(v) for v in node]
    return "" if isinstance(node, str) and "${" in node else node


@pytest.mark.parametrize("path", YAML_FILES, ids=lambda p: str(p.relative_to(PROJECT_ROOT)))
def test_every_target_of_wdss_configs_is_allowed_in_its_slot(path):
    config = OmegaConf.to_container(OmegaConf.load(path), resolve=False)
    check_targets(_uninterpolated(config), _package(path))


COMMANDS = {  # entry point -> its config folder and name
    "wdss.train": (CONF_DIR, "train"),
    "wdss.eval": (CONF_DIR, "eval"),
    "wdss.upscale": (CONF_DIR / "inference", "upscale"),
    "wdss.export": (CONF_DIR / "inference", "export"),
    "wdss.render": (CONF_DIR / "render", "default"),
}
OPTIONS = [
    f"{p.parent.name}={p.stem}"
    for g in ("variant", "experiment", "model", "callbacks")
    for p in (CONF_DIR / g).glob("*.yaml")
]


@pytest.mark.parametrize(
    "argv",
    [
        [],
        ["hydra/launcher=parallel"],
        ["hydra/launcher=slurm"],
        ["-cd", "sweeps", "-cn", "methods"],
        *[[o] for o in OPTIONS],
    ],
    ids=" ".join,
)
def test_every_composed_config_passes_the_check_before_hydra_runs(argv, capsys, monkeypatch):
    monkeypatch.chdir(PROJECT_ROOT)  # sweeps/ find conf/ relative to the project root
    check_built("wdss.train", *COMMANDS["wdss.train"], argv)
    assert capsys.readouterr().err == ""


@pytest.mark.parametrize("command", COMMANDS)
@pytest.mark.parametrize(
    "override, message",
    [
        (
            "+hydra.callbacks.evil={_target_: torch.save, obj: 1, f: PWNED}",
            r"hydra\.callbacks\.evil\._target_=torch\.save is not on wdss's allowlist for hydra\.callbacks\.evil, "
            r"which builds a Hydra callback",
        ),
        (
            "+hydra.callbacks.evil={_target_: wdss.render.render_preset, out_dir: PWNED}",
            r"hydra\.callbacks\.evil\._target_=wdss\.render\.render_preset is not on wdss's allowlist for hydra\.callb",
        ),
        (
            "+hydra.launcher.inner={_target_: torch.save, obj: 1, f: PWNED}",
            r"hydra\.launcher\.inner\._target_=torch\.save is not on wdss's allowlist: nothing is built at "
            r"hydra\.launcher\.inner",
        ),
        (
            "+hydra.job_logging.handlers.evil={class: subprocess.Popen, args: [touch, PWNED]}",
            r"hydra\.job_logging\.handlers\.evil\.class=subprocess\.Popen is not on wdss's allowlist of logging",
        ),
        (
            "hydra: {hydra_logging: {formatters: {evil: {'()': torch.save, obj: 1, f: PWNED}}}}",  # a file: no override
            r"hydra\.hydra_logging\.formatters\.evil\.\(\)=torch\.save is not on wdss's allowlist of logging",
        ),
        (
            "+hydra.callbacks.evil='${oc.create:{_target_: torch.save, obj: 1, f: PWNED}}'",
            r"hydra\.callbacks\.evil\._target_=torch\.save is not on",
        ),
    ],
    ids=["callback", "callback-of-another-kind", "launcher", "logging-class", "logging-factory", "interpolated"],
)
def test_what_hydra_builds_from_its_own_node_is_checked_before_it_runs(command, override, message, tmp_path, capsys):
    pwned = tmp_path / "pwned"
    config_dir, name = COMMANDS[command]
    argv = [override.replace("PWNED", str(pwned))]
    if override.startswith("hydra:"):  # a config file over the command's own
        layer = f"defaults: [{name}, _self_]\n{argv[0][:-1]}, searchpath: ['file://{config_dir}']}}\n"
        (tmp_path / "layer.yaml").write_text(layer)
        argv = ["-cd", str(tmp_path), "-cn", "layer"]
    with pytest.raises(SystemExit) as exit:
        check_built(command, config_dir, name, argv)
    assert exit.value.code == 2
    assert re.match(rf"{command}: {message}", capsys.readouterr().err)
    assert not pwned.exists()


def test_a_sweep_over_what_hydra_builds_is_refused(tmp_path, capsys):
    sweep = tmp_path / "sweep.yaml"
    sweep.write_text(
        "defaults: [train, _self_]\nhydra:\n  searchpath: [file://" + str(CONF_DIR) + "]\n  sweeper:\n    params:\n"
        "      hydra.job_logging.handlers.console.class: logging.StreamHandler,subprocess.Popen\n"
    )
    with pytest.raises(SystemExit):
        check_built("wdss.train", CONF_DIR, "train", ["-cd", str(tmp_path), "-cn", "sweep", "--multirun"])
    assert "hydra.sweeper.params sweeps hydra.job_logging.handlers.console.class" in capsys.readouterr().err


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
        sgd = {"_target_": "torch.optim.SGD", "_partial_": True}
        instantiate(sgd, at="optimizer", lr={"_target_": "torch.save", "f": "x"})
    assert not victim.exists()
    sgd = {"_target_": "torch.optim.SGD", "_partial_": True, "lr": 0.1}
    assert instantiate(sgd, at="optimizer").func is torch.optim.SGD
    with pytest.raises(
        TargetRefused, match=r"^_target_=torch\.optim\.SGD is not on wdss's allowlist: nothing is built"
    ):
        instantiate(sgd)  # a plain mapping says where it is built, or nothing is


def _interpolated(tmp_path: Path, escaped: bool = False) -> str:
    """A string that OmegaConf resolves to a node Hydra then builds: ``torch.save`` writing ``pwned``."""
    text = "${oc.create:{_target_: torch.save, obj: 1, f: '" + str(tmp_path / "pwned") + "'}}"
    return "\\" + text if escaped else text  # escaped: resolved once to the interpolation itself


def test_instantiate_checks_the_config_as_resolved_and_refuses_an_interpolation_left_after(tmp_path):
    upsample = {"_target_": "wdss.nets.upsamplers.baselines.Upsample"}
    with pytest.raises(TargetRefused, match=r"^net\.mode\._target_=torch\.save is not on wdss's allowlist: nothing"):
        instantiate({**upsample, "mode": _interpolated(tmp_path)}, at="net")
    with pytest.raises(InterpolationRefused, match=r"^net\.mode=\$\{oc\.create:.* still holds an interpolation"):
        instantiate({**upsample, "mode": _interpolated(tmp_path, escaped=True)}, at="net")
    assert not (tmp_path / "pwned").exists()


def test_a_kwarg_is_checked_as_instantiate_resolves_it(tmp_path):
    """Hydra merges kwargs into the config and resolves them: a run's tags (anyone who logs to the store sets them)
    passed to the logger would build what an interpolation in them makes."""
    logger = {"_target_": "lightning.pytorch.loggers.MLFlowLogger", "tracking_uri": f"sqlite:///{tmp_path}/m.db"}
    with pytest.raises(TargetRefused, match=r"^logger\.tags\.overrides\._target_=torch\.save is not on"):
        instantiate(logger, at="logger", tags={"overrides": _interpolated(tmp_path)})
    _no_file_but(tmp_path)


@pytest.mark.parametrize(
    "key, target, kind",
    [
        ("net", "wdss.render.render_preset", "network"),
        ("net", "torch.optim.Adam", "network"),
        ("optimizer", "wdss.nets.wdss.network.WDSSNet", "optimizer"),
        ("data.prepare", "wdss.data.SceneDataModule", "data preparer"),
        ("callbacks.ema", "lightning.pytorch.Trainer", "callback"),
        ("hydra.callbacks.x", "lightning.pytorch.callbacks.ModelCheckpoint", "Hydra callback"),
    ],
)
def test_each_slot_builds_only_its_own_kind(key, target, kind):
    node: dict = {"_target_": target}
    for part in reversed(key.split(".")):
        node = {part: node}
    with pytest.raises(
        TargetRefused,
        match=rf"^{re.escape(key)}\._target_={re.escape(target)} is not on wdss's allowlist for "
        rf"{re.escape(key)}, which builds a {kind} \(",
    ):
        check_targets(node)


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


def crafted_checkpoint(tmp_path: Path, net: dict, **hparams) -> Path:
    """A Lightning checkpoint, loadable weights-only, whose stored network config is ``net`` (and ``hparams``)."""
    honest = SuperResolutionModule({"_target_": "wdss.nets.upsamplers.baselines.Upsample"}, flip=False)
    path = tmp_path / "crafted.ckpt"
    torch.save(
        {
            "pytorch-lightning_version": lightning.__version__,
            "state_dict": honest.state_dict(),
            "hyper_parameters": {**honest.hparams, "net": net, **hparams},
        },
        path,
    )
    return path


UPSAMPLE = {"_target_": "wdss.nets.upsamplers.baselines.Upsample", "mode": "bilinear"}
# Checkpoints that pass a walk of their targets as stored: what they build hides in an interpolation, or is
# allowlisted as a callable of another kind (render_preset renders a dataset with Blender wherever out_dir says).
CRAFTED = {
    "interpolated-net": lambda tmp: ({**UPSAMPLE, "mode": _interpolated(tmp)}, {}, r"net\.mode=\$\{oc\.create"),
    "escaped-net": lambda tmp: ({**UPSAMPLE, "mode": _interpolated(tmp, True)}, {}, r"net\.mode=\\\$\{oc\.create"),
    "interpolated-optimizer": lambda tmp: (
        UPSAMPLE,
        {"optimizer": {"_target_": "torch.optim.Adam", "_partial_": True, "lr": _interpolated(tmp)}},
        r"optimizer\.lr=\$\{oc\.create",
    ),
    "interpolated-loss": lambda tmp: (UPSAMPLE, {"loss_weights": {"l1": _interpolated(tmp)}}, r"loss_weights\.l1="),
    "another-kind": lambda tmp: (
        {"_target_": "wdss.render.render_preset", "out_dir": str(tmp / "pwned"), "name": "mini"},
        {},
        r"net\._target_=wdss\.render\.render_preset is not on wdss's allowlist for (hyper_parameters\.)?net, which "
        r"builds a network",
    ),
}


@pytest.mark.parametrize("crafted", CRAFTED)
def test_a_checkpoint_that_hides_what_it_builds_is_refused_before_anything_is_built(crafted, tmp_path):
    net, hparams, message = CRAFTED[crafted](tmp_path)
    ckpt = crafted_checkpoint(tmp_path, net, **hparams)
    with pytest.raises(CheckpointError, match=rf"^checkpoint {ckpt}: hyper_parameters\.{message}"):
        read_checkpoint(ckpt)
    # The module refuses it too, whatever path loads it (a checkpoint's hyper-parameters are its arguments).
    with pytest.raises(TargetRefused, match=rf"^{message}"):
        SuperResolutionModule.load_from_checkpoint(ckpt, map_location="cpu", weights_only=True)
    assert not (tmp_path / "pwned").exists()


def _no_file_but(tmp_path: Path, *kept: Path) -> None:
    found = sorted(p for p in tmp_path.rglob("*") if p not in kept)
    assert not found, found


@pytest.mark.parametrize("crafted", ["interpolated-net", "escaped-net", "another-kind"])
@pytest.mark.parametrize("command", ["eval", "upscale", "export"])
def test_eval_upscale_and_export_refuse_a_crafted_checkpoint_leaving_no_file(crafted, command, tmp_path, monkeypatch):
    from tests.test_export import compose_export
    from tests.test_upscale import FIXTURE, compose_upscale
    from wdss.eval import evaluate
    from wdss.export import export
    from wdss.upscale import upscale

    monkeypatch.setenv("MLFLOW_TRACKING_URI", f"sqlite:///{tmp_path}/mlflow.db")
    net, hparams, message = CRAFTED[crafted](tmp_path)
    ckpt = crafted_checkpoint(tmp_path, net, **hparams)
    if command == "eval":
        cfg = compose_train([f"ckpt_path={ckpt}", "data=fixture"], tmp_path / "eval", name="eval")
    elif command == "upscale":
        cfg = compose_upscale(tmp_path, f"ckpt_path={ckpt}", f"input={FIXTURE}", f"output={tmp_path / 'up'}")
    else:
        cfg = compose_export(tmp_path, f"ckpt_path={ckpt}", "height=48", "width=96")
    with pytest.raises(CheckpointError, match=rf"hyper_parameters\.{message}"):
        {"eval": evaluate, "upscale": upscale, "export": export}[command](cfg)
    _no_file_but(tmp_path, ckpt)


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
    net = {"_target_": "wdss.nets.upsamplers.baselines.Upsample"}
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

    ckpt = crafted_checkpoint(tmp_path, {"_target_": "wdss.nets.upsamplers.baselines.Upsample"})
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


def test_a_checkpoint_with_arguments_under_lightnings_older_keys_is_refused(tmp_path):
    """Lightning merges ``hparams`` (and ``module_arguments``) into the model's arguments too."""
    ckpt = crafted_checkpoint(tmp_path, UPSAMPLE)
    checkpoint = torch.load(ckpt, weights_only=True)
    torch.save({**checkpoint, "hparams": {"lpips": {"backbone": "/etc/passwd", "linear": "/etc/passwd"}}}, ckpt)
    with pytest.raises(CheckpointError, match=rf"^checkpoint {ckpt} holds 'hparams', which wdss.train never writes"):
        read_checkpoint(ckpt)


@pytest.mark.slow
def test_python_m_wdss_eval_refuses_a_hydra_callback_off_the_list_before_hydra_builds_it(tmp_path):
    from tests.test_train import run_module

    ckpt = crafted_checkpoint(tmp_path, UPSAMPLE)
    evil = f"+hydra.callbacks.evil={{_target_: torch.save, obj: 1, f: {tmp_path / 'pwned'}}}"
    done = run_module(tmp_path, "wdss.eval", f"ckpt_path={ckpt}", evil, f"paths.log_dir={tmp_path}/outputs")
    assert done.returncode == 2, done.stderr
    assert done.stderr.startswith("wdss.eval: hydra.callbacks.evil._target_=torch.save is not on wdss's allowlist")
    _no_file_but(tmp_path, ckpt)


def test_the_checkpoint_ckpt_path_last_finds_is_checked_as_any_other(tmp_path, monkeypatch):
    """ckpt_path=last resolves to a last.ckpt in a run folder: that file is read and checked before Lightning
    loads it, as an explicit ckpt_path is."""
    import wdss.train
    from wdss.train import ConfigError, train

    net, hparams, message = CRAFTED["interpolated-net"](tmp_path)
    ckpt = crafted_checkpoint(tmp_path, net, **hparams)
    monkeypatch.setattr(wdss.train, "_resume", lambda cfg: (str(ckpt), "id-a"))
    with pytest.raises(ConfigError, match=rf"ckpt_path=last: checkpoint {ckpt}: .*{message}"):
        train(compose_train(["experiment=smoke", "ckpt_path=last"], tmp_path))
    assert not (tmp_path / "pwned").exists()


@pytest.mark.parametrize("content", [b"not weights", None])
def test_weight_files_named_by_the_config_are_read_weights_only_with_the_key_in_the_error(content, tmp_path):
    from wdss.checkpoint import CheckpointError
    from wdss.nets.comparison.rrdbnet import RRDBNet
    from wdss.training.metrics import LPIPS

    weights = tmp_path / "weights.pth"
    if content is None:
        _payload(tmp_path).rename(weights)  # a pickle of code in a torch archive
    else:
        weights.write_bytes(content)
    with pytest.raises(CheckpointError, match=rf"^model\.net\.weights={weights} (is not a torch|cannot be read)") as e:
        RRDBNet(weights=str(weights))
    assert "weights_only" not in str(e.value)
    with pytest.raises(CheckpointError, match=rf"^loss\.lpips\.backbone={weights} "):
        LPIPS(weights, weights)
    assert not (tmp_path / "pwned").exists()


@pytest.mark.parametrize(
    "saved,message",
    [
        (
            "data:\n  preprocessing:\n    brdf: ${oc.env:HOME}\n",
            r"data\.preprocessing\.brdf=\$\{oc\.env:HOME\} is an interpolation",
        ),
        ("data:\n  preprocessing: [1, 2]\n", r"data\.preprocessing is not a mapping of plain values"),
        ("data:\n  preprocessing:\n    brdf: {_target_: torch.save}\n", r"not a mapping of plain values"),
    ],
)
def test_the_run_config_beside_a_checkpoint_is_read_as_data(saved, message, tmp_path):
    """The preprocessing eval, upscale and export take from <run>/.hydra/config.yaml: plain values or refused."""
    from wdss.checkpoint import training_preprocessing

    ckpt = tmp_path / "run" / "checkpoints" / "last.ckpt"
    ckpt.parent.mkdir(parents=True)
    (tmp_path / "run" / ".hydra").mkdir()
    (tmp_path / "run" / ".hydra" / "config.yaml").write_text("data:\n  preprocessing:\n    brdf: extranet\n")
    assert training_preprocessing(ckpt) == {"brdf": "extranet", "brdf_knee": 0.0}  # a run from before the knee
    (tmp_path / "run" / ".hydra" / "config.yaml").write_text(saved)
    with pytest.raises(CheckpointError, match=message):
        training_preprocessing(ckpt)
