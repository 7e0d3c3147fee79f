"""Test sequences as video: super-resolution for real-time rendering is judged in motion.

The panels (LR nearest-upsampled | prediction | target | error x4, tone-mapped as the metrics see them), labelled
(:func:`labelled`), become ``<sequence>_<s>x.mp4`` (:class:`Mp4Writer`, H.264 through PyAV, which ships its own
FFmpeg, at the sequence's frame rate) and ``<sequence>_<s>x_crop.gif`` (:func:`write_gif`: the centre squares that the
report's qualitative figure shows, enlarged, which the MLflow UI shows inline). The eval and train callback that
writes and logs them per test sequence is :class:`wdss.callbacks.videos.SequenceVideos`; ``wdss.upscale`` writes its
MP4 with the same writer.

A short sequence plays too fast to watch (13 frames at 30 fps: 0.43 s), so every MP4 keeps the true frame rate and
repeats the whole sequence until it lasts at least :data:`MIN_SECONDS` (:func:`loops`); the GIF loops by itself.
"""

from __future__ import annotations

import math
from fractions import Fraction
from pathlib import Path
from typing import Any

import numpy as np

__all__ = [
    "CROP",
    "LABELS",
    "MIN_SECONDS",
    "Mp4Writer",
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
