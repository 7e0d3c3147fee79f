"""Packed sequences: a memory-mapped store read patch by patch (written by :mod:`wdss.data.pack`).

A packed store holds one folder per sequence, ``<store>/<sequence>/``:

* ``<H>P.bin``, one file per resolution: one record per frame, appended in packing order. A record starts with
  a table of ``(offset, length)`` (int64, from the record's start) of every ``(buffer, tile row, tile column)``
  chunk, then the chunks: a ``(C, t, t)`` tile of one buffer (``t`` = ``tile``, smaller at the right and bottom
  edges; ``tile: 0``, the default without compression: the whole frame) in the buffer's dtype: float16 where every
  channel of the source was half, float32 otherwise. With ``codec: zstd`` a chunk is compressed with a content
  checksum (a corrupt chunk fails to decode); with ``codec: lz4`` (the default) a chunk is the CRC-32 of the rest
  (4 bytes, little-endian), then an LZ4 block (high compression: a little larger than zip EXR files, decoded much
  faster than zstd); with ``codec: none`` it is stored as is, and a window of an untiled frame is one strided copy out
  of the memory map. Such a store is unchecked: a byte that changes in it later is read as it is (only each
  file's length is compared with the index, at opening); its errors and the packer say so.
* ``index.json``: format and version, the sequence's name, layout and source, codec and tile size, the sidecar's
  exposure, and per resolution: the file, the frame size, the frames, each buffer's dtype and source channels,
  and per packed frame its record's offset and length, the source files' sizes and CRC-32 (the zip format's
  checksum, so a zipped source is compared without decompressing it), non-finite counts per buffer and the
  frame's depth range (the normalisation's min and max after the far clamp, so that a patch needs no whole frame).
* ``sequence.json``: the source's sidecar, copied (camera rotations for flips, frame rate, exposure).

:class:`PackedSequence` reads a window of a frame by decoding only the tiles it overlaps, straight from the
memory map; it is a :class:`wdss.data.source.FrameSource`, as :class:`wdss.data.layouts.Sequence` is.
"""

from __future__ import annotations

import json
import logging
import zlib
from collections.abc import Iterable
from pathlib import Path

import numpy as np

from wdss.data.cache import FrameCache
from wdss.data.layouts import BUFFERS, SceneError, Sidecar, SidecarFacts, parse_sidecar
from wdss.data.preprocess import SANITIZE_ELSEWHERE, depth_range

__all__ = ["FORMAT", "VERSION", "PackedSequence", "discover_packed", "far_key", "is_packed"]

log = logging.getLogger(__name__)

FORMAT = "wdss-packed"
VERSION = 1
INDEX = "index.json"
CODECS = ("lz4", "zstd", "none")
LEVELS = {"lz4": 9, "zstd": 3}  # the default compression level per codec (lz4: its high-compression levels, 3-12)
DTYPES = ("float16", "float32")  # what a buffer is stored as: half where the source is half, float otherwise


def far_key(far: float | None) -> str:
    """The index key of a depth range computed with the far clamp ``far``."""
    return "none" if far is None else repr(float(far))


def is_packed(folder: str | Path) -> bool:
    """Whether ``folder`` is a packed sequence (it holds a packed index)."""
    return (Path(folder) / INDEX).is_file()


def tile_size(height: int, width: int, tile: int) -> int:
    """The tile size of a frame: ``tile``, or the whole frame for ``tile: 0``."""
    return tile if tile > 0 else max(height, width)


def tiles(height: int, width: int, tile: int) -> tuple[int, int]:
    """Tile rows and columns of a frame (``tile`` from :func:`tile_size`)."""
    return -(-height // tile), -(-width // tile)


def repack_hint(folder: Path) -> str:
    return f"re-pack it: remove {folder} and run python -m wdss.data.pack root=<the EXR scenes> out={folder.parent}"


class PackedSequence(SidecarFacts):
    """One packed sequence (a folder of :mod:`wdss.data.packed`); reads windows of frames as numpy arrays.

    Opening checks the index and that every file has the length its index records (a truncated or overwritten
    file is an error naming it and the sequence); a chunk that does not decode is one when it is read. A
    ``codec=none`` store carries no checksum (:attr:`checksummed` is False): changed bytes are read as they are.
    """

    def __init__(self, folder: str | Path) -> None:
        self.folder = Path(folder)
        where = self.folder / INDEX
        try:
            index = json.loads(where.read_text())
        except FileNotFoundError as err:
            raise SceneError(
                f"{self.folder} is not a packed sequence (no {INDEX}): pack it with wdss.data.pack"
            ) from err
        except (OSError, ValueError) as err:
            raise SceneError(f"packed index {where} cannot be read ({err}): {repack_hint(self.folder)}") from err
        if not isinstance(index, dict) or index.get("format") != FORMAT:
            raise SceneError(f"{where} is not a wdss packed index: {repack_hint(self.folder)}")
        if index.get("version") != VERSION:
            raise SceneError(f"{where} is version {index.get('version')} of the packed format, wdss reads {VERSION}")
        self.index = index
        try:
            self._check(index)
        except (KeyError, TypeError, ValueError) as err:
            raise SceneError(
                f"packed index {where} is malformed ({type(err).__name__}: {err}): {repack_hint(self.folder)}"
            ) from err
        self.name: str = index["sequence"]
        if not index.get("complete"):
            raise SceneError(
                f"packed sequence {self.name!r} ({self.folder}) is incomplete (its packing was interrupted): run "
                f"python -m wdss.data.pack again with the same arguments to finish it"
            )
        self.codec: str = index["codec"]
        self.checksummed = self.codec != "none"  # lz4 and zstd chunks carry one, checked as they are read
        self.tile: int = int(index["tile"])
        self.exposure: float | None = index.get("exposure")
        self._res = {int(h): r for h, r in index["resolutions"].items()}
        self.resolutions = sorted(self._res, reverse=True)
        self.hr = self.resolutions[0]
        self.frames = sorted(int(f) for f in self._res[self.hr]["packed"])
        self.sanitized: dict[str, int] = {}
        self._maps: dict[int, np.memmap] = {}
        self._ranges: dict[tuple[int, int, str], tuple[float, float]] = {}
        self._decompressor = None
        for height, res in self._res.items():
            path = self.folder / res["file"]
            expected = max((r["offset"] + r["length"] for r in res["packed"].values()), default=0)
            size = path.stat().st_size if path.is_file() else None
            if size != expected:
                found = "missing" if size is None else f"{size} bytes"
                raise SceneError(
                    f"packed file {path} of sequence {self.name!r} ({height}P) is {found}, its index records "
                    f"{expected} bytes: it is truncated or corrupt{self._unchecked()}; {repack_hint(self.folder)}"
                )
        sidecar = self.folder / "sequence.json"
        self._sidecar = parse_sidecar(sidecar.read_bytes(), str(sidecar)) if sidecar.is_file() else Sidecar({})
        self.frame_rate = self._sidecar.frame_rate

    @staticmethod
    def _check(index: dict) -> None:
        """The index's values are what a packed index holds: dtypes, codecs and sizes from short allowlists."""
        if index["codec"] not in CODECS or int(index["tile"]) < 0 or not isinstance(index["sequence"], str):
            raise ValueError(f"codec {index['codec']!r}, tile {index['tile']!r}")
        if not index["resolutions"]:
            raise ValueError("no resolutions")
        for height, res in index["resolutions"].items():
            int(height)
            if Path(res["file"]).name != res["file"] or len(res["shape"]) != 2:
                raise ValueError(f"file {res['file']!r}, shape {res['shape']!r}")
            for buffer, spec in res["buffers"].items():
                if buffer not in BUFFERS or spec["dtype"] not in DTYPES or len(spec["channels"]) != BUFFERS[buffer]:
                    raise ValueError(f"buffer {buffer!r}: {spec!r}")
            for frame, record in res["packed"].items():
                int(frame), int(record["offset"]), int(record["length"])

    def __repr__(self) -> str:
        return f"PackedSequence({self.name!r}, resolutions={self.resolutions}, frames={len(self.frames)})"

    def __getstate__(self) -> dict:  # memory maps and the decompressor do not cross process boundaries
        state = dict(self.__dict__)
        state["_maps"], state["_decompressor"] = {}, None
        return state

    # ---- the interface of wdss.data.source.FrameSource ---------------------------------------------------

    def frames_at(self, height: int) -> list[int]:
        """The frames packed at ``height``."""
        return sorted(int(f) for f in self._res.get(height, {}).get("packed", {}))

    def has(self, buffer: str, height: int, frame: int | None = None) -> bool:
        res = self._res.get(height)
        if res is None or buffer not in res["buffers"]:
            return False
        return frame is None or str(frame) in res["packed"]

    def shape(self, height: int) -> tuple[int, int]:
        h, w = self._res[height]["shape"]
        return int(h), int(w)

    def read(self, frame: int, height: int, buffers: Iterable[str], *, sanitize: bool = False) -> dict[str, np.ndarray]:
        """The requested buffers of one whole frame as float32 ``(C, H, W)`` arrays."""
        found, _ = self.read_window(frame, height, buffers, None, sanitize=sanitize)
        return {k: v.astype(np.float32) for k, v in found.items()}

    def read_window(
        self,
        frame: int,
        height: int,
        buffers: Iterable[str],
        window: tuple[int, int, int, int] | None,
        *,
        sanitize: bool = False,
        depth_far: float | None = None,
        depth_range: bool = False,
    ) -> tuple[dict[str, np.ndarray], tuple[float, float] | None]:
        """The ``(y, x, h, w)`` window of buffers of one frame in their stored dtype (zeros beyond the frame;
        ``None``: the whole frame) and, with ``depth_range``, the whole frame's depth range (from the index)."""
        wanted = list(dict.fromkeys(buffers))
        res = self._record(frame, height, wanted)
        out = {b: self._window(frame, height, b, window) for b in wanted}
        counts = res.get("nonfinite", {})
        for buffer in wanted:
            if counts.get(buffer):
                where = f"sequence {self.name!r}, frame {frame}, buffer {buffer} ({height}P, packed in {self.folder})"
                if not sanitize:
                    raise SceneError(
                        f"{where}: {counts[buffer]} non-finite value(s) (NaN or Inf) in the frame; set "
                        f"data.preprocessing.sanitize=true to replace them by 0 ({SANITIZE_ELSEWHERE})"
                    )
                bad = ~np.isfinite(out[buffer])
                if bad.any():
                    out[buffer][bad] = 0
                    key = f"{height}P:{frame}:{buffer}"
                    self.sanitized[key] = self.sanitized.get(key, 0) + int(bad.sum())
        return out, (self._depth_range(frame, height, depth_far) if depth_range else None)

    # ---- internals -------------------------------------------------------------------------------------

    def _record(self, frame: int, height: int, buffers: list[str]) -> dict:
        res = self._res.get(height)
        if res is None:
            raise SceneError(f"packed sequence {self.name!r} has no {height}P frames (it has {self.resolutions})")
        record = res["packed"].get(str(frame))
        if record is None:
            raise SceneError(f"packed sequence {self.name!r}: frame {frame} is not packed at {height}P")
        for buffer in buffers:
            if buffer not in BUFFERS:
                raise SceneError(f"unknown buffer {buffer!r}: expected one of {', '.join(BUFFERS)}")
            if buffer not in res["buffers"]:
                raise SceneError(
                    f"packed sequence {self.name!r}, frame {frame}: buffer {buffer!r} was not packed at {height}P "
                    f"({self.folder} holds {', '.join(res['buffers'])}); pack it with buffers=all"
                )
        return record

    def _map(self, height: int) -> np.memmap:
        if height not in self._maps:
            self._maps[height] = np.memmap(self.folder / self._res[height]["file"], dtype=np.uint8, mode="r")
        return self._maps[height]

    def _corrupt(self, height: int, frame: int, what: str) -> SceneError:
        path = self.folder / self._res[height]["file"]
        return SceneError(
            f"packed file {path} of sequence {self.name!r} is corrupt: frame {frame}, {what}{self._unchecked()}; "
            f"{repack_hint(self.folder)}"
        )

    def _unchecked(self) -> str:
        """What an error about a store without checksums adds: its other bytes were never checked either."""
        if self.checksummed:
            return ""
        return " (codec=none stores no checksum: bytes changed in place, at the same length, are read unnoticed)"

    def _decode(self, data: memoryview, size: int) -> bytes | memoryview:
        if self.codec == "none":
            return data
        if self.codec == "lz4":
            return lz4_decode(data, size)
        if self._decompressor is None:
            import zstandard

            self._decompressor = zstandard.ZstdDecompressor()
        return self._decompressor.decompress(data, max_output_size=size)

    def _window(self, frame: int, height: int, buffer: str, window: tuple[int, int, int, int] | None) -> np.ndarray:
        res = self._res[height]
        record = res["packed"][str(frame)]
        spec = res["buffers"][buffer]
        names = list(res["buffers"])
        dtype = np.dtype(spec["dtype"])
        channels = len(spec["channels"])
        full_h, full_w = self.shape(height)
        y, x, h, w = window if window is not None else (0, 0, full_h, full_w)
        out = np.zeros((channels, h, w), dtype=dtype)
        y0, y1, x0, x1 = max(y, 0), min(y + h, full_h), max(x, 0), min(x + w, full_w)
        if y0 >= y1 or x0 >= x1:
            return out
        t = tile_size(full_h, full_w, self.tile)
        rows, cols = tiles(full_h, full_w, t)
        mm = self._map(height)
        start, length = int(record["offset"]), int(record["length"])
        table_bytes = len(names) * rows * cols * 16
        if table_bytes > length:
            raise self._corrupt(height, frame, "its record is shorter than its chunk table")
        table = np.frombuffer(mm, dtype="<i8", count=len(names) * rows * cols * 2, offset=start)
        table = table.reshape(len(names), rows, cols, 2)[names.index(buffer)]
        rows_in, cols_in = range(y0 // t, (y1 - 1) // t + 1), range(x0 // t, (x1 - 1) // t + 1)
        # Small tiles: one decode per tile into a grid, then one copy (per-tile numpy calls would dominate); from
        # 128^2 on, each decoded tile is copied straight into the window (the grid's join and transpose cost more).
        many = len(rows_in) * len(cols_in) > 1 and t < 128
        if many and rows_in.stop * t <= full_h and cols_in.stop * t <= full_w:
            size = channels * t * t * dtype.itemsize
            window_table = table[rows_in.start : rows_in.stop, cols_in.start : cols_in.stop]
            grid = self._tile_grid(mm, window_table, start, length, table_bytes, size)
            if grid is not None:  # None: a chunk that is out of place or does not decode, named by the loop below
                grid = grid.view(dtype).reshape(len(rows_in), len(cols_in), channels, t, t)
                grid = grid.transpose(2, 0, 3, 1, 4).reshape(channels, len(rows_in) * t, len(cols_in) * t)
                top, left = rows_in.start * t, cols_in.start * t
                out[:, y0 - y : y1 - y, x0 - x : x1 - x] = grid[:, y0 - top : y1 - top, x0 - left : x1 - left]
                return out
        for ty in rows_in:
            for tx in cols_in:
                th, tw = min(t, full_h - ty * t), min(t, full_w - tx * t)
                size = channels * th * tw * dtype.itemsize
                offset, count = int(table[ty, tx, 0]), int(table[ty, tx, 1])
                if offset < table_bytes or count < 0 or offset + count > length:
                    raise self._corrupt(height, frame, f"buffer {buffer}, tile ({ty}, {tx}) lies outside its record")
                try:
                    data = self._decode(memoryview(mm)[start + offset : start + offset + count], size)
                except Exception as err:  # zstandard.ZstdError: a chunk whose bytes or checksum are wrong
                    raise self._corrupt(
                        height, frame, f"buffer {buffer}, tile ({ty}, {tx}) does not decode ({err})"
                    ) from err
                if len(data) != size:
                    raise self._corrupt(
                        height, frame, f"buffer {buffer}, tile ({ty}, {tx}) has {len(data)} bytes, not {size}"
                    )
                tile = np.frombuffer(data, dtype=dtype).reshape(channels, th, tw)
                # The overlap of the tile and the window, in frame coordinates.
                ty0, ty1 = max(y0, ty * t), min(y1, ty * t + th)
                tx0, tx1 = max(x0, tx * t), min(x1, tx * t + tw)
                out[:, ty0 - y : ty1 - y, tx0 - x : tx1 - x] = tile[
                    :, ty0 - ty * t : ty1 - ty * t, tx0 - tx * t : tx1 - tx * t
                ]
        return out

    def _tile_grid(self, mm: np.memmap, table: np.ndarray, start: int, length: int, table_bytes: int, size: int):
        """Whole tiles of ``size`` bytes, decoded and concatenated in row-major order (one decode call per tile, no
        array per tile), or None where a chunk lies outside its record or does not decode to a whole tile."""
        offsets, counts = table[..., 0].ravel(), table[..., 1].ravel()
        if (offsets < table_bytes).any() or (counts < 0).any() or (offsets + counts > length).any():
            return None
        view = memoryview(mm)
        try:
            chunks = [
                self._decode(view[start + o : start + o + c], size)
                for o, c in zip(offsets.tolist(), counts.tolist(), strict=True)
            ]
        except Exception:  # the tile-by-tile loop names the chunk
            return None
        if any(len(c) != size for c in chunks):
            return None
        return np.frombuffer(b"".join(chunks), dtype=np.uint8)

    def _depth_range(self, frame: int, height: int, far: float | None) -> tuple[float, float]:
        """The whole frame's depth range: recorded at packing for its far clamp, else computed once (cached)."""
        key = (frame, height, far_key(far))
        if key not in self._ranges:
            recorded = self._res[height]["packed"][str(frame)].get("depth_range", {}).get(far_key(far))
            if recorded is None:
                plane = self._window(frame, height, "depth", None)
                recorded = depth_range(np.nan_to_num(plane.astype(np.float32), nan=0.0, posinf=0.0, neginf=0.0), far)
            self._ranges[key] = (float(recorded[0]), float(recorded[1]))
        return self._ranges[key]

    def use_cache(self, cache: FrameCache | None) -> None:
        """Nothing to keep: a window decodes only its own tiles, straight from the memory map."""

    def stale(self) -> str | None:
        """Why the packed frames may no longer be the source's, or None (None too when the source is gone)."""
        recorded: dict[str, dict] = {}
        for res in self._res.values():
            for record in res["packed"].values():
                recorded.update(record.get("sources", {}))
        return changed_source(Path(self.index.get("source", "")), self.index.get("zip_prefix", ""), recorded)


def changed_source(source: Path, prefix: str, recorded: dict[str, dict]) -> str | None:
    """The first source file whose size or CRC-32 differs from ``recorded`` (name -> size, crc32), or None.

    Both are compared, for a folder as for a zip: a re-rendered frame often has the same byte size. A zip's are
    read from its central directory; a folder's files are read whole, once per process while their stat is
    unchanged (:func:`_file_crc32`).
    """
    if not str(source) or not source.exists():
        return None
    if source.is_dir():
        for name, meta in recorded.items():
            path = source / name
            if not path.is_file():
                return f"{path} changed since it was packed (it is gone)"
            if path.stat().st_size != meta["size"]:
                return _changed(path, "size")
            if _file_crc32(path) != meta["crc32"]:
                return _changed(path, "CRC-32")
        return None
    import zipfile

    try:
        with zipfile.ZipFile(source) as archive:
            infos = {i.filename: i for i in archive.infolist()}
    except (OSError, zipfile.BadZipFile) as err:
        return f"{source} cannot be read ({err})"
    for name, meta in recorded.items():
        info = infos.get(prefix + name)
        if info is None:
            return f"{source}:{prefix}{name} changed since it was packed (it is gone)"
        if info.file_size != meta["size"] or meta["crc32"] != info.CRC:
            return _changed(f"{source}:{prefix}{name}", "size" if info.file_size != meta["size"] else "CRC-32")
    return None


def _changed(where: object, what: str) -> str:
    return f"{where} changed since it was packed (sizes and CRC-32 compared: its {what} differs)"


_CRC32: dict[tuple, int] = {}  # (path, size, mtime, ctime, inode) -> CRC-32: a file read once per process


def _file_crc32(path: Path) -> int:
    """The CRC-32 of a file, as the packer recorded it (:func:`crc32` of its bytes), cached while its stat holds."""
    stat = path.stat()
    key = (str(path.resolve()), stat.st_size, stat.st_mtime_ns, stat.st_ctime_ns, stat.st_ino)
    if key not in _CRC32:
        value = 0
        with open(path, "rb") as handle:
            for block in iter(lambda: handle.read(1 << 22), b""):
                value = zlib.crc32(block, value)
        _CRC32[key] = value & 0xFFFFFFFF
    return _CRC32[key]


def lz4_encode(data: bytes, level: int) -> bytes:
    """One lz4 chunk: the CRC-32 of the block (4 bytes, little-endian), then the LZ4 block (no size header)."""
    import lz4.block

    block = lz4.block.compress(data, mode="high_compression", compression=level, store_size=False)
    return crc32(block).to_bytes(4, "little") + block


def lz4_decode(data: memoryview, size: int) -> bytes:
    """The ``size`` bytes of an lz4 chunk (:func:`lz4_encode`); a chunk whose checksum differs is a ValueError."""
    import lz4.block

    block = data[4:]
    if len(data) < 4 or crc32(block) != int.from_bytes(data[:4], "little"):
        raise ValueError("its CRC-32 differs")
    return lz4.block.decompress(block, uncompressed_size=size)


def crc32(data: bytes) -> int:
    return zlib.crc32(data) & 0xFFFFFFFF


def discover_packed(store: str | Path, names: Iterable[str]) -> list[PackedSequence]:
    """The named packed sequences of ``store``; a missing one is an error naming it and how to pack it."""
    store = Path(store)
    out = []
    for name in names:
        folder = store / name
        if not is_packed(folder):
            raise SceneError(
                f"sequence {name!r} is not packed in {store} (no {folder / INDEX}): pack the scenes with "
                f"python -m wdss.data.pack root=<the EXR scenes> out={store}, or set data.format=exr"
            )
        out.append(PackedSequence(folder))
    return out
