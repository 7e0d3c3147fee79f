"""Training progress in a log: a plain line per epoch and per test, never a carriage-return bar."""

from __future__ import annotations

import logging
import re
import sys

import lightning as L
import torch
from lightning.pytorch.demos.boring_classes import BoringModel

from wdss.callbacks.progress_bar import LineProgressBar, LogLines, progress_bar, progress_callbacks
from wdss.logfile import teed_output


class LoggingModel(BoringModel):
    def training_step(self, batch, batch_idx):
        out = super().training_step(batch, batch_idx)
        self.log("train/loss", out["loss"], prog_bar=True)
        return out

    def validation_step(self, batch, batch_idx):
        self.log("val/psnr", torch.tensor(30.0 + self.current_epoch), prog_bar=True)


def fit_and_test(bar: LineProgressBar | LogLines, **kwargs) -> L.Trainer:
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
        **kwargs,
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
    assert [type(c) for c in progress_callbacks()] == [LineProgressBar]


def test_under_an_entry_point_what_is_printed_reaches_the_log_file_and_the_console_is_unchanged(tmp_path, capsys):
    """A Hydra job's log file (a file handler on the root logger) gets the plain lines, the metrics and warnings, as
    records of the command; beside a rich bar (a terminal) LogLines writes the same lines to the file only."""
    log = tmp_path / "train.log"
    handler = logging.FileHandler(log)
    handler.setFormatter(logging.Formatter("[%(name)s][%(levelname)s] - %(message)s"))
    logging.getLogger().addHandler(handler)
    try:
        with teed_output("wdss.train"):
            fit_and_test(LineProgressBar())
            print("  test/psnr_2x = 30.5")
            sys.stdout.write("bar 1/3\rbar 2/3\r\x1b[2K\x1b[1mdone\x1b[0m\n")  # a bar redrawn in place
            print("a warning", file=sys.stderr)
        printed = capsys.readouterr()
        assert printed.out.endswith("  test/psnr_2x = 30.5\nbar 1/3\rbar 2/3\r\x1b[2K\x1b[1mdone\x1b[0m\n")
        lines = log.read_text().splitlines()
        assert lines[-3:] == [
            "[wdss.train][INFO] -   test/psnr_2x = 30.5",
            "[wdss.train][INFO] - done",
            "[wdss.train][WARNING] - a warning",
        ]
        epochs = [line for line in lines if line.startswith("[wdss.train][INFO] - epoch ")]
        assert len(epochs) == 2 and epochs[1].endswith("val/psnr=31")
        [test] = [line for line in printed.out.splitlines() if line.startswith("test: ")]
        assert f"[wdss.train][INFO] - {test}" in lines  # as printed

        log.write_text("")
        with teed_output("wdss.train"):
            fit_and_test(LogLines(), enable_progress_bar=False)
        assert "epoch " not in capsys.readouterr().out
        lines = [line for line in log.read_text().splitlines() if line.startswith("[wdss.train]")]
        assert [line.split(":")[0] for line in lines] == [
            "[wdss.train][INFO] - epoch 1/2",
            "[wdss.train][INFO] - epoch 2/2",
            "[wdss.train][INFO] - test",
        ]
    finally:
        logging.getLogger().removeHandler(handler)
        handler.close()


def test_lightnings_chatter_is_dropped_and_its_warnings_pass(caplog, recwarn):
    """The advertisement, the absent accelerators and the limits of 1.0 go; a warning from the same logger stays."""
    from lightning.pytorch.utilities.rank_zero import rank_zero_info, rank_zero_warn

    from wdss.callbacks.progress_bar import model_line, quiet_lightning

    quiet_lightning()
    quiet_lightning()  # twice: one filter
    log = logging.getLogger("lightning.pytorch.utilities.rank_zero")
    assert sum(type(f).__name__ == "_Chatter" for f in log.filters) == 1
    with caplog.at_level(logging.INFO, logger="lightning.pytorch.utilities.rank_zero"):
        rank_zero_info("💡 Tip: For seamless cloud logging, try installing litlogger")
        rank_zero_info("GPU available: False, used: False")
        rank_zero_info("`Trainer(limit_train_batches=1.0)` was configured so 100% of the batches will be used..")
        rank_zero_info("Restoring states from the checkpoint path at x.ckpt")
    assert "Tip" not in caplog.text and "GPU available" not in caplog.text and "limit_train" not in caplog.text
    assert "Restoring states" in caplog.text
    import warnings

    warnings.warn("`isinstance(treespec, LeafSpec)` is deprecated, use `isinstance(treespec, TreeSpec)`", stacklevel=1)
    rank_zero_warn("a real problem")
    assert [str(w.message) for w in recwarn] == ["a real problem"]
    net = torch.nn.Linear(3, 2)
    net.bias.requires_grad_(False)
    assert model_line(net) == "model: Linear, 8 parameters (6 trainable)"
