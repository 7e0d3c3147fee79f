"""``python -m wdss.data.pack root=DIR [out=DIR] [key=value ...]``: EXR sequences -> a packed store.

Converts every sequence under ``root`` (either layout, folders or zips) into a packed store
(:mod:`wdss.data.packed`; default ``out``: ``<root>.packed``), one folder per sequence and one file per resolution.
Options (``key=value``):

``buffers``    ``all`` (default) or a comma list of buffers (color, base_color, depth, normal, specular, metallic,
               roughness, nov, motion)
``inputs``     instead of ``buffers``: the batch keys of a model (a model config's ``inputs`` and ``test_inputs``,
               e.g. ``inputs=lr,gbuffer,history,temporal_mask,spatial_mask,brdf,target,motion``): the buffers
               they read; ``brdf=split_sum`` adds roughness and NoV
``sequences``  a comma list of sequence names (default: all under ``root``)
``layout``     auto | unreal | dfasr
``codec``      lz4 (default: a little larger than zip EXR files, decoded much faster than zstd) | zstd (about the
               EXR files' size) | none (larger still, but a patch is one copy out of the memory map:
               the fastest to read; unchecked: a byte changed in the store later is read as it is); lz4 and
               zstd checksum every chunk
``level``      compression level (default: lz4 9, its high-compression levels are 3-12; zstd 3)
``tile``       tile size in pixels: a patch decodes the tiles it overlaps (default 128 when compressed; 0: whole
               frames, the default without compression)
``verify``     frames per resolution compared bit for bit with the EXR source after packing (default 2), ``all``, 0
``depth_far``  the far clamp whose depth ranges the index records (default 100, data.preprocessing.depth_far's)

Packing resumes: frames already packed are kept (after checking that their source files did not change) and the
rest appended; a frame cut short by a kill is discarded and packed again.
"""

from __future__ import annotations

import functools
import json
import os
import sys
import time
from collections.abc import Callable, Iterable
from collections.abc import Sequence as Seq
from pathlib import Path
from typing import BinaryIO

import numpy as np

from wdss.data.exr import read_exr
from wdss.data.layouts import BUFFERS, OPTIONAL_BUFFERS, SceneError, Sequence, discover_sequences
from wdss.data.packed import (
    CODECS,
    FORMAT,
    INDEX,
    LEVELS,
    VERSION,
    PackedSequence,
    changed_source,
    crc32,
    far_key,
    lz4_encode,
    tile_size,
    tiles,
)
from wdss.data.preprocess import depth_range
from wdss.progress import Progress

__all__ = ["main", "pack", "pack_sequence", "verify_sequence"]

OPTIONS = (
    "root",
    "out",
    "buffers",
    "inputs",
    "brdf",
    "sequences",
    "layout",
    "codec",
    "level",
    "tile",
    "verify",
    "depth_far",
)
# 128^2 tiles: fewer, larger chunks decode faster per patch than 64^2 and pack a little smaller; a 432^2 patch
# reads ~1.7x its pixels (64^2: ~1.4x), cheaper than the per-chunk cost it saves.
TILE = 128
SAVE_EVERY_S = 5.0  # the index is rewritten at most this often while packing (and after every resolution)


def _dtype(planes: Iterable[np.ndarray]) -> np.dtype:
    """float16 where every channel is half, float32 otherwise (exact for half, float and 24-bit integers)."""
    return np.dtype(np.float16) if all(p.dtype == np.float16 for p in planes) else np.dtype(np.float32)


def _source_frame(seq: Sequence, frame: int, height: int, buffers: list[str]) -> tuple[dict, dict, tuple[int, int]]:
    """One frame's buffers as ``(C, H, W)`` arrays in their source dtype, the source files' sizes and CRC-32, and
    the frame size; files of another size are an error naming them."""
    by_file: dict[str, list[str]] = {}
    for buffer in buffers:
        name = seq.file(buffer, height, frame)
        if name is None:
            raise SceneError(
                f"sequence {seq.name!r}, frame {frame}: buffer {buffer!r} is missing at {height}P "
                f"(expected {seq.layout.expected(buffer, height, frame)})"
            )
        by_file.setdefault(name, []).append(buffer)
    arrays, sources, shapes = {}, {}, {}
    for name, names in by_file.items():
        data = seq.source.read_bytes(name)
        sources[name] = {"size": len(data), "crc32": crc32(data)}
        channels = [c for b in names for c in seq.layout.SLOTS[b].channels]
        stem = seq.layout.SLOTS[names[0]].stem
        check = functools.partial(seq.check_size, frame, height, stem, name)  # before its pixels are allocated
        planes = read_exr(data, channels, name=seq.source.describe(name), keep_dtype=True, check_size=check)
        shapes[name] = next(iter(planes.values())).shape
        for buffer in names:
            stack = [planes[c] for c in seq.layout.SLOTS[buffer].channels]
            arrays[buffer] = np.stack(stack).astype(_dtype(stack), copy=False)
    if len(set(shapes.values())) > 1:
        sizes = ", ".join(f"{seq.source.describe(n)} {s[1]}x{s[0]}" for n, s in shapes.items())
        raise SceneError(f"sequence {seq.name!r}, frame {frame}: buffers differ in size at {height}P: {sizes}")
    return arrays, sources, next(iter(shapes.values()))


def _encode(arrays: dict[str, np.ndarray], order: list[str], tile: int, compress) -> bytes:
    """One frame's record: the chunk table, then every (buffer, tile row, tile column) chunk."""
    height, width = arrays[order[0]].shape[-2:]
    tile = tile_size(height, width, tile)
    rows, cols = tiles(height, width, tile)
    table = np.zeros((len(order), rows, cols, 2), dtype="<i8")
    chunks, position = [], table.nbytes
    for b, buffer in enumerate(order):
        array = arrays[buffer]
        for ty in range(rows):
            for tx in range(cols):
                part = array[:, ty * tile : (ty + 1) * tile, tx * tile : (tx + 1) * tile]
                data = np.ascontiguousarray(part).tobytes()
                data = compress(data) if compress else data
                table[b, ty, tx] = (position, len(data))
                chunks.append(data)
                position += len(data)
    return table.tobytes() + b"".join(chunks)


def _save(folder: Path, index: dict) -> None:
    tmp = folder / f".{INDEX}.{os.getpid()}.tmp"
    tmp.write_text(json.dumps(index, indent=1))
    os.replace(tmp, folder / INDEX)


def _exposure(seq: Sequence) -> float | None:
    if not seq.source.has("sequence.json"):
        return None
    try:
        value = json.loads(seq.source.read_bytes("sequence.json")).get("exposure")
    except (ValueError, AttributeError):
        return None
    return float(value) if isinstance(value, int | float) and not isinstance(value, bool) else None


def pack_sequence(
    seq: Sequence,
    folder: str | Path,
    *,
    buffers: Iterable[str] | None = None,
    codec: str = "lz4",
    level: int | None = None,
    tile: int | None = None,
    verify: int | None = 2,
    depth_far: float | None = 100.0,
) -> PackedSequence:
    """Pack (or finish packing) one sequence into ``folder``; ``verify`` frames per resolution (None: all) are then
    compared bit for bit with the source."""
    level, tile = _codec_options(codec, level, tile)
    folder = Path(folder)
    wanted = _wanted_buffers(seq, buffers)
    settings = {"buffers": wanted, "codec": codec, "level": level if codec != "none" else None, "tile": tile}
    index = _open_index(seq, folder, settings)
    index["complete"] = False
    if seq.source.has("sequence.json"):
        (folder / "sequence.json").write_bytes(seq.source.read_bytes("sequence.json"))
    compress = _compressor(codec, level)
    frames_at = {h: seq.frames_at(h) for h in seq.resolutions}
    todo = sum(len(f) - len(index["resolutions"].get(str(h), {}).get("packed", {})) for h, f in frames_at.items())
    with Progress(f"pack {seq.name}", todo, every_s=5.0, unit="frames") as progress:
        for height in seq.resolutions:
            present = [b for b in wanted if seq.has(b, height)]
            if present:
                frames = frames_at[height]
                _pack_resolution(seq, folder, index, height, frames, present, tile, compress, depth_far, progress)
    index["complete"] = True
    _save(folder, index)
    packed = PackedSequence(folder)
    verify_sequence(seq, packed, verify)
    return packed


def _codec_options(codec: str, level: int | None, tile: int | None) -> tuple[int | None, int]:
    """The compression level and tile size to pack with (their defaults for ``codec`` where not given), checked."""
    if codec not in CODECS:
        raise ValueError(f"codec must be one of {', '.join(CODECS)}, got {codec!r}")
    tile = (TILE if codec != "none" else 0) if tile is None else int(tile)
    level = LEVELS.get(codec) if level is None else int(level)
    if tile != 0 and tile < 8:
        raise ValueError(f"tile must be 0 (whole frames) or at least 8 pixels, got {tile}")
    return level, tile


def _wanted_buffers(seq: Sequence, buffers: Iterable[str] | None) -> list[str]:
    """The buffers to pack (None: every one the sequence has at HR), each checked to exist at HR."""
    wanted = [b for b in BUFFERS if seq.has(b, seq.hr)] if buffers is None else list(dict.fromkeys(buffers))
    # An optional buffer a sequence lacks is packed as absent: reading treats it so (it emits nothing).
    wanted = [b for b in wanted if b not in OPTIONAL_BUFFERS or seq.has(b, seq.hr)]
    for buffer in wanted:
        if buffer not in BUFFERS:
            raise SceneError(f"unknown buffer {buffer!r}: expected one of {', '.join(BUFFERS)}")
        if not seq.has(buffer, seq.hr):
            raise SceneError(f"sequence {seq.name!r} has no {buffer!r} buffer at {seq.hr}P to pack")
    return wanted


def _open_index(seq: Sequence, folder: Path, settings: dict) -> dict:
    """The index of a packing to resume in ``folder`` (refused when made with other settings or from source files that
    changed since), or a new one, the folder made."""
    source = seq.source.path.resolve()
    index_path = folder / INDEX
    if not index_path.is_file():
        folder.mkdir(parents=True, exist_ok=True)
        index = {"format": FORMAT, "version": VERSION, "sequence": seq.name, "layout": seq.layout.name}
        index |= {"source": str(source), "zip_prefix": seq.source.prefix, **settings}
        return index | {"exposure": _exposure(seq), "complete": False, "resolutions": {}}
    try:
        index = json.loads(index_path.read_text())
    except ValueError as err:
        raise SceneError(f"{index_path} cannot be read ({err}): remove {folder} to pack it again") from err
    before = {k: index.get(k) for k in settings}
    if index.get("format") != FORMAT or index.get("version") != VERSION or before != settings:
        raise SceneError(
            f"{folder} holds a packing of {seq.name!r} with other settings ({before}, asked {settings}): remove "
            "it or pack with the same settings"
        )
    recorded = {
        n: m for r in index["resolutions"].values() for f in r["packed"].values() for n, m in f["sources"].items()
    }
    changed = changed_source(source, index.get("zip_prefix", ""), recorded)
    if changed:
        raise SceneError(
            f"cannot resume packing {seq.name!r} into {folder}: {changed}; remove {folder} to pack it again"
        )
    return index


def _compressor(codec: str, level: int | None) -> Callable[[bytes], bytes] | None:
    """What compresses one chunk in ``codec`` at ``level`` (None: stored as it is)."""
    if codec == "zstd":
        import zstandard

        return zstandard.ZstdCompressor(level=level, write_checksum=True, write_content_size=True).compress
    if codec == "lz4":
        return functools.partial(lz4_encode, level=level)
    return None


def _pack_resolution(
    seq: Sequence,
    folder: Path,
    index: dict,
    height: int,
    frames: list[int],
    present: list[str],
    tile: int,
    compress: Callable[[bytes], bytes] | None,
    depth_far: float | None,
    progress: Progress,
) -> None:
    """Append the frames of one resolution not packed yet to its file (after the last whole record: one cut short by
    a kill is packed again), saving the index now and then and once done."""
    res = index["resolutions"].setdefault(
        str(height), {"file": f"{height}P.bin", "shape": None, "frames": frames, "buffers": {}, "packed": {}}
    )
    path = folder / res["file"]
    end = max((r["offset"] + r["length"] for r in res["packed"].values()), default=0)
    size = path.stat().st_size if path.exists() else 0
    if size < end:
        raise SceneError(
            f"{path} is shorter than its index records ({size} < {end} bytes): remove {folder} to pack again"
        )
    saved = time.monotonic()
    with open(path, "r+b" if path.exists() else "wb") as out:
        out.truncate(end)  # a record cut short by a kill is packed again
        out.seek(end)
        for frame in frames:
            if str(frame) in res["packed"]:
                continue
            arrays, sources, shape = _source_frame(seq, frame, height, present)
            _fit_layout(seq, res, frame, height, present, arrays, shape)
            record = _encode(arrays, present, tile, compress)
            meta = _record_meta(arrays, sources, end, len(record), depth_far)
            out.write(record)
            end += len(record)
            res["packed"][str(frame)] = meta
            progress.advance()
            if time.monotonic() - saved >= SAVE_EVERY_S:
                _sync(out)
                _save(folder, index)
                saved = time.monotonic()
        _sync(out)
    _save(folder, index)


def _fit_layout(
    seq: Sequence, res: dict, frame: int, height: int, present: list[str], arrays: dict, shape: tuple[int, int]
) -> None:
    """Record the resolution's frame size and per-buffer dtype and channels from its first packed frame, or check a
    later frame against them: another size, or a float buffer earlier frames stored as half, is an error; a half
    buffer earlier frames stored as float is widened in place."""
    if res["shape"] is None:
        res["shape"] = list(shape)
        for buffer in present:
            slot = seq.layout.SLOTS[buffer]
            stem = seq.file(buffer, height, frame).rsplit("/", 1)[-1].split(".")[0]
            res["buffers"][buffer] = {
                "dtype": arrays[buffer].dtype.name,
                "channels": [f"{stem}.{c}" for c in slot.channels],
            }
    elif list(shape) != res["shape"]:
        raise SceneError(
            f"sequence {seq.name!r}, frame {frame}: {height}P is {shape[1]}x{shape[0]}, the sequence's "
            f"first packed frame {res['shape'][1]}x{res['shape'][0]}"
        )
    for buffer in present:
        stored = np.dtype(res["buffers"][buffer]["dtype"])
        if arrays[buffer].dtype != stored:
            if stored == np.float16:
                raise SceneError(
                    f"sequence {seq.name!r}, frame {frame}: buffer {buffer!r} at {height}P is float, "
                    "earlier frames' is half: re-render the sequence with one precision per buffer"
                )
            arrays[buffer] = arrays[buffer].astype(stored)


def _record_meta(arrays: dict, sources: dict, offset: int, length: int, depth_far: float | None) -> dict:
    """A packed frame's index entry: where its record lies, its source files, its non-finite values per buffer and
    its depth range (under ``depth_far`` and unclamped)."""
    meta: dict = {"offset": offset, "length": length, "sources": sources}
    meta["nonfinite"] = {b: int((~np.isfinite(a)).sum()) for b, a in arrays.items() if not np.isfinite(a).all()}
    if "depth" in arrays:
        depth = np.nan_to_num(arrays["depth"].astype(np.float32), nan=0.0, posinf=0.0, neginf=0.0)
        meta["depth_range"] = {far_key(f): list(depth_range(depth, f)) for f in {depth_far, None}}
    return meta


def _sync(out: BinaryIO) -> None:
    """The file's writes on disk, before an index that records them is saved."""
    out.flush()
    os.fsync(out.fileno())


def verify_sequence(seq: Sequence, packed: PackedSequence, frames: int | None = 2) -> int:
    """Compare ``frames`` evenly spaced frames per resolution (None: every frame) of a packed sequence with its
    EXR source, bit for bit; a difference is an error naming the packed file, frame, buffer and source file.
    Returns the number of frames compared."""
    checked = 0
    for height in packed.resolutions:
        res = packed._res[height]
        numbers = sorted(int(f) for f in res["packed"])
        if frames is not None:
            numbers = (
                sorted({numbers[round(i)] for i in np.linspace(0, len(numbers) - 1, min(frames, len(numbers)))})
                if frames
                else []
            )
        for frame in numbers:
            source, _, _ = _source_frame(seq, frame, height, list(res["buffers"]))
            for buffer, expected in source.items():
                expected = expected.astype(res["buffers"][buffer]["dtype"], copy=False)
                found = packed._window(frame, height, buffer, None)
                bits = np.dtype(f"u{expected.dtype.itemsize}")
                if found.shape != expected.shape or not np.array_equal(found.view(bits), expected.view(bits)):
                    raise SceneError(
                        f"packed file {packed.folder / res['file']} of sequence {packed.name!r} differs from its "
                        "source: "
                        f"frame {frame}, buffer {buffer} ({seq.source.describe(seq.file(buffer, height, frame))}); "
                        f"remove {packed.folder} and pack it again"
                    )
            checked += 1
    return checked


def pack(
    root: str | Path,
    out: str | Path | None = None,
    *,
    buffers: Iterable[str] | None = None,
    sequences: Iterable[str] | None = None,
    layout: str = "auto",
    codec: str = "lz4",
    level: int | None = None,
    tile: int | None = None,
    verify: int | None = 2,
    depth_far: float | None = 100.0,
) -> Path:
    """Pack the sequences under ``root`` (or the named ones) into ``out`` (default ``<root>.packed``)."""
    root = Path(root)
    out = Path(out) if out is not None else root.with_name(f"{root.name}.packed")
    for seq in discover_sequences(root, sequences, layout):
        pack_sequence(
            seq,
            out / seq.name,
            buffers=buffers,
            codec=codec,
            level=level,
            tile=tile,
            verify=verify,
            depth_far=depth_far,
        )
    return out


def _options(argv: Seq[str]) -> dict[str, str]:
    options = {}
    for arg in argv:
        key, sep, value = arg.partition("=")
        if not sep or key not in OPTIONS:
            raise SystemExit(f"wdss.data.pack: expected key=value with key one of {', '.join(OPTIONS)}, got {arg!r}")
        options[key] = value
    if "root" not in options:
        raise SystemExit("wdss.data.pack: root=<folder of EXR sequences> is required")
    if "buffers" in options and "inputs" in options:
        raise SystemExit("wdss.data.pack: give buffers= or inputs=, not both")
    return options


def _names(value: str | None) -> list[str] | None:
    return None if value in (None, "", "all") else [v.strip() for v in value.split(",") if v.strip()]


def main(argv: Seq[str] | None = None) -> None:
    options = _options(sys.argv[1:] if argv is None else argv)
    buffers = _names(options.get("buffers"))
    if "inputs" in options:
        from wdss.data.dataset import requirements
        from wdss.data.preprocess import Preprocessing

        need = requirements(_names(options["inputs"]) or [], Preprocessing(brdf=options.get("brdf", "extranet")))
        buffers = [b for b in BUFFERS if any(b in role for role in need.values())]
    verify = options.get("verify", "2")
    far = options.get("depth_far", "100")
    try:
        out = pack(
            options["root"],
            options.get("out") or None,
            buffers=buffers,
            sequences=_names(options.get("sequences")),
            layout=options.get("layout", "auto"),
            codec=options.get("codec", "lz4"),
            level=int(options["level"]) if "level" in options else None,
            tile=int(options["tile"]) if "tile" in options else None,
            verify=None if verify == "all" else int(verify),
            depth_far=None if far in ("null", "none") else float(far),
        )
    except (SceneError, ValueError) as err:
        raise SystemExit(f"wdss.data.pack: {err}") from err
    print(f"wdss.data.pack: {options['root']} -> {out}", flush=True)
    if options.get("codec") == "none":
        print(
            f"wdss.data.pack: codec=none stores no checksum: a byte that changes in {out} later is read as it is "
            "(lz4 and zstd check every chunk as it is read)",
            flush=True,
        )


if __name__ == "__main__":
    main()
