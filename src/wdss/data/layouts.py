"""Scene layouts on disk: which file and channel holds each buffer, at each resolution, for each frame.

A *sequence* is a folder (or one ``.zip`` of that folder) of consecutive frames. A *layout* is the naming
convention inside it. Two are known, and a renderer that writes one of them needs no reader of its own:

* :class:`UnrealLayout`, the WDSS authors' capture plugin: resolution folders ``<H>P`` (``1080P``, ``540P``,
  ...) holding four RGBA files per frame, ``BaseColorDepth.NNNN.exr`` (base colour, depth),
  ``NormalSpecular.NNNN.exr`` (world normal, specular), ``PretonemapMetallic.NNNN.exr`` (HDR colour,
  metallic) and ``MV_Roughness_NOV.NNNN.exr`` (motion vector, roughness, NoV).
* :class:`DFASRLayout`: ``GBuffer-<H>P/`` (high-resolution G-buffers) and ``Nojitter-<H>P/`` (colour and
  low-resolution buffers) of ``<prefix><Buffer>.NNNN.exr`` files, ``<Buffer>`` one of
  ``PreTonemapHDRColor``, ``BaseColor``, ``WorldNormalAndSceneDepth``, ``MotionVectorAndMetallicAndRoughness``,
  ``NoV``, ``Specular``.

The buffers and their channels are :data:`wdss.data.buffers.BUFFERS`; the optional ``emission`` is
``Emissive.NNNN.exr`` in either layout, written by wdss's renderer.

Reading opens only the files that hold a requested buffer, each at most once per call, and returns only the
requested channels; a requested buffer that is missing is an error naming sequence, frame, file and channel.
"""

from __future__ import annotations

import json
import logging
import re
import zipfile
import zlib
from abc import ABC, abstractmethod
from collections.abc import Callable, Iterable
from dataclasses import dataclass
from pathlib import Path
from typing import NamedTuple

import numpy as np
import torch

from wdss.data.buffers import BUFFERS, OPTIONAL_BUFFERS
from wdss.data.cache import FrameCache
from wdss.data.exr import read_exr, read_exr_size
from wdss.data.preprocess import SANITIZE_ELSEWHERE
from wdss.data.preprocess import depth_range as frame_depth_range
from wdss.errors import UserError
from wdss.ops.sampling import crop

__all__ = [
    "BUFFERS",
    "DEFAULT_FRAME_RATE",
    "DFASRLayout",
    "OPTIONAL_BUFFERS",
    "SceneError",
    "SceneLayout",
    "Sequence",
    "Sidecar",
    "UnrealLayout",
    "discover_sequences",
]

# Frames per second of a sequence whose sequence.json does not say (wdss's renderer steps per frame, not per
# second): the floor of real-time rendering, for videos.
DEFAULT_FRAME_RATE = 30.0

log = logging.getLogger(__name__)

_FRAME_FILE = re.compile(r"^(?P<stem>.+)\.(?P<frame>\d+)\.exr$")


class SceneError(UserError):
    """A scene that does not hold what was asked of it: missing buffer, frame, file, channel or size."""


@dataclass(frozen=True)
class Slot:
    """Where a buffer lives: the file stem and its channels, in the buffer's channel order."""

    stem: str
    channels: tuple[str, ...]


# --------------------------------------------------------------------------------------------------------
# Sources: a folder or a zip, with every read counted
# --------------------------------------------------------------------------------------------------------


class Source:
    """The files of one sequence, from a folder or a zip; ``opens`` counts the files whose pixels were read.

    A zip that cannot be opened (truncated: no central directory) is an error here, at discovery; a member
    that cannot be read (bad CRC, corrupt data) is one when it is read. Both name the zip (and the member).
    """

    def __init__(self, path: str | Path) -> None:
        self.path = Path(path)
        self.opens = 0
        self._zip: zipfile.ZipFile | None = None
        if self.path.is_dir():
            self.names = sorted(
                str(p.relative_to(self.path)).replace("\\", "/") for p in self.path.rglob("*.exr") if p.is_file()
            )
            self._prefix = ""
        elif self.path.is_file():
            try:
                with zipfile.ZipFile(self.path) as archive:
                    names = sorted(n for n in archive.namelist() if n.endswith(".exr"))
            except (zipfile.BadZipFile, EOFError) as err:
                raise SceneError(
                    f"sequence {self.path} is not a readable zip file ({err}): is it truncated or corrupt? "
                    "Re-create it, or use the sequence folder"
                ) from err
            # A zip of the sequence folder may keep that folder as its top level.
            top = {n.split("/", 1)[0] for n in names if "/" in n}
            self._prefix = f"{top.pop()}/" if len(top) == 1 and not self._has_resolution_dirs(names) else ""
            self.names = [n[len(self._prefix) :] for n in names]
        else:
            raise SceneError(f"sequence {self.path} is neither a folder nor a zip file")

    @staticmethod
    def _has_resolution_dirs(names: list[str]) -> bool:
        return any(re.fullmatch(r"(?:(?:GBuffer|Nojitter)-)?\d+P", n.split("/", 1)[0]) for n in names if "/" in n)

    @property
    def prefix(self) -> str:
        """The top folder a zip keeps the sequence's files under ("" for a folder or a flat zip)."""
        return self._prefix

    def describe(self, name: str) -> str:
        return f"{self.path}/{name}" if self.path.is_dir() else f"{self.path}:{self._prefix}{name}"

    def has(self, name: str) -> bool:
        if self.path.is_dir():
            return (self.path / name).is_file()
        with zipfile.ZipFile(self.path) as archive:
            return self._prefix + name in archive.namelist()

    def read_bytes(self, name: str) -> bytes:
        if self.path.is_dir():
            return (self.path / name).read_bytes()
        # A short-lived handle: one opened here, at discovery, would be shared by forked loader workers.
        with zipfile.ZipFile(self.path) as archive:
            return self._member(archive, name)

    def read(
        self,
        name: str,
        channels: Iterable[str],
        *,
        keep_dtype: bool = False,
        check_size: Callable[[tuple[int, int]], None] | None = None,
    ) -> dict[str, np.ndarray]:
        """The planes of one file (``check_size``: see :func:`wdss.data.exr.read_exr`)."""
        self.opens += 1
        options = {"name": self.describe(name), "keep_dtype": keep_dtype, "check_size": check_size}
        if self.path.is_dir():
            return read_exr(self.path / name, channels, **options)
        if self._zip is None:
            self._zip = zipfile.ZipFile(self.path)
        return read_exr(self._member(self._zip, name), channels, **options)

    def size(self, name: str) -> tuple[int, int]:
        """The ``(H, W)`` of one file, from its header (not counted in :attr:`opens`: no pixels are decoded)."""
        if self.path.is_dir():
            return read_exr_size(self.path / name, name=self.describe(name))
        if self._zip is None:
            self._zip = zipfile.ZipFile(self.path)
        return read_exr_size(self._member(self._zip, name), name=self.describe(name))

    def _member(self, archive: zipfile.ZipFile, name: str) -> bytes:
        try:
            return archive.read(self._prefix + name)
        except (zipfile.BadZipFile, zlib.error, EOFError, NotImplementedError) as err:
            raise SceneError(
                f"cannot read member {self._prefix}{name} of zip {self.path}: {err}; the zip is corrupt, re-create it"
            ) from err

    def __getstate__(self) -> dict:  # zip handles do not cross process boundaries (DataLoader workers)
        state = dict(self.__dict__)
        state["_zip"] = None
        return state


# --------------------------------------------------------------------------------------------------------
# Layouts
# --------------------------------------------------------------------------------------------------------


class SceneLayout(ABC):
    """A naming convention: resolution folders (``_FOLDER``, height in its last group) and buffer slots."""

    name: str
    SLOTS: dict[str, Slot]
    _FOLDER: re.Pattern

    @classmethod
    def matches(cls, names: list[str]) -> bool:
        """Whether a sequence's file list follows this layout."""
        return any(cls._FOLDER.match(n.split("/", 1)[0]) for n in names if "/" in n)

    def resolutions(self, names: list[str]) -> list[int]:
        """The heights of the resolutions present, largest first."""
        folders = (self._FOLDER.match(n.split("/", 1)[0]) for n in names if "/" in n)
        return sorted({int(m.group(m.lastindex)) for m in folders if m}, reverse=True)

    @abstractmethod
    def index(self, names: list[str]) -> dict:
        """A lookup table ``(height, stem, frame) -> file`` built once from the file list."""

    @abstractmethod
    def expected(self, buffer: str, height: int, frame: int) -> str:
        """The file a buffer would be in, for error messages."""

    def locate(self, buffer: str, height: int, frame: int, index: dict) -> tuple[str, Slot] | None:
        """The file (relative name) and slot of ``buffer`` at ``height`` for ``frame``, or None if absent."""
        slot = self.SLOTS[buffer]
        name = index.get((height, slot.stem, frame))
        return (name, slot) if name else None

    def frames(self, index: dict, height: int) -> list[int]:
        return sorted({frame for (folder_height, _, frame) in index if folder_height == height})


class UnrealLayout(SceneLayout):
    """The WDSS authors' Unreal Engine capture layout (docs/reference.md section 4)."""

    name = "unreal"
    SLOTS: dict[str, Slot] = {
        "base_color": Slot("BaseColorDepth", ("R", "G", "B")),
        "depth": Slot("BaseColorDepth", ("A",)),
        "normal": Slot("NormalSpecular", ("R", "G", "B")),
        "specular": Slot("NormalSpecular", ("A",)),
        "color": Slot("PretonemapMetallic", ("R", "G", "B")),
        "metallic": Slot("PretonemapMetallic", ("A",)),
        "motion": Slot("MV_Roughness_NOV", ("R", "G")),
        "roughness": Slot("MV_Roughness_NOV", ("B",)),
        "nov": Slot("MV_Roughness_NOV", ("A",)),
        "emission": Slot("Emissive", ("R", "G", "B")),  # wdss's renderer; not in the authors' captures
    }
    _FOLDER = re.compile(r"^(\d+)P$")

    def index(self, names: list[str]) -> dict:
        table = {}
        for name in names:
            folder, _, file = name.partition("/")
            folder_match, file_match = self._FOLDER.match(folder), _FRAME_FILE.match(file)
            if folder_match and file_match:
                table[(int(folder_match.group(1)), file_match.group("stem"), int(file_match.group("frame")))] = name
        return table

    def expected(self, buffer: str, height: int, frame: int) -> str:
        return f"{height}P/{self.SLOTS[buffer].stem}.{frame:04d}.exr"


class DFASRLayout(SceneLayout):
    """DFASR's layout: ``GBuffer-<H>P`` and ``Nojitter-<H>P`` folders of prefixed buffer files."""

    name = "dfasr"
    SLOTS: dict[str, Slot] = {
        "color": Slot("PreTonemapHDRColor", ("R", "G", "B")),
        "base_color": Slot("BaseColor", ("R", "G", "B")),
        "normal": Slot("WorldNormalAndSceneDepth", ("R", "G", "B")),
        "depth": Slot("WorldNormalAndSceneDepth", ("A",)),
        "motion": Slot("MotionVectorAndMetallicAndRoughness", ("R", "G")),
        "metallic": Slot("MotionVectorAndMetallicAndRoughness", ("B",)),
        "roughness": Slot("MotionVectorAndMetallicAndRoughness", ("A",)),
        "nov": Slot("NoV", ("R",)),
        "specular": Slot("Specular", ("R",)),
        "emission": Slot("Emissive", ("R", "G", "B")),  # optional: not in DFASR's published data
    }
    _FOLDER = re.compile(r"^(GBuffer|Nojitter)-(\d+)P$")
    _STEMS = sorted({s.stem for s in SLOTS.values()}, key=len, reverse=True)

    def index(self, names: list[str]) -> dict:
        table: dict = {}
        for name in names:
            folder, _, file = name.partition("/")
            folder_match, file_match = self._FOLDER.match(folder), _FRAME_FILE.match(file)
            if not (folder_match and file_match):
                continue
            stem = next((s for s in self._STEMS if file_match.group("stem").endswith(s)), None)
            if stem is None:
                continue
            kind, height = folder_match.group(1), int(folder_match.group(2))
            # High-resolution G-buffers live in GBuffer-<H>P; colour and everything else in Nojitter-<H>P.
            key = (height, stem, int(file_match.group("frame")))
            if kind == "GBuffer" or key not in table:
                table[key] = name
        return table

    def expected(self, buffer: str, height: int, frame: int) -> str:
        folder = "Nojitter" if buffer == "color" else "GBuffer or Nojitter"
        return f"{folder}-{height}P/<prefix>{self.SLOTS[buffer].stem}.{frame:04d}.exr"


LAYOUTS: dict[str, type[SceneLayout]] = {"unreal": UnrealLayout, "dfasr": DFASRLayout}


# --------------------------------------------------------------------------------------------------------
# A sequence: source + layout
# --------------------------------------------------------------------------------------------------------


class Sidecar(NamedTuple):
    """What a ``sequence.json`` tells the loader: camera rotations and LR sample offsets by frame, the frame rate."""

    cameras: dict[int, torch.Tensor]
    frame_rate: float = DEFAULT_FRAME_RATE
    lr_jitter: dict[int, tuple[float, float]] = {}


class SidecarFacts:
    """The per-frame facts of a sequence's ``sequence.json`` (``self._sidecar``), for every kind of sequence."""

    _sidecar: Sidecar

    def camera(self, frame: int) -> torch.Tensor | None:
        """The 3x3 camera-to-world rotation of ``frame`` from the sidecar ``sequence.json``, if there is one."""
        return self._sidecar.cameras.get(frame)

    def lr_jitter(self, frame: int) -> tuple[float, float]:
        """Where ``frame``'s native LR pixels were shaded, from their centres (LR pixels, x right, y down)."""
        return self._sidecar.lr_jitter.get(frame, (0.0, 0.0))


class Sequence(SidecarFacts):
    """One sequence of frames in a known layout; :meth:`read` loads named buffers of one frame (a
    :class:`wdss.data.source.FrameSource`)."""

    def __init__(self, path: str | Path, layout: str = "auto") -> None:
        self.source = Source(path)
        self.name = self.source.path.name.removesuffix(".zip")
        names = self.source.names
        if not names:
            raise SceneError(f"sequence {self.source.path} holds no EXR files")
        if layout == "auto":
            found = [cls for cls in LAYOUTS.values() if cls.matches(names)]
            if len(found) != 1:
                raise SceneError(
                    f"sequence {self.source.path}: cannot tell its layout (found folders "
                    f"{sorted({n.split('/', 1)[0] for n in names})[:6]}); expected <H>P/ folders (unreal) or "
                    "GBuffer-<H>P/ and Nojitter-<H>P/ (dfasr)"
                )
            self.layout: SceneLayout = found[0]()
        elif layout in LAYOUTS:
            if not LAYOUTS[layout].matches(names):
                raise SceneError(f"sequence {self.source.path} is not in the {layout!r} layout")
            self.layout = LAYOUTS[layout]()
        else:
            raise SceneError(f"unknown scene layout {layout!r}: expected auto, {', '.join(LAYOUTS)}")
        self._index = self.layout.index(names)
        self.resolutions = self.layout.resolutions(names)
        self.hr = self.resolutions[0]
        self.frames = self.layout.frames(self._index, self.hr)
        self.sanitized: dict[str, int] = {}
        self._sizes: dict[tuple[int, str], tuple[str, tuple[int, int]]] = {}  # (height, stem) -> first file, size
        self._shapes: dict[int, tuple[int, int]] = {}
        self.cache: FrameCache | None = None  # decoded frames kept between reads (the data module sets one)
        # At discovery: a malformed sidecar fails before training starts.
        self._sidecar = self._read_sidecar()
        self.frame_rate = self._sidecar.frame_rate

    def __repr__(self) -> str:
        return (
            f"Sequence({self.name!r}, layout={self.layout.name}, resolutions={self.resolutions}, "
            f"frames={len(self.frames)})"
        )

    def has(self, buffer: str, height: int, frame: int | None = None) -> bool:
        return self.file(buffer, height, self.frames[0] if frame is None else frame) is not None

    def frames_at(self, height: int) -> list[int]:
        """The frames that have files at ``height``."""
        return self.layout.frames(self._index, height)

    def stale(self) -> str | None:
        """None: the EXR files are the source, never out of date with themselves."""
        return None

    def use_cache(self, cache: FrameCache | None) -> None:
        """Keep decoded frames in ``cache`` (None: none): a patch is cut from a whole decoded frame."""
        self.cache = cache

    def file(self, buffer: str, height: int, frame: int) -> str | None:
        """The file (relative to the sequence) holding ``buffer`` of ``frame`` at ``height``, or None."""
        found = self.layout.locate(buffer, height, frame, self._index)
        return found[0] if found else None

    def _read_sidecar(self) -> Sidecar:
        if not self.source.has("sequence.json"):
            return Sidecar({})
        return parse_sidecar(self.source.read_bytes("sequence.json"), self.source.describe("sequence.json"))

    def read(self, frame: int, height: int, buffers: Iterable[str], *, sanitize: bool = False) -> dict[str, np.ndarray]:
        """The requested buffers of one frame at one resolution, as float32 ``(C, H, W)`` arrays (the caller's own).

        Non-finite values are an error naming file, channel, frame and count; with ``sanitize`` they are
        replaced by 0, counted in :attr:`sanitized` (per file) and logged.
        """
        decoded = self._decoded(frame, height, buffers, sanitize)
        return {k: v.copy() for k, v in decoded.items()} if self.cache is not None else decoded

    def _decoded(self, frame: int, height: int, buffers: Iterable[str], sanitize: bool) -> dict[str, np.ndarray]:
        """:meth:`read`'s arrays, from :attr:`cache` when it holds them (then read-only: copy before writing)."""
        wanted = list(dict.fromkeys(buffers))
        if self.cache is None:
            return self._decode(frame, height, wanted, sanitize)
        key = (str(self.source.path), frame, height, tuple(wanted), sanitize)
        found = self.cache.get(key)
        return found if found is not None else self.cache.put(key, self._decode(frame, height, wanted, sanitize))

    def _decode(self, frame: int, height: int, wanted: list[str], sanitize: bool) -> dict[str, np.ndarray]:
        by_file: dict[str, list[tuple[str, Slot]]] = {}
        for buffer in wanted:
            if buffer not in BUFFERS:
                raise SceneError(f"unknown buffer {buffer!r}: expected one of {', '.join(BUFFERS)}")
            found = self.layout.locate(buffer, height, frame, self._index)
            if found is None:
                raise SceneError(
                    f"sequence {self.name!r}, frame {frame}: buffer {buffer!r} is missing at {height}P "
                    f"(expected {self.layout.expected(buffer, height, frame)}, channels "
                    f"{','.join(self.layout.SLOTS[buffer].channels)})"
                )
            by_file.setdefault(found[0], []).append((buffer, found[1]))
        out: dict[str, np.ndarray] = {}
        shapes: dict[str, tuple[int, int]] = {}
        for name, slots in by_file.items():
            stem = slots[0][1].stem
            planes = self.source.read(  # a header of another size is refused before its pixels are allocated
                name,
                [c for _, slot in slots for c in slot.channels],
                check_size=lambda size, name=name, stem=stem: self.check_size(frame, height, stem, name, size),
            )
            for channel, plane in planes.items():
                bad = ~np.isfinite(plane)
                if bad.any():
                    count = int(bad.sum())
                    where = (
                        f"sequence {self.name!r}, frame {frame}, file {self.source.describe(name)}, channel {channel}"
                    )
                    if not sanitize:
                        raise SceneError(
                            f"{where}: {count} non-finite value(s) (NaN or Inf); set data.preprocessing.sanitize=true "
                            f"to replace them by 0 ({SANITIZE_ELSEWHERE})"
                        )
                    plane[bad] = 0.0
                    self.sanitized[f"{name}:{channel}"] = self.sanitized.get(f"{name}:{channel}", 0) + count
                    log.warning("%s: replaced %d non-finite value(s) by 0", where, count)
            for buffer, slot in slots:
                out[buffer] = np.stack([planes[c] for c in slot.channels])
            shapes[name] = next(iter(planes.values())).shape
        if len(set(shapes.values())) > 1:
            sizes = ", ".join(f"{self.source.describe(n)} {s[1]}x{s[0]}" for n, s in shapes.items())
            raise SceneError(f"sequence {self.name!r}, frame {frame}: buffers differ in size at {height}P: {sizes}")
        return out

    def shape(self, height: int) -> tuple[int, int]:
        """The ``(H, W)`` of the sequence's frames at ``height``, from the header of a file of its first frame."""
        if height not in self._shapes:
            frame = self.frames[0]
            buffer = next((b for b in ("color", "depth", *BUFFERS) if self.has(b, height, frame)), None)
            if buffer is None:
                raise SceneError(f"sequence {self.name!r}, frame {frame}: no buffer at {height}P")
            self._shapes[height] = self._header_size(self.file(buffer, height, frame), height)
        return self._shapes[height]

    def _header_size(self, name: str, height: int) -> tuple[int, int]:
        """The ``(H, W)`` a file's header claims, once its height is its folder's (``<H>P``): the first frame is
        what the others are compared with, and no header may claim a size its folder does not name."""
        size = self.source.size(name)
        if size[0] != height:
            raise SceneError(
                f"sequence {self.name!r}: {self.source.describe(name)} is {size[1]}x{size[0]} by its header, but its "
                f"folder is {height}P: every file at a resolution is as high as its folder says"
            )
        return size

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
        """The ``(y, x, h, w)`` window of buffers of one frame (zeros beyond the frame; ``None``: the whole frame)
        and, with ``depth_range``, the whole frame's depth range after the ``depth_far`` clamp.

        An EXR file is decoded whole; the depth plane is read for the range even when ``depth`` is not asked for.
        """
        wanted = list(dict.fromkeys(buffers))
        extra = depth_range and "depth" not in wanted
        full = self._decoded(frame, height, [*wanted, "depth"] if extra else wanted, sanitize)
        found = frame_depth_range(full["depth"], depth_far) if depth_range else None
        if self.cache is None:
            return {k: crop(full[k], window) for k in wanted}, found
        return {k: np.array(crop(full[k], window)) for k in wanted}, found  # a copy: cached frames are read-only

    def check_size(self, frame: int, height: int, stem: str, name: str, size: tuple[int, int]) -> None:
        """A file (``size`` from its header, before decoding) must have the size of the same file of the
        sequence's first frame at its resolution, whose header must give its folder's height.

        Patches and batches of one size would otherwise hide a frame rendered at another resolution, and decoding
        allocates whatever a header claims.
        """
        key = (height, stem)
        if key not in self._sizes:
            first = min(f for (h, s, f) in self._index if (h, s) == key)
            reference = self._index[(height, stem, first)]
            self._sizes[key] = (reference, self._header_size(reference, height))
        reference, expected = self._sizes[key]
        if size != expected:
            raise SceneError(
                f"sequence {self.name!r}, frame {frame}: {self.source.describe(name)} is {size[1]}x{size[0]}, but "
                f"the sequence's first frame at {height}P is {expected[1]}x{expected[0]} "
                f"({self.source.describe(reference)}); every frame of a sequence needs one size per resolution"
            )


def parse_sidecar(raw: bytes, where: str) -> Sidecar:
    """Camera rotations by frame, the frame rate (``fps``, default :data:`DEFAULT_FRAME_RATE`) and the native LR
    frames' sub-pixel jitter by frame (``lr_jitter``: ``[x, y]`` LR pixels, x right, y down, where the LR was
    rendered jittered) of a ``sequence.json``; ``where`` names it in errors."""
    try:
        meta = json.loads(raw)
    except ValueError as err:  # JSONDecodeError and UnicodeDecodeError
        raise SceneError(f"{where} is not valid JSON: {err}") from err
    cameras, jitter = {}, {}
    try:
        for entry in meta.get("frames", []):
            matrix = torch.tensor(entry["camera_to_world"], dtype=torch.float32)
            if matrix.ndim != 2 or min(matrix.shape) < 3:
                raise ValueError(f"camera_to_world of frame {entry['frame']} has shape {list(matrix.shape)}")
            cameras[int(entry["frame"])] = matrix[:3, :3]
            if "lr_jitter" in entry:
                x, y = (float(v) for v in entry["lr_jitter"])
                if not (abs(x) <= 0.5 and abs(y) <= 0.5):  # NaN fails too
                    raise ValueError(f"lr_jitter of frame {entry['frame']} is {[x, y]}, not within half a pixel")
                jitter[int(entry["frame"])] = (x, y)
    except (AttributeError, KeyError, TypeError, ValueError, RuntimeError) as err:
        raise SceneError(
            f"{where}: malformed 'frames' ({type(err).__name__}: {err}); expected a list of "
            "{frame: N, camera_to_world: 4x4 matrix[, lr_jitter: [x, y]]}"
        ) from err
    fps = meta.get("fps", DEFAULT_FRAME_RATE)
    if isinstance(fps, bool) or not isinstance(fps, int | float) or not 0 < fps <= 1000:
        raise SceneError(f"{where}: 'fps' must be a number of frames per second, got {fps!r}")
    return Sidecar(cameras, float(fps), jitter)


def discover_sequences(root: str | Path, names: Iterable[str] | None = None, layout: str = "auto") -> list[Sequence]:
    """The sequences under ``root``: its sub-folders and zip files (or the named ones), sorted by name."""
    root = Path(root)
    if not root.is_dir():
        raise SceneError(f"scene root {root} is not a folder")
    if names is None:
        paths = sorted(p for p in root.iterdir() if p.is_dir() or p.suffix == ".zip")
        if not paths:
            raise SceneError(f"scene root {root} holds no sequence folders or zip files")
    else:
        paths = []
        for name in names:
            candidates = [root / name, root / f"{name}.zip"]
            found = next((p for p in candidates if p.exists()), None)
            if found is None:
                available = sorted(p.name for p in root.iterdir())[:10]
                raise SceneError(f"sequence {name!r} not found under {root} (it holds {available})")
            paths.append(found)
    return [Sequence(p, layout) for p in paths]
