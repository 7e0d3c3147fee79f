"""Lightning's exponential moving average of the weights, made to test what it validated (``callbacks=ema``).

Lightning's ``EMAWeightAveraging`` validates and checkpoints the averaged weights, and keeps the raw ones in the
checkpoint as ``current_model_state`` so that a resumed fit goes on from them. When ``trainer.test(ckpt_path=...)``
runs after a fit in the same process, the callback still holds its averaged model and loads that raw state into
the module: the test would then measure weights that neither validation nor the checkpoint's ``state_dict``
describe. Outside fitting, this subclass leaves the module with the checkpoint's (averaged) ``state_dict``, as
``wdss.eval`` reads it, and once a fit ends it drops its averaged model, whose validation hooks would otherwise swap
it in for whatever a later ``trainer.validate`` loads.
"""

from __future__ import annotations

from typing import Any

import lightning.pytorch as pl
from lightning.pytorch.callbacks import EMAWeightAveraging as _LightningEMA
from lightning.pytorch.trainer.states import TrainerFn

__all__ = ["EMAWeightAveraging"]


class EMAWeightAveraging(_LightningEMA):
    """``lightning.pytorch.callbacks.EMAWeightAveraging`` whose test, validation and prediction use the average."""

    def on_load_checkpoint(
        self, trainer: pl.Trainer, pl_module: pl.LightningModule, checkpoint: dict[str, Any]
    ) -> None:
        if trainer.state.fn == TrainerFn.FITTING:
            super().on_load_checkpoint(trainer, pl_module, checkpoint)

    def teardown(self, trainer: pl.Trainer, pl_module: pl.LightningModule, stage: str) -> None:
        # on_train_end has copied the average into the module: what the fit leaves is what it checkpointed
        if stage == "fit":
            self._average_model = None
