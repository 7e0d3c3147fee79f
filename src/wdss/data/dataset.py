"""Frames on disk -> named training and evaluation batches.

:class:`FrameDataset` reads, per sample, only the buffers that the requested batch keys need (from the
current and previous high-resolution frame and, where one matches the scale, a native low-resolution
folder), and only the patch: a packed store (:mod:`wdss.data.packed`) reads the patch's tiles, an EXR file is
decoded whole and cut. Previous frames are cut with the margin their warp needs (the motion vectors' extent in
the patch). It mirrors the patch and records each frame's depth range. :class:`Collate` stacks the samples into
a :class:`~wdss.data.preprocess.RawBatch` and, unless the preprocessing runs on the device, builds the batch
in the loader's worker (:mod:`wdss.data.preprocess`: scale, point sampling, BRDF, demodulation, warps, masks).
The batch keys are defined in :mod:`wdss.data.batch`; a sequence is read through
:class:`~wdss.data.source.FrameSource`, EXR files and packed stores alike.
"""

from __future__ import annotations

import logging
from collections.abc import Iterable, Mapping
from collections.abc import Sequence as Seq
from typing import Any

import numpy as np
import torch
import torch.nn.functional as F
from torch import Tensor
from torch.utils.data import Dataset, Sampler

from wdss.data.batch import BATCH_KEYS, GBUFFER_STACK, KEYS, LR_GEOMETRY, LR_GUIDE
from wdss.data.buffers import BUFFERS
from wdss.data.layouts import SceneError
from wdss.data.preprocess import Preprocessing, RawBatch, brdf_of, build_batch
from wdss.data.source import FrameSource
from wdss.ops.sampling import flip, flip_jitter, lr_size, scale_matches

__all__ = [
    "BATCH_KEYS",
    "LR_SOURCES",
    "GBUFFER_STACK",
    "Collate",
    "EpochSampler",
    "FrameDataset",
    "Preprocessing",
    "brdf_of",
    "build_batch",
    "draw_scale",
    "parse_scale",
    "requirements",
]

log = logging.getLogger(__name__)

_MASK_BUFFERS = {"depth", "normal", "base_color"}
_WARPED = {"history", "temporal_mask", "history2"}  # keys that warp previous frames by the motion vectors
ROLES = ("hr", "lr", "prev", "prev_lr", "prev2")
_OFFSET = {"hr": 0, "lr": 0, "prev": 1, "prev_lr": 1, "prev2": 2}  # frames back from the sample's frame
_HR_OF = {"lr": "hr", "prev_lr": "prev"}  # a low-resolution role and the high-resolution frame it samples


LR_SOURCES = ("auto", "native", "point")
ScaleSpec = float | tuple[float, float] | dict


def parse_scale(scale: Any, key: str = "data.scale") -> ScaleSpec:
    """A training scale: a number (fixed), ``[low, high]`` (drawn uniformly per batch) or ``{choices: [2, 3, 4]}``
    (one of them per batch: the scales a dataset rendered natively, so that every batch reads native LR frames)."""
    if isinstance(scale, Mapping):
        if set(scale) != {"choices"} or not scale["choices"]:
            raise ValueError(f"{key} as a mapping is {{choices: [s1, s2, ...]}}, got {dict(scale)}")
        return {"choices": tuple(float(s) for s in scale["choices"])}
    if isinstance(scale, Iterable) and not isinstance(scale, str):
        values = tuple(float(s) for s in scale)
        if len(values) != 2:
            raise ValueError(f"{key} is a number, [low, high] or {{choices: [...]}}, got {list(values)}")
        return values
    return float(scale)


def draw_scale(scale: ScaleSpec, seed: int | None = None) -> float:
    """One batch's scale under ``scale`` (:func:`parse_scale`), from ``seed`` when given."""
    rng = torch.Generator().manual_seed(seed) if seed is not None else None
    if isinstance(scale, dict):
        choices = scale["choices"]
        return float(choices[int(torch.randint(len(choices), (), generator=rng))])
    if isinstance(scale, tuple):
        low, high = scale
        return float(low + (high - low) * torch.rand((), generator=rng).item())
    return float(scale)


def requirements(keys: Iterable[str], prep: Preprocessing) -> dict[str, set[str]]:
    """Buffers per role for ``keys``: ``hr`` (current frame), ``lr`` (current, low resolution), ``prev`` (previous
    frame), ``prev_lr`` (previous, low resolution), ``prev2`` (the frame before the previous one)."""
    keys = set(keys)
    unknown = keys - set(KEYS)
    if unknown:
        raise ValueError(f"unknown batch keys {sorted(unknown)}: expected some of {', '.join(BATCH_KEYS)}")
    need: dict[str, set[str]] = {role: set() for role in ROLES}
    brdf = prep.brdf_buffers
    # Where emission is separated, every colour that is demodulated loses its emitted part first.
    emitted = {"emission"} if prep.separates_emission else set()
    if "emission" in keys:
        need["hr"] |= emitted
    if "target" in keys:
        need["hr"] |= {"color"}
    if "brdf" in keys:
        need["hr"] |= brdf
    if "lr" in keys:
        need["lr"] |= {"color"} | (brdf | emitted if prep.demodulate else set())
    if "lr_color" in keys:
        need["lr"] |= {"color"}
    if "lr_brdf" in keys:
        need["lr"] |= brdf
    if "lr_guide" in keys:
        need["lr"] |= set(LR_GUIDE)
    if "gbuffer" in keys:
        need["hr"] |= set(GBUFFER_STACK)
    if "spatial_mask" in keys:
        need["hr"] |= _MASK_BUFFERS
        need["lr"] |= _MASK_BUFFERS
    if "history" in keys:
        need["prev"] |= {"color"} | (brdf | emitted if prep.demodulate else set())
        need["hr"] |= {"motion"}
    if "temporal_mask" in keys:
        need["hr"] |= _MASK_BUFFERS | {"motion"}
        need["prev"] |= _MASK_BUFFERS
    if "motion" in keys:
        need["hr"] |= {"motion"}
    if "lr_gbuffer" in keys:
        need["lr"] |= set(LR_GEOMETRY)
    if "prev_lr_color" in keys:
        need["prev_lr"] |= {"color"}
    if "prev_lr_gbuffer" in keys:
        need["prev_lr"] |= set(LR_GEOMETRY)
    if "history2" in keys:
        need["prev2"] |= {"color"} | (brdf | emitted if prep.demodulate else set())
        need["prev"] |= {"motion"}
        need["hr"] |= {"motion"}
    return need


class FrameDataset(Dataset):
    """Samples of one split: every frame of every sequence (that has history, where history is needed).

    ``scale``: a number (fixed scale), or a ``(low, high)`` range or ``{choices: [...]}`` set (:func:`parse_scale`)
    from which :class:`EpochSampler` draws one per batch and hands to every item of it (items without one, read
    directly, get theirs from :class:`Collate`, after the read: point-sampled).
    ``lr_source``: where the LR frame comes from, the data's sampling convention: ``native`` (the sequence's own
    ``<H>P`` folder at the scale, rendered at LR as an engine does; an error naming the sequence where it has none),
    ``point`` (the HR frame point-sampled, the authors' convention, whatever folders exist) or ``auto`` (native
    where a folder matches the scale, else point-sampled).
    ``patch``: high-resolution patch size for training, ``None`` for full frames.
    ``first_frame``: ``"skip"`` leaves out frames without a previous frame when history is needed;
    ``"zeros"`` keeps them with zero history.
    ``sequence_length``: ``T > 1`` makes each sample ``T`` consecutive frames ending at the item's frame,
    cropped and mirrored alike (``{"steps": [...]}``), for recurrent training.
    """

    def __init__(
        self,
        sequences: Seq[FrameSource],
        keys: Iterable[str],
        *,
        scale: float | tuple[float, float] = 2.0,
        patch: int | None = None,
        preprocessing: Preprocessing | None = None,
        flips: bool = False,
        first_frame: str = "skip",
        frame_ranges: dict[str, tuple[int, int]] | None = None,
        sequence_length: int = 1,
        seed: int = 0,
        lr_source: str = "auto",
    ) -> None:
        if lr_source not in LR_SOURCES:
            raise ValueError(f"data.lr_source must be one of {', '.join(LR_SOURCES)}, got {lr_source!r}")
        if first_frame not in ("skip", "zeros"):
            raise ValueError(f"first_frame must be 'skip' or 'zeros', got {first_frame!r}")
        if sequence_length < 1:
            raise ValueError(f"sequence_length must be >= 1, got {sequence_length}")
        self.sequences = list(sequences)
        self.keys = tuple(keys)
        self.prep = preprocessing or Preprocessing()
        self.scale = parse_scale(scale)
        self.lr_source = lr_source
        self.patch = patch
        self.flips = flips
        self.first_frame = first_frame
        self.sequence_length = sequence_length
        self.seed = seed
        self.need = requirements(self.keys, self.prep)
        # Mirroring world-space normals needs each frame's camera rotation (sequence.json): a sequence without them
        # (foreign frames) is read unmirrored rather than refused part-way through training.
        self.unmirrored = set()
        if flips and any("normal" in buffers for buffers in self.need.values()):
            self.unmirrored = {i for i, s in enumerate(self.sequences) if any(s.camera(f) is None for f in s.frames)}
        if self.unmirrored:
            log.warning(
                "data.flips: %s %s no camera rotation per frame in sequence.json (needed to mirror world-space "
                "normals): %s not mirrored",
                ", ".join(self.sequences[i].name for i in sorted(self.unmirrored)),
                *(("has", "its frames are") if len(self.unmirrored) == 1 else ("have", "their frames are")),
            )
        self.warps = bool(_WARPED & set(self.keys))
        self.no_emission = self._check_emission()
        back = max((_OFFSET[role] for role, buffers in self.need.items() if buffers), default=0)
        self.items: list[tuple[int, int]] = []
        for index, seq in enumerate(self.sequences):
            frames = seq.frames
            if frame_ranges and seq.name in frame_ranges:
                start, stop = frame_ranges[seq.name]
                frames = [f for f in frames if start <= f < stop]
            available = set(seq.frames)
            for frame in frames:
                first = frame - sequence_length + 1
                if any(f not in available for f in range(first, frame + 1)):
                    continue
                if first_frame == "skip" and any(first - k not in available for k in range(1, back + 1)):
                    continue
                self.items.append((index, frame))
        if not self.items:
            names = ", ".join(s.name for s in self.sequences)
            raise SceneError(
                f"no usable frames in sequences [{names}] (history needs two consecutive frames, a sequence "
                f"length of {sequence_length} needs {sequence_length})"
            )

    def __len__(self) -> int:
        return len(self.items)

    def _check_emission(self) -> set[str]:
        """The sequences without an emission buffer, where one is read: they emit nothing (``emission=auto``), or
        they are an error naming them (``emission=true``)."""
        if not any("emission" in buffers for buffers in self.need.values()):
            return set()
        missing = {seq.name for seq in self.sequences if not seq.has("emission", seq.hr)}
        if missing and self.prep.emission is True:
            raise SceneError(
                f"sequence(s) {', '.join(sorted(missing))} have no emission buffer (Emissive.NNNN.exr), which "
                "data.preprocessing.emission=true requires; set it to auto (they then emit nothing) or false"
            )
        for name in sorted(missing):
            log.info("sequence %r has no emission buffer: its colour is demodulated whole (as if nothing emits)", name)
        return missing

    def native_lr(self, seq: FrameSource, scale: float | None = None) -> int | None:
        """The native low-resolution folder read at ``scale`` (default: the fixed scale), if any: the one choice of
        where the LR frame and its G-buffer (:func:`wdss.data.preprocess.lr_guide`) come from (``lr_source``)."""
        scale = self.scale if scale is None else scale  # a range or set: the batch's scale is not known here
        if not isinstance(scale, float) or self.lr_source == "point" or not (self.need["lr"] or self.need["prev_lr"]):
            return None
        for height in seq.resolutions[1:]:
            if scale_matches(seq.hr, height, scale):
                return height
        if self.lr_source == "native":
            folders = ", ".join(f"{h}P" for h in seq.resolutions[1:]) or "none"
            raise SceneError(
                f"sequence {seq.name!r} has no native LR folder at scale {scale:g} ({seq.hr}P / {scale:g}; it has "
                f"{folders}), which data.lr_source=native requires; render it, or set data.lr_source=auto|point"
            )
        return None

    def _frame(self, seq: FrameSource, frame: int, lr_height: int | None, window: tuple | None) -> dict:
        """The raw buffers of one frame in each role, cut to the window (zeros for history before the first frame),
        each high-resolution frame's depth range, and the margins of the previous frames' windows."""
        need, prep = self.need, self.prep
        hr_box, lr_box = window if window is not None else (None, None)
        # Without a native low-resolution folder, LR roles are point-sampled from their HR frame.
        reads = {
            "hr": (frame, seq.hr, need["hr"] | (set() if lr_height else need["lr"])),
            "lr": (frame, lr_height, need["lr"] if lr_height else set()),
            "prev": (frame - 1, seq.hr, need["prev"] | (set() if lr_height else need["prev_lr"])),
            "prev_lr": (frame - 1, lr_height, need["prev_lr"] if lr_height else set()),
            "prev2": (frame - 2, seq.hr, need["prev2"]),
        }
        # Native LR depth is normalised with the range of its HR frame, as point-sampled LR depth (cut from the
        # HR frame) is: the spatial mask compares HR depth with LR depth, and both paths must agree.
        ranged = {
            role: prep.depth_normalize
            and ("depth" in reads[role][2] or any(hr == role and "depth" in reads[lr][2] for lr, hr in _HR_OF.items()))
            for role in ("hr", "prev", "prev2")
        }
        available = set(seq.frames)
        out: dict = {"sequence": seq.name, "frame": frame, "ranges": {}, "margins": {"prev": 0, "prev2": 0}}
        margin = 0
        for role in ROLES:
            number, height, buffers = reads[role]
            box = lr_box if role in _HR_OF else hr_box
            if role in ("prev", "prev2") and box is not None and self.warps and buffers:
                # The previous frame's window: the patch grown by the extent of the motion that points into it.
                motion = out["hr" if role == "prev" else "prev"].get("motion")
                margin += _margin(motion, seq.shape(seq.hr)) if motion is not None else 0
                y, x, h, w = box
                box = (y - margin, x - margin, h + 2 * margin, w + 2 * margin)
                out["margins"][role] = margin
            if role in _HR_OF and "depth" in buffers and prep.depth_normalize:
                out["ranges"][role] = out["ranges"][_HR_OF[role]]
            want_range = ranged.get(role, False)
            emits_nothing = "emission" in buffers and seq.name in self.no_emission
            buffers = buffers - {"emission"} if emits_nothing else buffers
            if not buffers and not want_range:
                out[role] = {}
                continue
            if number in available:
                raw, found = seq.read_window(
                    number,
                    height,
                    sorted(buffers),
                    box,
                    sanitize=prep.sanitize,
                    depth_far=prep.depth_far,
                    depth_range=want_range,
                )
            else:  # history before the first frame, kept with zeros (first_frame="zeros"): they stay zero when cleaned
                h, w = box[2:] if box is not None else seq.shape(height)
                raw, found = {b: np.zeros((BUFFERS[b], h, w), np.float32) for b in buffers}, (0.0, 1.0)
            if emits_nothing:
                h, w = box[2:] if box is not None else seq.shape(height)
                raw["emission"] = np.zeros((3, h, w), raw["color"].dtype if "color" in raw else np.float32)
            # Half buffers stay half up to the preprocessing (half the bytes to move); normals are mirrored in float.
            out[role] = {
                k: torch.from_numpy(v).float() if k == "normal" else torch.from_numpy(v) for k, v in raw.items()
            }
            if want_range:
                out["ranges"][role] = found
        return out

    def _check_native_lr(self, seq: FrameSource, frame: int, lr_height: int, scale: float) -> None:
        hr_shape, lr_shape = seq.shape(seq.hr), seq.shape(lr_height)
        expected = lr_size(*hr_shape, scale)
        if tuple(lr_shape) != expected:
            raise SceneError(
                f"sequence {seq.name!r}, frame {frame}: the {lr_height}P frame is {lr_shape[1]}x{lr_shape[0]}, "
                f"but {hr_shape[1]}x{hr_shape[0]} at scale {scale:g} needs {expected[1]}x{expected[0]}"
            )

    def __getitem__(self, index: int | tuple) -> dict:
        # (index, epoch[, scale]) from EpochSampler: all randomness is a function of (seed, epoch, index), so a run
        # that is killed and resumed from its last epoch sees exactly the samples an uninterrupted one would.
        index, epoch, scale = (*index, None)[:3] if isinstance(index, tuple) else (index, None, None)
        rng = torch.Generator().manual_seed(_mix(self.seed, epoch, index)) if epoch is not None else None
        seq_index, frame = self.items[index]
        seq = self.sequences[seq_index]
        scale = scale if scale is not None else self.scale  # the sampler's draw, else the fixed scale (or a spec)
        lr_height = self.native_lr(seq, scale)
        if lr_height:
            self._check_native_lr(seq, frame, lr_height, scale)
        window = self._window(seq, lr_height and seq.hr / lr_height, rng)
        steps = [self._frame(seq, f, lr_height, window) for f in range(frame - self.sequence_length + 1, frame + 1)]
        flips = (False, False)
        if self.flips:
            flips = (bool(torch.rand((), generator=rng) < 0.5), bool(torch.rand((), generator=rng) < 0.5))
            if seq_index in self.unmirrored:  # drawn all the same: the other samples' draws do not move
                flips = (False, False)
        for step in steps:
            # Where the LR pixels were shaded: a jittered native frame's offset; point samples are taken here.
            jitter = torch.tensor(seq.lr_jitter(step["frame"]) if lr_height else (0.0, 0.0), dtype=torch.float32)
            step["lr_jitter"] = flip_jitter(jitter, horizontal=flips[0], vertical=flips[1])
            if any(flips):  # margins are symmetric: a mirrored window with its margin is the mirrored margin's window
                for role in ROLES:
                    camera = seq.camera(step["frame"] - _OFFSET[role])
                    camera = seq.camera(step["frame"]) if camera is None else camera
                    step[role] = flip(step[role], horizontal=flips[0], vertical=flips[1], camera=camera)
            step["seed"] = _mix(self.seed, epoch, index) if epoch is not None else None
            step["scale"] = scale if isinstance(scale, float) else None  # None: Collate draws it, after the read
        return steps[0] if self.sequence_length == 1 else {"steps": steps}

    def _window(self, seq: FrameSource, native_scale: float | None, rng: torch.Generator | None) -> tuple | None:
        """A random patch position shared by every step of a sample: HR ``(y, x, h, w)`` and LR likewise."""
        if self.patch is None:
            return None
        height, width = seq.shape(seq.hr)
        size = self.patch
        if height < size or width < size:
            raise SceneError(f"patch size {size} is larger than the frame ({height}x{width})")
        if native_scale:  # crop on the low-resolution grid so both patches cover the same pixels
            step = round(native_scale)
            size -= size % step  # e.g. 64 -> 63 at 3x: the largest patch that a native LR patch covers exactly
            y = int(torch.randint(0, (height - size) // step + 1, (), generator=rng)) * step
            x = int(torch.randint(0, (width - size) // step + 1, (), generator=rng)) * step
            return (y, x, size, size), (y // step, x // step, size // step, size // step)
        y = int(torch.randint(0, height - size + 1, (), generator=rng))
        x = int(torch.randint(0, width - size + 1, (), generator=rng))
        return (y, x, size, size), None


def _margin(motion: Tensor, shape: tuple[int, int]) -> int:
    """Pixels on every side that a backward warp by ``motion`` reaches beyond its window (bilinear taps included).

    At most the frame's size: history from farther away is outside the frame, zeros either way."""
    reach = float(torch.nan_to_num(motion.float().abs(), nan=0.0, posinf=0.0).max()) if motion.numel() else 0.0
    return min(int(np.ceil(reach)) + 1, max(shape) + 1)


class Collate:
    """Stack samples into a :class:`~wdss.data.preprocess.RawBatch` (runs in loader workers) and build the batch
    from it there, or, with ``on_device``, leave that to the device (the DataModule's ``on_after_batch_transfer``)."""

    def __init__(
        self,
        keys: Iterable[str],
        preprocessing: Preprocessing,
        scale: ScaleSpec,
        *,
        on_device: bool = False,
    ) -> None:
        self.keys = set(keys) | {"scale"}
        self.prep = preprocessing
        self.scale = parse_scale(scale)
        self.on_device = on_device

    def pick_scale(self, first: Mapping[str, Any]) -> float:
        """The batch's scale: the one its samples were read at (:class:`EpochSampler` draws it), else fixed, else
        drawn here from the first sample's seed (samples read without a scale: their LR is point-sampled)."""
        if first.get("scale") is not None:
            return float(first["scale"])
        return draw_scale(self.scale, first.get("seed"))

    def __call__(self, samples: list[dict]) -> dict | RawBatch:
        first = samples[0]["steps"][0] if "steps" in samples[0] else samples[0]
        scale = self.pick_scale(first)
        if "steps" in samples[0]:  # sequences: one batch per time step, all at the batch's scale
            length = len(samples[0]["steps"])
            return {"steps": [self._one(self.raw([s["steps"][t] for s in samples], scale)) for t in range(length)]}
        return self._one(self.raw(samples, scale))

    def _one(self, raw: RawBatch) -> dict | RawBatch:
        return raw if self.on_device else raw.build()

    def batch(self, samples: list[dict], scale: float) -> dict:
        """The batch of ``samples`` at ``scale``, built here."""
        return self.raw(samples, scale).build()

    def raw(self, samples: list[dict], scale: float) -> RawBatch:
        """The samples stacked by role; previous frames padded with zeros to the batch's largest margin."""
        margins = {role: max(s["margins"][role] for s in samples) for role in ("prev", "prev2")}

        def stack(role: str) -> dict[str, Tensor]:
            pad = [margins.get(role, 0) - s["margins"].get(role, 0) for s in samples]
            return {
                name: torch.stack(
                    [
                        F.pad(s[role][name], (p, p, p, p)) if p else s[role][name]
                        for s, p in zip(samples, pad, strict=True)
                    ]
                )
                for name in samples[0][role]
            }

        need = requirements(self.keys - {"scale"}, self.prep)
        roles = {role: stack(role) for role in ROLES}
        return RawBatch(
            keys=tuple(sorted(self.keys - {"scale"})),
            prep=self.prep,
            scale=scale,
            roles=roles,
            ranges={
                role: torch.tensor([s["ranges"][role] for s in samples], dtype=torch.float32)
                for role in samples[0]["ranges"]
            },
            margins=margins,
            sampled={low: tuple(sorted(need[low])) for low in _HR_OF if need[low] and not roles[low]},
            sequence=[s["sequence"] for s in samples],
            frame=torch.tensor([s["frame"] for s in samples]),
            lr_jitter=torch.stack([s.get("lr_jitter", torch.zeros(2)) for s in samples]),
        )


def _mix(seed: int, epoch: int | None, index: int) -> int:
    """A per-(seed, epoch, sample) seed for torch.Generator."""
    return (int(seed) * 1_000_003 + int(epoch or 0) * 7_919 + int(index)) % (2**63 - 1)


class EpochSampler(Sampler):
    """A random order that is a function of (seed, epoch) alone, yielding ``(index, draw)``.

    Lightning calls :meth:`set_epoch` before each epoch, so resuming from epoch ``k`` replays the order (and,
    through the dataset's per-sample generators, the crops, flips and scales) of an uninterrupted run.
    ``repeats``: each item is drawn that many times per epoch (several patches per frame of a small dataset),
    each draw with its own randomness: ``draw = epoch * repeats + r``.

    Under DDP, ``rank`` of ``world_size`` processes takes its own share of every epoch, so the shares are disjoint
    and still a function of (seed, epoch) alone (a resume replays them): shuffled, every ``world_size``-th draw of
    the one permutation from position ``rank``, the remainder of the division left out so that every rank steps
    the same number of batches (DDP synchronises every step); in order (evaluation), a contiguous block, so that a
    sequence's frames stay consecutive (a recurrent model and the temporal metrics pair each frame with the one
    before; only a pair cut by a block's start is lost).

    ``scale``: a range or set of scales (:func:`parse_scale`) from which each batch of ``batch_size`` consecutive
    draws gets one scale, a function of (seed, epoch, batch) too, yielded as ``(index, draw, scale)``: the dataset
    then knows the scale before it reads, and reads a native LR folder of that scale where the data has one.
    """

    def __init__(
        self,
        size: int,
        seed: int = 0,
        shuffle: bool = True,
        repeats: int = 1,
        rank: int = 0,
        world_size: int = 1,
        *,
        scale: ScaleSpec | None = None,
        batch_size: int = 1,
    ) -> None:
        if repeats < 1:
            raise ValueError(f"data.patches_per_frame must be >= 1, got {repeats}")
        if not 0 <= rank < world_size:
            raise ValueError(f"rank {rank} is not one of {world_size} processes")
        if size * repeats < world_size:  # an empty share: that rank would never reach the others' collectives
            raise ValueError(f"{size * repeats} samples cannot be shared among {world_size} processes")
        self.size, self.seed, self.shuffle, self.epoch, self.repeats = size, seed, shuffle, 0, repeats
        self.rank, self.world_size = rank, world_size
        self.scale = None if scale is None or isinstance(scale, float) else parse_scale(scale)
        self.batch_size = max(1, int(batch_size))

    def set_epoch(self, epoch: int) -> None:
        self.epoch = epoch

    def _block(self) -> range:
        total = self.size * self.repeats
        return range(total * self.rank // self.world_size, total * (self.rank + 1) // self.world_size)

    def __len__(self) -> int:
        return self.size * self.repeats // self.world_size if self.shuffle else len(self._block())

    def __iter__(self):
        if self.shuffle:
            total = self.size * self.repeats
            order = torch.randperm(total, generator=torch.Generator().manual_seed(_mix(self.seed, self.epoch, 0)))
            order = order[: total - total % self.world_size][self.rank :: self.world_size]
        else:
            order = self._block()
        draws = [(int(v) % self.size, self.epoch * self.repeats + int(v) // self.size) for v in order]
        if self.scale is None:
            return iter(draws)
        # Seeds of their own (negative batch numbers), so a batch's scale is independent of its samples' crops.
        scales = [
            draw_scale(self.scale, _mix(self.seed, self.epoch, -1 - b))
            for b in range((len(draws) + self.batch_size - 1) // self.batch_size)
        ]
        return iter([(index, draw, scales[p // self.batch_size]) for p, (index, draw) in enumerate(draws)])
