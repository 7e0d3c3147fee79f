"""Test sequences as video: super-resolution for real-time rendering is judged in motion.

:class:`SequenceVideos` (``video=true`` of ``wdss.eval`` and ``wdss.train``) writes, per test sequence and scale,
``<sequence>_<s>x.mp4``: LR (nearest-upsampled) | prediction | target | error x4, tone-mapped as the metrics see
them (:func:`wdss.callbacks.images.comparison_panel`), labelled, at the sequence's frame rate, H.264 through PyAV
(which ships its own FFmpeg); and ``<sequence>_<s>x_crop.gif``: the same four tiles cropped to the centre
square that the report's qualitative figure shows, enlarged, which the MLflow UI shows inline. Both are logged as
artifacts of the run under ``videos/``.

A short sequence plays too fast to watch (13 frames at 30 fps: 0.43 s), so every MP4 (:class:`Mp4Writer`, also
``wdss.upscale``'s) keeps the true frame rate and repeats the whole sequence until it lasts at least
:data:`MIN_SECONDS` (:func:`loops`); the GIF loops by itself.
"""

from __future__ import annotations

import math
from fractions import Fraction
from pathlib import Path
from typing import Any

import lightning as L
import numpy as np
from torch import Tensor

from wdss.data.layouts import DEFAULT_FRAME_RATE
from wdss.tracking.logged_run import logged_run

__all__ = [
    "CROP",
    "LABELS",
    "MIN_SECONDS",
    "Mp4Writer",
    "SequenceVideos",
    "centre_box",
    "labelled",
    "loops",
    "write_gif",
]

LABELS = ("LR (nearest)", "prediction", "target", "error x4")
CROP = 96  # side of the centre crop (high-resolution pixels), also the report's qualitative figure's
MIN_SECONDS = 3.0  # an MP4 shorter than this repeats its sequence until it lasts this long


def loops(frames: int, fps: float, min_seconds: float = MIN_SECONDS) -> int:
    """How many times a sequence of ``frames`` plays, whole, in a video that lasts at least ``min_seconds``."""
    return max(1, math.ceil(min_seconds * fps / frames)) if frames else 1


def centre_box(height: int, width: int, size: int = CROP) -> tuple[int, int, int]:
    """``(top, left, side)`` of the centred square of at most ``size`` pixels."""
    side = min(size, height, width)
    return (height - side) // 2, (width - side) // 2, side


def labelled(panel: np.ndarray, labels: tuple[str, ...] = LABELS, strip: int = 14) -> np.ndarray:
    """``panel`` (H, W, 3) uint8 of ``len(labels)`` equal tiles side by side under a black strip naming each."""
    from PIL import Image, ImageDraw

    height, width = panel.shape[:2]
    image = Image.new("RGB", (width, height + strip))
    image.paste(Image.fromarray(panel), (0, strip))
    draw = ImageDraw.Draw(image)
    tile = width // len(labels)
    for index, text in enumerate(labels):
        draw.text((index * tile + 3, 1), text, fill=(255, 255, 255))
    return np.asarray(image)


class Mp4Writer:
    """An H.264 MP4 (yuv420p, CRF 18) written frame by frame; odd sizes gain a copy of the last row or column
    (4:2:0 chroma needs even sizes).

    A sequence shorter than ``min_seconds`` plays :func:`loops` times: its encoded packets are kept (a few MB, never
    the frames) and muxed again at ``close``, shifted in time, each copy starting on the sequence's keyframe.
    """

    def __init__(self, path: str | Path, fps: float, min_seconds: float = MIN_SECONDS) -> None:
        import av

        self.path = Path(path)
        self._container = av.open(str(self.path), mode="w")
        self._rate = Fraction(fps).limit_denominator(1001)
        self._stream = self._container.add_stream("libx264", rate=self._rate)
        self._stream.pix_fmt = "yuv420p"
        self._stream.options = {"crf": "18"}
        self.min_seconds = min_seconds
        self.frames = 0  # of the sequence, once
        self.loops = 1  # how many times it plays, known at close
        self._packets: list[tuple[bytes, int, int, bool, Fraction]] | None = [] if min_seconds > 0 else None

    def _mux(self, packets: list[Any]) -> None:
        if self._packets is not None:  # copied first: muxing takes the packet's data
            self._packets += [(bytes(p), p.pts, p.dts, p.is_keyframe, p.time_base) for p in packets]
        self._container.mux(packets)

    def write(self, rgb: np.ndarray) -> None:
        import av

        height, width = rgb.shape[:2]
        rgb = np.pad(rgb, ((0, height % 2), (0, width % 2), (0, 0)), mode="edge")
        if self.frames == 0:
            self._stream.height, self._stream.width = rgb.shape[:2]
        frame = av.VideoFrame.from_ndarray(np.ascontiguousarray(rgb), format="rgb24")
        self._mux(self._stream.encode(frame))
        self.frames += 1
        if self.frames >= self.min_seconds * self._rate:  # long enough as it is: nothing to repeat
            self._packets = None

    def close(self) -> None:
        import av

        self._mux(self._stream.encode())  # flush the encoder's delayed frames
        if self._packets:
            self.loops = loops(self.frames, self._rate, self.min_seconds)
            for copy in range(1, self.loops):
                for data, pts, dts, keyframe, time_base in self._packets:
                    shift = round(copy * self.frames / self._rate / time_base)  # the sequence's length, in ticks
                    packet = av.Packet(data)
                    packet.pts, packet.dts, packet.time_base = pts + shift, dts + shift, time_base
                    packet.is_keyframe, packet.stream = keyframe, self._stream
                    self._container.mux(packet)
        self._packets = None
        self._container.close()


def write_gif(frames: list[np.ndarray], path: str | Path, fps: float) -> None:
    """An animated GIF that loops, ``fps`` frames per second (GIF counts in 10 ms steps)."""
    from PIL import Image

    images = [Image.fromarray(frame) for frame in frames]
    images[0].save(path, save_all=True, append_images=images[1:], duration=int(round(1000 / fps, -1)), loop=0)


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
        from wdss.callbacks.images import comparison_panel  # imported here: that module imports this one

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
