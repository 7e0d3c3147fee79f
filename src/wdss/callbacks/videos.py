"""Test sequences as video, logged to the run: :class:`SequenceVideos` (``video=true`` of ``wdss.eval`` and
``wdss.train``) writes, per test sequence and scale, an MP4 and a cropped GIF (:mod:`wdss.video` writes them) and
logs both as artifacts of the trainer's MLflow run under ``videos/``."""

from __future__ import annotations

from pathlib import Path
from typing import Any

import lightning as L
import numpy as np
from torch import Tensor

from wdss.callbacks.images import comparison_panel
from wdss.data.layouts import DEFAULT_FRAME_RATE
from wdss.tracking.logged_run import logged_run
from wdss.video import CROP, LABELS, Mp4Writer, centre_box, labelled, write_gif

__all__ = ["SequenceVideos"]


class SequenceVideos(L.Callback):
    """Write an MP4 and a cropped GIF of every test sequence at every scale into ``out_dir`` and log them.

    Needs the module's ``test_step`` to return ``shown`` (the tone-mapped prediction) and frames in order,
    sequence after sequence, as the test loaders give them.
    """

    def __init__(self, out_dir: str | Path, crop: int = CROP, enlarge: int = 2) -> None:
        self.out_dir = Path(out_dir)
        self.crop, self.enlarge = crop, enlarge
        self._key: str | None = None
        self._writer: Mp4Writer | None = None
        self._fps = DEFAULT_FRAME_RATE
        self._crops: list[np.ndarray] = []

    def on_test_batch_end(
        self, trainer: L.Trainer, pl_module: Any, outputs: Any, batch: Any, batch_idx: int, dataloader_idx: int = 0
    ) -> None:
        if not outputs or "shown" not in outputs:
            return
        label = f"{float(batch['scale'][0]):g}x"
        for index, sequence in enumerate(batch["sequence"]):
            key = f"{sequence}_{label}"
            if key != self._key:
                self._finish(trainer)
                self._start(key, self._frame_rate(trainer, dataloader_idx, sequence))
            sample = {k: v[index : index + 1] for k, v in batch.items() if isinstance(v, Tensor) and v.ndim == 4}
            panel = comparison_panel(sample, {"display": outputs["shown"][index : index + 1]}, pl_module.tone)
            self._writer.write(labelled(panel))
            self._crops.append(self._crop(panel))

    def on_test_epoch_end(self, trainer: L.Trainer, pl_module: Any) -> None:
        self._finish(trainer)

    def on_exception(self, trainer: L.Trainer, pl_module: Any, exception: BaseException) -> None:
        if self._writer is not None:  # close the file; a partial video is not logged
            self._writer.close()
        self._writer, self._key, self._crops = None, None, []

    @staticmethod
    def _frame_rate(trainer: L.Trainer, dataloader_idx: int, sequence: str) -> float:
        datasets = getattr(getattr(trainer, "datamodule", None), "datasets", {}).get("test", [])
        if dataloader_idx < len(datasets):
            for seq in datasets[dataloader_idx].sequences:
                if seq.name == sequence:
                    return seq.frame_rate
        return DEFAULT_FRAME_RATE

    def _start(self, key: str, fps: float) -> None:
        self.out_dir.mkdir(parents=True, exist_ok=True)
        self._key, self._fps, self._crops = key, fps, []
        self._writer = Mp4Writer(self.out_dir / f"{key}.mp4", fps)

    def _crop(self, panel: np.ndarray) -> np.ndarray:
        """The centre square of each of the four tiles, side by side, enlarged (nearest) and labelled."""
        tile = panel.shape[1] // len(LABELS)
        top, left, side = centre_box(panel.shape[0], tile, self.crop)
        tiles = [panel[top : top + side, i * tile + left : i * tile + left + side] for i in range(len(LABELS))]
        crops = np.concatenate(tiles, axis=1).repeat(self.enlarge, axis=0).repeat(self.enlarge, axis=1)
        return labelled(crops)

    def _finish(self, trainer: L.Trainer) -> None:
        if self._writer is None:
            return
        self._writer.close()
        gif = self.out_dir / f"{self._key}_crop.gif"
        write_gif(self._crops, gif, self._fps)
        run = logged_run(trainer)
        if run is not None:
            for path in (self._writer.path, gif):
                run.client.log_artifact(run.run_id, str(path), "videos")
        self._writer, self._key, self._crops = None, None, []
