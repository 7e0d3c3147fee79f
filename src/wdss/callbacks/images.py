"""The pictures a run logs to MLflow: validation panels every few epochs and the first test frames of each scale.

:class:`ValidationPanels` logs, for the first validation batch of every ``model.image_every_n_epochs``-th epoch,
``images/val_epochNNN.png`` (:func:`comparison_panel`: LR | prediction | target | error x4, captioned as the eval
videos are) and, for a network that predicts subbands, ``images/subbands_epochNNN.png`` (:func:`subband_panel`).
:class:`FirstTestFrames` logs the first three frames of each test scale's first sequence, tone-mapped as the metrics see
them, as ``test/pred_<s>x.png``, ``test/pred_<s>x_t1.png``, ``test/pred_<s>x_t2.png`` and the matching
``test/target_*``: the report's qualitative figure. Both log nothing where the trainer has no MLflow run
(:func:`~wdss.tracking.logged_run.logged_run`).
"""

from __future__ import annotations

from collections.abc import Mapping
from typing import Any

import lightning as L
import numpy as np
import torch
from torch import Tensor

from wdss.ops.tonemap import ToneMap
from wdss.tracking.logged_run import logged_run
from wdss.video import labelled

__all__ = ["SUBBAND_LABELS", "FirstTestFrames", "ValidationPanels", "comparison_panel", "subband_panel"]


def comparison_panel(batch: Mapping[str, Any], out: Mapping[str, Tensor | None], tone: ToneMap) -> np.ndarray:
    """LR (nearest-upsampled) | prediction | target | error x4, tone-mapped, as an (H, 4W, 3) uint8 array."""
    reference = batch["target"][:1].float()
    target = tone(reference, reference)
    shown = out.get("display")
    pred = shown[:1].detach().float() if shown is not None else tone(out["color"][:1].detach().float(), reference)
    lr_source = batch.get("lr_color")
    if lr_source is None and "lr" in batch:
        lr_brdf = torch.nn.functional.interpolate(batch["brdf"][:1], size=batch["lr"].shape[-2:], mode="nearest")
        lr_source = batch["lr"][:1] * lr_brdf
        if "emission" in batch:
            lr_source = lr_source + torch.nn.functional.interpolate(
                batch["emission"][:1], size=lr_source.shape[-2:], mode="nearest"
            )
    lr = (
        torch.zeros_like(target)
        if lr_source is None
        else tone(
            torch.nn.functional.interpolate(lr_source[:1].float(), size=target.shape[-2:], mode="nearest"), reference
        )
    )
    error = ((pred - target).abs() * 4).clamp(0, 1)
    row = torch.cat([lr, pred, target, error], dim=-1)[0]
    return (row.permute(1, 2, 0).cpu().numpy() * 255).round().astype(np.uint8)


SUBBAND_LABELS = ("LL (own range)", "LH", "HL", "HH (0.5 = zero)")


def subband_panel(coefficients: Tensor) -> np.ndarray:
    """The four subbands of the first image, side by side, each scaled to its own range (uint8): LL from 0 to its
    largest magnitude, the detail bands around grey 0.5 for zero (:data:`SUBBAND_LABELS`)."""
    bands = coefficients.detach().float().view(4, -1, *coefficients.shape[-2:])[:, :3]
    tiles = []
    for index, band in enumerate(bands):
        band = band.mean(0)
        if index == 0:
            band = band / band.abs().max().clamp_min(1e-8)
        else:
            band = 0.5 + band / (2 * band.abs().max().clamp_min(1e-8))
        tiles.append(band.clamp(0, 1))
    image = torch.cat(tiles, dim=-1)
    return (image.cpu().numpy() * 255).round().astype(np.uint8)


class ValidationPanels(L.Callback):
    """Log the comparison and subband panels of the first validation batch, every ``image_every_n_epochs`` epochs
    (the module's hyper-parameter; 0: never).

    Needs the module's ``validation_step`` to return its outputs (``color`` or ``display``, and ``coefficients``
    where the network predicts subbands) and the module's ``tone``.
    """

    def on_validation_batch_end(
        self, trainer: L.Trainer, pl_module: Any, outputs: Any, batch: Any, batch_idx: int, dataloader_idx: int = 0
    ) -> None:
        every = pl_module.hparams.get("image_every_n_epochs", 1)
        if batch_idx != 0 or not every or trainer.current_epoch % every or not outputs:
            return
        run = logged_run(trainer)
        if run is None:
            return
        epoch = f"{trainer.current_epoch:03d}"
        panel = labelled(comparison_panel(batch, outputs, pl_module.tone))
        run.client.log_image(run.run_id, panel, artifact_file=f"images/val_epoch{epoch}.png")
        coefficients = outputs.get("coefficients")
        if coefficients is not None:
            subbands = labelled(subband_panel(coefficients[0]), SUBBAND_LABELS)
            run.client.log_image(run.run_id, subbands, artifact_file=f"images/subbands_epoch{epoch}.png")


class FirstTestFrames(L.Callback):
    """Log the first three frames of each test scale's first sequence, predicted and target, tone-mapped.

    Needs the module's ``test_step`` to return ``shown`` and ``shown_target`` (the tone-mapped prediction and
    target, ``(N, 3, H, W)`` in [0, 1]) and the frames in order, as the test loaders give them.
    """

    FRAMES = 3

    def __init__(self) -> None:
        self._shown: dict[str, tuple[str, int]] = {}  # scale label -> its first sequence, frames logged

    def on_test_epoch_start(self, trainer: L.Trainer, pl_module: Any) -> None:
        self._shown = {}

    def on_test_batch_end(
        self, trainer: L.Trainer, pl_module: Any, outputs: Any, batch: Any, batch_idx: int, dataloader_idx: int = 0
    ) -> None:
        if not outputs or "shown" not in outputs or "shown_target" not in outputs:
            return
        run = logged_run(trainer)
        if run is None:
            return
        label = f"{float(batch['scale'][0]):g}x"
        for index, sequence in enumerate(batch["sequence"]):
            first, logged = self._shown.setdefault(label, (sequence, 0))
            if sequence != first or logged >= self.FRAMES:
                continue
            suffix = f"_t{logged}" if logged else ""
            for kind, images in (("pred", outputs["shown"]), ("target", outputs["shown_target"])):
                image = _uint8(images[index])
                run.client.log_image(run.run_id, image, artifact_file=f"test/{kind}_{label}{suffix}.png")
            self._shown[label] = (first, logged + 1)


def _uint8(image: Tensor) -> np.ndarray:
    """A ``(3, H, W)`` image in [0, 1] as an ``(H, W, 3)`` uint8 array."""
    return (image.detach().float().permute(1, 2, 0).cpu().numpy() * 255).round().astype(np.uint8)
