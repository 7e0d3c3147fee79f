"""python -m wdss.data.check: what a folder of frames holds and what a model would lack, before training."""

from __future__ import annotations

import shutil

from wdss.data.check import check_sequence, main
from wdss.data.layouts import Sequence
from wdss.paths import PROJECT_ROOT

FIXTURE = PROJECT_ROOT / "tests" / "fixtures" / "rendered"


def test_the_committed_render_is_described_and_readable(capsys):
    assert main([str(FIXTURE), "--scales", "2", "3", "4"]) == 0
    out = capsys.readouterr().out
    assert "fixture_000: layout unreal; HR 96x48, 5 frames" in out
    assert "24P (LR 2x): 5 frames; color, base_color, depth, normal" in out
    assert "cameras for 5/5 frames; LR jitter none" in out
    assert "median luminance" in out and "to middle grey 0.18" in out
    assert "scale 3: native LR 16P" in out and "1 sequence(s) readable" in out


def test_what_a_model_reads_and_the_data_lacks_is_named_with_status_2(tmp_path, capsys):
    folder = tmp_path / "mine" / "seq"
    shutil.copytree(FIXTURE / "fixture_000", folder)
    for lr in folder.glob("24P/BaseColorDepth.*.exr"):
        lr.unlink()  # the native 2x folder lacks base colour and depth
    scene = Sequence(folder)
    needs = {"hr": {"color", "base_color", "emission"}, "lr": {"color", "base_color"}}
    lines, problems = check_sequence(scene, [2.0, 3.0, 5.0], needs)
    assert problems == [
        "seq: the model reads LR base_color at scale 2, which 24P lacks (data.lr_source=point reads it from HR)",
        "seq: 96x48 is not divisible by scale 5",
    ]
    assert "  scale 5: no native LR folder; LR point-sampled from HR (data.lr_source=auto)" in lines
    assert main([str(tmp_path / "mine"), "--scales", "5"]) == 2
    assert "seq: 96x48 is not divisible by scale 5" in capsys.readouterr().err


def test_a_missing_folder_is_one_line(tmp_path, capsys):
    assert main([str(tmp_path / "nowhere")]) == 2
    assert capsys.readouterr().err == f"wdss.data.check: {tmp_path / 'nowhere'} is not a folder\n"
