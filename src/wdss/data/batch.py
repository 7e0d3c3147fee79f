"""The batch: the one contract between the data and the networks, written once, as data.

A batch is a dict. Every key it may hold is a :class:`BatchKey` of :data:`KEYS`: its grid (``hr``: ``(N, C, H, W)``
on the high-resolution grid; ``lr``: ``(N, C, h, w)`` on the low-resolution one, ``h = round(H / s)``; ``sample``:
one value per sample), its channels, dtype and space, and what it means. Three keys are in every batch
(:data:`ALWAYS`: ``scale``, ``sequence``, ``frame``); every other one (:data:`BATCH_KEYS`) only when a model's
``inputs`` ask for it (:class:`wdss.data.dataset.FrameDataset` reads only the buffers those need), and ``emission``
only where the preprocessing separates emission too.

Spaces: colours are linear HDR radiance as rendered (pre-exposed); ``lr``, ``history`` and ``history2`` are
irradiance, colour less its emission over the BRDF factor (:func:`wdss.data.preprocess.irradiance_of`; colour when
``preprocessing.demodulate`` is false). No key is tone-mapped or in log space: a network that wants log1p inputs
takes them itself (its ``input_log``). G-buffer keys are cleaned (:func:`wdss.data.preprocess.clean`): far depth 0,
depth normalised by its HR frame's range, unit normals. Motion is in HR pixels, current minus previous screen
position, y up; ``lr_jitter`` in LR pixels from the pixel centre, x right, y down.

With ``data.sequence_length = T > 1`` a training batch is ``{"steps": [batch_1, ..., batch_T]}``.

:func:`check_batch` holds a batch to this table (the tests, and the data module's first batch of each loader).
"""

from __future__ import annotations

from collections.abc import Iterable, Mapping
from dataclasses import dataclass
from typing import Any

import torch

from wdss.data.buffers import BUFFERS

__all__ = [
    "ALWAYS",
    "BATCH_KEYS",
    "GBUFFER_STACK",
    "KEYS",
    "LR_GEOMETRY",
    "LR_GUIDE",
    "BatchError",
    "BatchKey",
    "check_batch",
]

# The high-resolution G-buffer stack of the network (key ``gbuffer``), in channel order (11 channels).
GBUFFER_STACK = ("base_color", "depth", "normal", "specular", "roughness", "nov", "metallic")
# The guide of every LR-side comparison (joint bilateral taps, the learned kernel; key ``lr_guide``): the first 7
# channels of the stack, albedo 3, depth 1, normal 3, as the LR frame saw them (wdss.data.preprocess.lr_guide).
LR_GUIDE = GBUFFER_STACK[:3]
# The low-resolution geometry of NSRR and FuseSR (keys ``lr_gbuffer`` and ``prev_lr_gbuffer``): depth 1, normal 3.
LR_GEOMETRY = ("depth", "normal")

GRIDS = ("hr", "lr", "sample")


class BatchError(ValueError):
    """A batch that breaks the contract of :data:`KEYS`: a bug of whatever built it, named by key."""


@dataclass(frozen=True)
class BatchKey:
    """One key of the batch.

    ``grid``: ``hr`` ``(N, C, H, W)``, ``lr`` ``(N, C, h, w)`` or ``sample`` (``(N, C)``, or ``(N,)`` where
    ``channels`` is None); ``stack``: the buffers concatenated in channel order, for the G-buffer keys; ``dtype``
    None: a list of ``N`` strings; ``always``: in every batch, asked for or not; ``absent``: when the key is left
    out although asked for ("" if never).
    """

    name: str
    grid: str
    channels: int | None
    space: str
    meaning: str
    stack: tuple[str, ...] = ()
    dtype: torch.dtype | None = torch.float32
    always: bool = False
    absent: str = ""

    @property
    def shape(self) -> tuple[str | int, ...]:
        """The shape, symbolic where it varies: ``N`` samples, ``H x W`` high and ``h x w`` low resolution."""
        tail = {"hr": ("H", "W"), "lr": ("h", "w"), "sample": ()}[self.grid]
        return ("N", *(() if self.channels is None else (self.channels,)), *tail)


def _stacked(name: str, grid: str, stack: tuple[str, ...], meaning: str) -> BatchKey:
    space = "G-buffer, cleaned"
    return BatchKey(name, grid, sum(BUFFERS[b] for b in stack), space, meaning, stack=stack)


_RADIANCE = "linear HDR radiance"
_IRRADIANCE = "linear irradiance (radiance when preprocessing.demodulate is false)"

KEYS: dict[str, BatchKey] = {
    key.name: key
    for key in (
        BatchKey("target", "hr", 3, _RADIANCE, "the high-resolution colour (ground truth)"),
        BatchKey("brdf", "hr", 3, "BRDF factor", "the high-resolution BRDF factor F, 1 where F vanishes"),
        BatchKey("lr", "lr", 3, _IRRADIANCE, "the low-resolution input: (colour - emission) / F_lr"),
        BatchKey("lr_color", "lr", 3, _RADIANCE, "the low-resolution colour (image-space baselines)"),
        BatchKey("lr_brdf", "lr", 3, "BRDF factor", "the low-resolution BRDF factor F_lr"),
        _stacked(
            "lr_guide",
            "lr",
            LR_GUIDE,
            "the G-buffer the LR colour was shaded with: a native LR folder's own, else the HR one point-sampled "
            "at the LR pixels (wdss.data.preprocess.lr_guide)",
        ),
        BatchKey(
            "lr_jitter",
            "sample",
            2,
            "LR pixels, x right, y down",
            "where the LR pixels were shaded, from their centres: a jittered native LR frame's lr_jitter, negated "
            "along a mirrored axis; else 0",
        ),
        _stacked("gbuffer", "hr", GBUFFER_STACK, "the high-resolution G-buffer stack"),
        BatchKey("spatial_mask", "hr", 1, "mask in {0, 1}", "1 where HR and upsampled LR G-buffers disagree"),
        BatchKey("history", "hr", 3, _IRRADIANCE, "the previous HR frame, warped by the motion vectors"),
        BatchKey(
            "temporal_mask",
            "hr",
            5,
            "differences >= 0",
            "|d depth|, |d albedo| (3), (1 - n.n')/2 against the warped previous frame",
        ),
        BatchKey("motion", "hr", 2, "HR pixels, current - previous, y up", "the motion vectors"),
        _stacked("lr_gbuffer", "lr", LR_GEOMETRY, "the low-resolution depth and normal (NSRR, FuseSR)"),
        BatchKey("prev_lr_color", "lr", 3, _RADIANCE, "the previous frame's low-resolution colour (NSRR)"),
        _stacked("prev_lr_gbuffer", "lr", LR_GEOMETRY, "the previous frame's low-resolution depth and normal (NSRR)"),
        BatchKey("history2", "hr", 3, _IRRADIANCE, "frame t-2 warped to t through t-1 (FuseSR)"),
        BatchKey(
            "emission",
            "hr",
            3,
            _RADIANCE,
            "the high-resolution emitted radiance, added to the remodulated prediction (0 for a sequence without "
            "the buffer)",
            absent="where preprocessing.emission does not separate emission",
        ),
        BatchKey("scale", "sample", None, "HR pixels per LR pixel", "the batch's nominal scale s", always=True),
        BatchKey("sequence", "sample", None, "names", "the sequence of each sample", dtype=None, always=True),
        BatchKey("frame", "sample", None, "frame numbers", "the frame of each sample", dtype=torch.int64, always=True),
    )
}
# The keys a model's inputs may ask for, and those in every batch.
BATCH_KEYS = tuple(name for name, key in KEYS.items() if not key.always)
ALWAYS = tuple(name for name, key in KEYS.items() if key.always)


def check_batch(batch: Mapping[str, Any], needs: Iterable[str] = ()) -> None:
    """Hold ``batch`` (or each step of a ``{"steps": [...]}`` batch) to :data:`KEYS`: every key known, ``needs`` and
    :data:`ALWAYS` present (but a key that may be absent), each of its dtype and shape, ``N``, ``H x W`` and
    ``h x w`` one size across keys. A :class:`BatchError` names the first key that breaks it."""
    needs = tuple(needs)
    unknown = sorted(set(needs) - set(KEYS))
    if unknown:
        raise BatchError(f"unknown batch keys {unknown}: expected some of {', '.join(KEYS)}")
    if "steps" in batch:
        for step in batch["steps"]:
            check_batch(step, needs)
        return
    unknown = sorted(set(batch) - set(KEYS))
    if unknown:
        raise BatchError(f"the batch holds unknown keys {unknown}: expected some of {', '.join(KEYS)}")
    missing = [k for k in (*ALWAYS, *needs) if k not in batch and not KEYS[k].absent]
    if missing:
        raise BatchError(f"the batch lacks {', '.join(dict.fromkeys(missing))} (it holds {', '.join(batch)})")
    sizes: dict[str, tuple[int, str]] = {}  # N, H, W, h, w -> the size and the key that first had it
    for name, value in batch.items():
        _check_key(KEYS[name], value, sizes)


def _check_key(key: BatchKey, value: Any, sizes: dict[str, tuple[int, str]]) -> None:
    """One key's dtype and shape; its symbolic sizes are recorded in (and compared with) ``sizes``."""
    if key.dtype is None:
        if not isinstance(value, list) or not all(isinstance(v, str) for v in value):
            raise BatchError(f"batch key {key.name!r} is a list of str, got {type(value).__name__}")
        found: tuple[int, ...] = (len(value),)
    else:
        if not isinstance(value, torch.Tensor) or value.dtype != key.dtype:
            what = value.dtype if isinstance(value, torch.Tensor) else type(value).__name__
            raise BatchError(f"batch key {key.name!r} is {key.dtype}, got {what}")
        found = tuple(value.shape)
    wrong = f"batch key {key.name!r} has shape {_show(key.shape)}, got {list(found)}"
    if len(found) != len(key.shape):
        raise BatchError(wrong)
    for symbol, size in zip(key.shape, found, strict=True):
        if isinstance(symbol, int) and size != symbol:
            raise BatchError(wrong)
        if isinstance(symbol, str) and sizes.setdefault(symbol, (size, key.name))[0] != size:
            other, owner = sizes[symbol]
            raise BatchError(f"{wrong}: {symbol} is {other} in {owner!r}")


def _show(shape: tuple[str | int, ...]) -> str:
    return f"({', '.join(map(str, shape))})"
