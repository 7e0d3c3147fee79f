"""The entry points' error contract (wdss.errors): input a user can fix is one line on stderr and exit status 2;
anything else keeps its traceback."""

from __future__ import annotations

import logging

import pytest

from wdss.checkpoint import CheckpointError
from wdss.config.targets import TargetRefused
from wdss.data.exr import ExrError
from wdss.data.layouts import SceneError
from wdss.errors import ConfigError, UserError, one_line_errors
from wdss.export import ExportError
from wdss.upscale import UpscaleError


@pytest.mark.parametrize(
    "error", [ConfigError, SceneError, ExrError, CheckpointError, TargetRefused, UpscaleError, ExportError]
)
def test_every_user_error_is_one_line_and_status_2(capsys, error):
    @one_line_errors("wdss.thing")
    def main(key: str) -> None:
        raise error(f"{key}: 'mnii' is not a dataset")

    with pytest.raises(SystemExit) as exit_:
        main("data.root")
    assert exit_.value.code == 2 and issubclass(error, UserError)
    out, err = capsys.readouterr()
    assert out == "" and err == "wdss.thing: data.root: 'mnii' is not a dataset\n"


def test_a_bug_keeps_its_traceback_and_a_result_passes_through():
    @one_line_errors("wdss.thing")
    def main(fail: bool) -> float:
        if fail:
            raise KeyError("a bug")
        return 1.5

    assert main(False) == 1.5
    with pytest.raises(KeyError, match="a bug"):
        main(True)


def test_what_an_entry_point_printed_and_how_it_ended_are_in_the_job_log_file(tmp_path, capsys):
    @one_line_errors("wdss.thing")
    def main(error: Exception) -> None:
        print("epoch 1/2: 3 batches in 1s")
        raise error

    log = tmp_path / "thing.log"  # as Hydra's job logging: a file handler on the root logger
    handler = logging.FileHandler(log)
    logging.getLogger().addHandler(handler)
    try:
        with pytest.raises(SystemExit):
            main(ConfigError("data.root: 'mnii' is not a dataset"))
        with pytest.raises(KeyError):
            main(KeyError("a bug"))
    finally:
        logging.getLogger().removeHandler(handler)
        handler.close()
    assert capsys.readouterr().err == "wdss.thing: data.root: 'mnii' is not a dataset\n"  # the console as before
    text = log.read_text()
    assert text.startswith("epoch 1/2: 3 batches in 1s\nwdss.thing: data.root: 'mnii' is not a dataset\nepoch 1/2")
    assert "Traceback (most recent call last)" in text and text.endswith("KeyError: 'a bug'\n")


@pytest.mark.parametrize(
    ("argv", "line"),
    [
        (["data.rooot=x"], "wdss.train: unknown config key data.rooot (did you mean data.root?)"),
        (["data=tiny", "trainer.max_epoch=3"], "wdss.train: unknown config key trainer.max_epoch (did you mean "),
        (["dtaa.root=x"], "wdss.train: unknown config key dtaa (did you mean data?)"),
        (["model.net.zzzz=1"], "wdss.train: unknown config key model.net.zzzz (model.net has: _target_, "),
    ],
)
def test_a_mistyped_key_names_the_closest_keys_not_plus_key(capsys, argv, line):
    from wdss.errors import check_overrides
    from wdss.paths import CONF_DIR

    with pytest.raises(SystemExit) as exit_:
        check_overrides("wdss.train", CONF_DIR, "train", argv)
    assert exit_.value.code == 2
    err = capsys.readouterr().err
    assert err.startswith(line) and err.count("\n") == 1 and "+" not in err


def test_valid_overrides_and_hydra_flags_pass_to_hydra(capsys):
    from wdss.errors import check_overrides
    from wdss.paths import CONF_DIR

    check_overrides("wdss.train", CONF_DIR, "train", ["data=tiny", "trainer.max_epochs=3", "+extra=1"])
    check_overrides("wdss.train", CONF_DIR, "train", ["-m", "data.rooot=1,2"])  # a sweep: Hydra's to report
    check_overrides("wdss.render", CONF_DIR / "render", "default", ["-cn", "mini", "frames=3"])
    check_overrides("wdss.train", CONF_DIR, "train", ["data=nonexistent"])  # Hydra lists the group's options
    assert capsys.readouterr().err == ""


def test_a_missing_checkpoint_names_the_checkpoints_beside_it(tmp_path):
    from wdss.checkpoint import read_checkpoint

    run = tmp_path / "run"
    (run / "checkpoints").mkdir(parents=True)
    for name in ("epoch015.ckpt", "last.ckpt"):
        (run / "checkpoints" / name).write_bytes(b"")
    with pytest.raises(
        CheckpointError, match=r"epoch16.ckpt is not a file; .*checkpoints holds epoch015.ckpt, last.ckpt$"
    ):
        read_checkpoint(run / "checkpoints" / "epoch16.ckpt")
    with pytest.raises(CheckpointError, match=r"is not a file; .*checkpoints holds epoch015.ckpt, last.ckpt$"):
        read_checkpoint(run)  # a run folder given for its checkpoint
    with pytest.raises(CheckpointError, match=r"nowhere.ckpt is not a file$"):
        read_checkpoint(tmp_path / "nowhere.ckpt")
