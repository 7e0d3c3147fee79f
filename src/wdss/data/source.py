"""The frame source: what the dataset and the data module read a sequence of frames through, whatever holds it.

Two kinds implement :class:`FrameSource`: :class:`wdss.data.layouts.Sequence` (a folder or zip of EXR files in a
known layout; whole frames decoded, then cut) and :class:`wdss.data.packed.PackedSequence` (a packed store; a window
decodes only the tiles it overlaps). The same frame gives the same values from either (a packed buffer keeps the
dtype of its source, float16 where the EXR channels were half; an EXR one is read as float32).
"""

from __future__ import annotations

from collections.abc import Iterable
from typing import Protocol, runtime_checkable

import numpy as np
import torch

from wdss.data.cache import FrameCache

__all__ = ["FrameSource", "Window"]

Window = tuple[int, int, int, int]  # (y, x, h, w) in the frame's pixels; it may reach beyond the frame


@runtime_checkable
class FrameSource(Protocol):
    """One sequence of frames: its resolutions and buffers, its frames' pixels and its sidecar's facts.

    ``resolutions`` are heights, largest (``hr``) first; ``frames`` the frame numbers at ``hr``; ``sanitized``
    counts the non-finite values replaced by 0 (``sanitize``), per file or frame and buffer.
    """

    name: str
    resolutions: list[int]
    hr: int
    frames: list[int]
    frame_rate: float
    sanitized: dict[str, int]

    def frames_at(self, height: int) -> list[int]:
        """The frames held at ``height``."""
        ...

    def has(self, buffer: str, height: int, frame: int | None = None) -> bool:
        """Whether ``buffer`` is held at ``height`` (for ``frame``; None: the sequence's first frame, or any)."""
        ...

    def shape(self, height: int) -> tuple[int, int]:
        """The ``(H, W)`` of the frames at ``height``."""
        ...

    def read(self, frame: int, height: int, buffers: Iterable[str], *, sanitize: bool = False) -> dict[str, np.ndarray]:
        """The named buffers of one whole frame as float32 ``(C, H, W)`` arrays, the caller's own; a missing buffer
        or frame, or a non-finite value without ``sanitize``, is a SceneError naming it."""
        ...

    def read_window(
        self,
        frame: int,
        height: int,
        buffers: Iterable[str],
        window: Window | None,
        *,
        sanitize: bool = False,
        depth_far: float | None = None,
        depth_range: bool = False,
    ) -> tuple[dict[str, np.ndarray], tuple[float, float] | None]:
        """The ``window`` of the named buffers of one frame (zeros beyond the frame; None: the whole frame), float16
        or float32 as held, and with ``depth_range`` the whole frame's depth range after the ``depth_far`` clamp."""
        ...

    def camera(self, frame: int) -> torch.Tensor | None:
        """The 3x3 camera-to-world rotation of ``frame`` (``sequence.json``), if recorded."""
        ...

    def lr_jitter(self, frame: int) -> tuple[float, float]:
        """Where ``frame``'s native LR pixels were shaded, from their centres (LR pixels, x right, y down)."""
        ...

    def stale(self) -> str | None:
        """Why the frames may no longer be those of the files they were made from, or None."""
        ...

    def use_cache(self, cache: FrameCache | None) -> None:
        """Keep decoded frames in ``cache`` between reads, where decoding whole frames makes that pay."""
        ...
