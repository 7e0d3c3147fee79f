"""Render presets compose as ``python -m wdss.render -cn <name>`` does, inside a running Hydra app as well."""

from __future__ import annotations

import sys

import pytest
import yaml
from hydra import compose, initialize_config_dir
from hydra.core.global_hydra import GlobalHydra

from wdss.paths import CONF_DIR
from wdss.render import sequence
from wdss.render.sequence import preset_settings

PRESETS = sorted(p.stem for p in (CONF_DIR / "render").glob("*.yaml"))


def command_settings(name: str, capsys, monkeypatch) -> dict:
    """What ``python -m wdss.render -cn <name> --cfg job --resolve`` prints, run in this process."""
    from wdss.render.__main__ import main

    monkeypatch.setattr(sys, "argv", ["wdss.render", "-cn", name, "--cfg", "job", "--resolve"])
    try:
        main()
    finally:
        GlobalHydra.instance().clear()
    return yaml.safe_load(capsys.readouterr().out)


@pytest.mark.parametrize("name", PRESETS)
def test_a_preset_has_the_settings_of_the_render_command(name, capsys, monkeypatch):
    expected = command_settings(name, capsys, monkeypatch)
    assert expected["sequences"] and "hydra" not in expected
    assert preset_settings(name) == expected


def test_render_preset_runs_inside_a_running_hydra_app(tmp_path, monkeypatch):
    """wdss.train's DataModule renders its dataset on first use, while the training's Hydra app is running."""
    calls = []
    monkeypatch.setattr(sequence, "render_sequences", lambda out, seqs, **settings: calls.append((out, seqs, settings)))
    with initialize_config_dir(config_dir=str(CONF_DIR), version_base="1.3"):
        sequence.render_preset(tmp_path, "mini")
        # The app's own Hydra is untouched: it still composes its configs.
        assert GlobalHydra.instance().is_initialized() and compose("train").data.prepare.name == "mini"
    [(out, seqs, settings)] = calls
    expected = preset_settings("mini")
    assert out == tmp_path and seqs == expected["sequences"]
    dropped = ("out_dir", "sequences", "preview", "preview_frame")
    assert settings == {k: v for k, v in expected.items() if k not in dropped}
