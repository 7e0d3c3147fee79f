"""Training progress in a log: a plain line per epoch and per test, never a carriage-return bar."""

from __future__ import annotations

import re

import lightning as L
import torch
from lightning.pytorch.demos.boring_classes import BoringModel

from wdss.progress_bar import LineProgressBar, progress_bar


class LoggingModel(BoringModel):
    def training_step(self, batch, batch_idx):
        out = super().training_step(batch, batch_idx)
        self.log("train/loss", out["loss"], prog_bar=True)
        return out

    def validation_step(self, batch, batch_idx):
        self.log("val/psnr", torch.tensor(30.0 + self.current_epoch), prog_bar=True)


def fit_and_test(bar: LineProgressBar) -> list[str]:
    trainer = L.Trainer(
        max_epochs=2,
        limit_train_batches=3,
        limit_val_batches=2,
        limit_test_batches=2,
        callbacks=[bar],
        logger=False,
        enable_checkpointing=False,
        enable_model_summary=False,
        num_sanity_val_steps=0,
    )
    model = LoggingModel()
    trainer.fit(model)
    trainer.test(model, verbose=False)
    return trainer


def test_a_log_gets_a_line_per_epoch_with_its_metrics_and_eta_and_one_per_test(capsys):
    fit_and_test(LineProgressBar())
    lines = capsys.readouterr().out.splitlines()
    assert "\r" not in "".join(lines)
    epochs = [line for line in lines if line.startswith("epoch ")]
    assert len(epochs) == 2
    assert re.fullmatch(r"epoch 1/2: 3 batches in \d+s, ETA \d+s, train/loss=[-\d.e]+ val/psnr=30", epochs[0])
    assert epochs[1].startswith("epoch 2/2: 3 batches in ") and epochs[1].endswith("val/psnr=31")
    assert re.fullmatch(r"test: 2 batches in \d+s", lines[-1])


def test_a_long_loop_gets_a_line_every_every_s_seconds(capsys):
    fit_and_test(LineProgressBar(every_s=0))
    lines = capsys.readouterr().out.splitlines()
    assert [line.split(" (")[0] for line in lines if line.startswith("epoch 1/2: batch")] == [
        "epoch 1/2: batch 1/3",
        "epoch 1/2: batch 2/3",
        "epoch 1/2: batch 3/3",
    ]
    assert sum(line.startswith("epoch 2/2 validation: batch") for line in lines) == 2
    assert [line.split(" (")[0] for line in lines if line.startswith("test: batch")] == [
        "test: batch 1/2",
        "test: batch 2/2",
    ]


def test_off_a_terminal_or_in_a_sweep_the_bar_is_plain_lines():
    assert isinstance(progress_bar(), LineProgressBar)  # pytest captures stdout: not a terminal
    assert isinstance(progress_bar(multirun=True), LineProgressBar)
