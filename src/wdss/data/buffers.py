"""The named per-pixel buffers a frame holds, and their channel counts: what readers load and the batch stacks.

``color`` 3 (linear HDR radiance), ``base_color`` 3, ``depth`` 1, ``normal`` 3 (world space), ``specular`` 1,
``metallic`` 1, ``roughness`` 1, ``nov`` 1, ``motion`` 2 (high-resolution pixels, current minus previous screen
position, y up), ``emission`` 3 (optional: the emitted radiance of directly visible surfaces, part of ``color``).
Where each lives in a scene's files is its layout's business (:mod:`wdss.data.layouts`).
"""

from __future__ import annotations

__all__ = ["BUFFERS", "OPTIONAL_BUFFERS"]

BUFFERS: dict[str, int] = {
    "color": 3,
    "base_color": 3,
    "depth": 1,
    "normal": 3,
    "specular": 1,
    "metallic": 1,
    "roughness": 1,
    "nov": 1,
    "motion": 2,
    "emission": 3,
}
# Buffers a sequence may lack (the authors' and DFASR's captures have no emission): read as absent, not an error.
OPTIONAL_BUFFERS = ("emission",)
