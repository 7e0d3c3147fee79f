"""OpenEXR in and out through the ``OpenEXR.File`` API: one-part scanline files, half or float channels.

Reading returns float32 numpy planes by channel name; every failure names the file (and the channel).
"""

from __future__ import annotations

import io
import os
from collections.abc import Callable, Iterable, Mapping
from pathlib import Path

import numpy as np
import OpenEXR

from wdss.errors import UserError

__all__ = ["COMPRESSIONS", "ExrError", "read_exr", "read_exr_size", "write_exr"]

COMPRESSIONS = {
    "none": OpenEXR.NO_COMPRESSION,
    "zip": OpenEXR.ZIP_COMPRESSION,
    "zips": OpenEXR.ZIPS_COMPRESSION,
    "piz": OpenEXR.PIZ_COMPRESSION,
    "rle": OpenEXR.RLE_COMPRESSION,
}


class ExrError(UserError):
    """An EXR file that cannot be read as asked: missing, corrupt, or without a needed channel."""


def read_exr(
    source: str | os.PathLike | bytes,
    channels: Iterable[str] | None = None,
    *,
    name: str | None = None,
    keep_dtype: bool = False,
    check_size: Callable[[tuple[int, int]], None] | None = None,
) -> dict[str, np.ndarray]:
    """Read the named ``channels`` (all when ``None``) of a one-part EXR as float32 ``(H, W)`` planes.

    ``source`` is a path or the file's bytes (e.g. a zip member); ``name`` is what errors call it.
    The File API decodes the whole part; only the requested planes are converted and returned.
    ``keep_dtype``: half channels stay float16 and float channels float32 (the packer stores them bit for bit).
    ``check_size``: called with the header's ``(H, W)`` before any pixel is decoded, to refuse the file by raising:
    decoding allocates whatever the header claims (a 23 KB file can claim 60000x60000, ~27 GB).
    """
    if check_size is not None:
        check_size(read_exr_size(source, name=name))
    label, part = _open(source, name, header_only=False)
    available = part.channels
    wanted = list(available) if channels is None else list(channels)
    missing = [c for c in wanted if c not in available]
    if missing:
        raise ExrError(f"{label} has no channel {', '.join(missing)} (it has {', '.join(sorted(available))})")
    if keep_dtype:
        return {c: np.asarray(available[c].pixels) for c in wanted}
    return {c: np.asarray(available[c].pixels, dtype=np.float32) for c in wanted}


def read_exr_size(source: str | os.PathLike | bytes, *, name: str | None = None) -> tuple[int, int]:
    """The ``(H, W)`` of a one-part EXR, from its header alone (no pixel data is decoded)."""
    _, part = _open(source, name, header_only=True)
    low, high = part.header["dataWindow"]
    return int(high[1] - low[1] + 1), int(high[0] - low[0] + 1)


def _open(source: str | os.PathLike | bytes, name: str | None, *, header_only: bool) -> tuple[str, OpenEXR.Part]:
    """The label errors use and the one part of an EXR file, or an :class:`ExrError` naming the file."""
    label = name or str(source if not isinstance(source, bytes) else "<bytes>")
    try:
        if isinstance(source, bytes):
            exr = OpenEXR.File(io.BytesIO(source), separate_channels=True, header_only=header_only)
        else:
            if not os.path.exists(source):
                raise ExrError(f"EXR file not found: {label}")
            exr = OpenEXR.File(str(source), separate_channels=True, header_only=header_only)
        parts = exr.parts
    except ExrError:
        raise
    except Exception as err:  # OpenEXR raises RuntimeError/OSError/ValueError variants for broken files
        raise ExrError(f"cannot read EXR {label} (corrupt, truncated or not an EXR file): {err}") from err
    if not parts:  # the binding only warns about undecodable pixel data and returns no part
        raise ExrError(f"cannot read EXR {label} (corrupt or truncated: its pixel data cannot be decoded)")
    if len(parts) != 1:
        raise ExrError(f"{label} has {len(parts)} parts; wdss reads one-part EXR files")
    return label, parts[0]


def write_exr(
    path: str | os.PathLike,
    channels: Mapping[str, np.ndarray],
    *,
    half: bool | Iterable[str] = False,
    compression: str = "zip",
) -> None:
    """Write float planes ``(H, W)`` as a one-part scanline EXR, atomically (a temp file, then a rename).

    ``half``: ``True`` stores every channel as 16-bit half, or an iterable names the half channels.
    """
    if compression not in COMPRESSIONS:
        raise ValueError(f"unknown EXR compression {compression!r}: expected one of {', '.join(COMPRESSIONS)}")
    half_names = set(channels) if half is True else set(half or ())
    planes = {}
    shape = None
    for key, plane in channels.items():
        arr = np.asarray(plane)
        if arr.ndim != 2:
            raise ValueError(f"EXR channel {key!r} for {path} must be 2-D (H, W), got shape {arr.shape}")
        if shape is not None and arr.shape != shape:
            raise ValueError(f"EXR channels for {path} differ in size: {key!r} is {arr.shape}, others {shape}")
        shape = arr.shape
        planes[key] = np.ascontiguousarray(arr, dtype=np.float16 if key in half_names else np.float32)
    header = {"compression": COMPRESSIONS[compression], "type": OpenEXR.scanlineimage}
    target = Path(path)
    target.parent.mkdir(parents=True, exist_ok=True)
    tmp = target.with_name(f".{target.name}.{os.getpid()}.tmp")
    try:
        OpenEXR.File(header, planes).write(str(tmp))
        os.replace(tmp, target)
    finally:
        if tmp.exists():
            tmp.unlink()
