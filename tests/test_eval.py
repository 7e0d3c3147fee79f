"""wdss.eval preprocesses as the checkpoint's training run did (the end-to-end eval tests are in test_train.py)."""

from __future__ import annotations

from omegaconf import OmegaConf

import wdss.eval as wdss_eval


def _run_with_checkpoint(tmp_path, config: str):
    run = tmp_path / "run"
    (run / ".hydra").mkdir(parents=True)
    (run / ".hydra" / "config.yaml").write_text(config)
    (run / "checkpoints").mkdir()
    return run / "checkpoints" / "last.ckpt"


def _defaults():
    return OmegaConf.create({"data": {"preprocessing": {"brdf_knee": 0.1, "color_max": None, "depth_far": 100.0}}})


def test_eval_demodulates_as_the_training_run_did(tmp_path):
    # A run from before the knee: its model was trained on the hard switch, whatever the default is now.
    ckpt = _run_with_checkpoint(tmp_path, "data:\n  preprocessing:\n    color_max: 10.0\n")
    cfg = _defaults()
    wdss_eval._as_trained(cfg, ckpt)
    assert cfg.data.preprocessing.brdf_knee == 0.0 and cfg.data.preprocessing.color_max == 10.0
    assert cfg.data.preprocessing.depth_far == 100.0  # not in the run's config: the current default


def test_eval_keeps_what_its_command_line_sets(tmp_path, monkeypatch):
    ckpt = _run_with_checkpoint(tmp_path, "data:\n  preprocessing:\n    color_max: 10.0\n    brdf_knee: 0.0\n")
    monkeypatch.setattr(wdss_eval, "_command_line_keys", lambda: {"data.preprocessing.brdf_knee"})
    cfg = _defaults()
    wdss_eval._as_trained(cfg, ckpt)
    assert cfg.data.preprocessing.brdf_knee == 0.1 and cfg.data.preprocessing.color_max == 10.0


def test_eval_of_a_checkpoint_outside_a_run_folder_uses_the_config(tmp_path):
    cfg = _defaults()
    wdss_eval._as_trained(cfg, tmp_path / "model.ckpt")
    assert cfg == _defaults()


def test_a_malformed_run_id_beside_a_checkpoint_is_unknown_not_an_abort(tmp_path, capsys):
    """``mlflow_run_id`` is a file anyone can edit: only an MLflow run id is ever passed to the store."""
    from wdss.eval import training_run_id

    ckpt = tmp_path / "run" / "checkpoints" / "last.ckpt"
    ckpt.parent.mkdir(parents=True)
    ckpt.write_bytes(b"")
    assert training_run_id(ckpt) is None  # no file: unknown, silently
    for malformed in ("../../etc/passwd", "run id with spaces", "ABCDEF" * 6):
        (tmp_path / "run" / "mlflow_run_id").write_text(malformed)
        assert training_run_id(ckpt) is None
        assert "holds no MLflow run id" in capsys.readouterr().out
    (tmp_path / "run" / "mlflow_run_id").write_text("0123456789abcdef0123456789abcdef\n")
    assert training_run_id(ckpt) == "0123456789abcdef0123456789abcdef"
