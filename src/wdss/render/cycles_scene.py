"""What a sequence renders: a scene in Blender with fixed Cycles settings that can be put at a frame.

:class:`wdss.render.blender.BlenderScene` (procedural) and :class:`wdss.render.scene_file.FileScene` (a scene
file) differ in how they are built and how they reach a frame (:meth:`CyclesScene.set_frame`); rendering is one.
Importing this module does not need Blender; rendering does (the ``render`` extra).
"""

from __future__ import annotations

from typing import Any

import numpy as np

__all__ = ["CyclesScene"]


class CyclesScene:
    """A Blender scene (``scene``) rendered with ``samples`` per pixel, ``denoise`` and ``filter_width``."""

    scene: Any
    samples: int
    denoise: bool
    filter_width: float

    def set_frame(self, frame: int) -> None:
        """Put the scene at ``frame`` of the sequence (0: the history of frame 1)."""
        raise NotImplementedError

    def render(
        self,
        frame: int,
        width: int,
        height: int,
        *,
        samples: int | None = None,
        jitter: tuple[float, float] | None = None,
    ) -> dict[str, np.ndarray]:
        """Render ``frame`` at ``width x height`` (sub-pixel ``jitter``: see
        :func:`wdss.render.blender.render_passes`); the passes as ``(C, H, W)`` float32 arrays, rows top-down."""
        from wdss.render.blender import render_passes

        self.set_frame(frame)
        return render_passes(
            self.scene,
            width,
            height,
            samples=samples or self.samples,
            denoise=self.denoise,
            filter_width=self.filter_width,
            jitter=jitter,
        )
