"""Frames on disk -> named training and evaluation batches.

:class:`FrameDataset` reads, per sample, only the buffers that the requested batch keys need (from the
current and previous high-resolution frame and, where one matches the scale, a native low-resolution
folder), cleans them (non-finite check, far-depth clamp, depth normalisation, unit normals), crops a patch
and mirrors it. :class:`Collate` then works on the whole batch, in the loader's worker: it picks the
batch's scale, point-samples the low-resolution frame where no native one was read, computes BRDF factors,
demodulates, warps the history and computes the masks. The batch keys are documented in
:mod:`wdss.data.datamodule`.
"""

from __future__ import annotations

import logging
from collections.abc import Iterable
from collections.abc import Sequence as Seq
from dataclasses import dataclass, field

import numpy as np
import torch
from torch import Tensor
from torch.utils.data import Dataset, Sampler

from wdss.data.brdf import demodulate, extranet_brdf, safe_brdf, split_sum_brdf
from wdss.data.layouts import BUFFERS, SceneError, Sequence
from wdss.data.sampling import flip, lr_size, point_sample, scale_matches
from wdss.data.warp import normalize_normals, spatial_mask, temporal_mask, warp_backward

__all__ = ["BATCH_KEYS", "GBUFFER_STACK", "Collate", "EpochSampler", "FrameDataset", "Preprocessing", "requirements"]

log = logging.getLogger(__name__)

# The high-resolution G-buffer stack of the network, in channel order (11 channels).
GBUFFER_STACK = ("base_color", "depth", "normal", "specular", "roughness", "nov", "metallic")
BATCH_KEYS = (
    "target",
    "brdf",
    "lr",
    "lr_color",
    "lr_brdf",
    "gbuffer",
    "spatial_mask",
    "history",
    "temporal_mask",
    "motion",
    "lr_gbuffer",
    "prev_lr_color",
    "prev_lr_gbuffer",
    "history2",
)
_MASK_BUFFERS = {"depth", "normal", "base_color"}
ROLES = ("hr", "lr", "prev", "prev_lr", "prev2")
_OFFSET = {"hr": 0, "lr": 0, "prev": 1, "prev_lr": 1, "prev2": 2}  # frames back from the sample's frame


@dataclass
class Preprocessing:
    """How buffers become batch tensors (the ``data.preprocessing`` config)."""

    brdf: str = "extranet"  # extranet | split_sum
    demodulate: bool = True  # lr and history are irradiance (colour / F) rather than colour
    depth_far: float | None = 100.0  # depth beyond this is background: set to 0 (the authors' loader)
    depth_normalize: bool = True  # per-frame min-max normalisation of depth (DFASR); LR by its HR frame's range
    color_max: float | None = None  # clip HDR colour to [0, color_max] at load (the authors used 10)
    sanitize: bool = False  # replace non-finite values by 0 and count them, instead of failing
    spatial_thresholds: dict = field(default_factory=lambda: {"depth": 0.01, "normal": 0.9, "albedo": 0.1})

    def __post_init__(self) -> None:
        if self.brdf not in ("extranet", "split_sum"):
            raise ValueError(f"data.preprocessing.brdf must be 'extranet' or 'split_sum', got {self.brdf!r}")

    @property
    def brdf_buffers(self) -> set[str]:
        extra = {"roughness", "nov"} if self.brdf == "split_sum" else set()
        return {"base_color", "metallic", "specular"} | extra


def requirements(keys: Iterable[str], prep: Preprocessing) -> dict[str, set[str]]:
    """Buffers per role for ``keys``: ``hr`` (current frame), ``lr`` (current, low resolution), ``prev`` (previous
    frame), ``prev_lr`` (previous, low resolution), ``prev2`` (the frame before the previous one)."""
    keys = set(keys)
    unknown = keys - set(BATCH_KEYS) - {"scale"}
    if unknown:
        raise ValueError(f"unknown batch keys {sorted(unknown)}: expected some of {', '.join(BATCH_KEYS)}")
    need: dict[str, set[str]] = {role: set() for role in ROLES}
    brdf = prep.brdf_buffers
    if "target" in keys:
        need["hr"] |= {"color"}
    if "brdf" in keys:
        need["hr"] |= brdf
    if "lr" in keys:
        need["lr"] |= {"color"} | (brdf if prep.demodulate else set())
    if "lr_color" in keys:
        need["lr"] |= {"color"}
    if "lr_brdf" in keys:
        need["lr"] |= brdf
    if "gbuffer" in keys:
        need["hr"] |= set(GBUFFER_STACK)
    if "spatial_mask" in keys:
        need["hr"] |= _MASK_BUFFERS
        need["lr"] |= _MASK_BUFFERS
    if "history" in keys:
        need["prev"] |= {"color"} | (brdf if prep.demodulate else set())
        need["hr"] |= {"motion"}
    if "temporal_mask" in keys:
        need["hr"] |= _MASK_BUFFERS | {"motion"}
        need["prev"] |= _MASK_BUFFERS
    if "motion" in keys:
        need["hr"] |= {"motion"}
    if "lr_gbuffer" in keys:
        need["lr"] |= {"depth", "normal"}
    if "prev_lr_color" in keys:
        need["prev_lr"] |= {"color"}
    if "prev_lr_gbuffer" in keys:
        need["prev_lr"] |= {"depth", "normal"}
    if "history2" in keys:
        need["prev2"] |= {"color"} | (brdf if prep.demodulate else set())
        need["prev"] |= {"motion"}
        need["hr"] |= {"motion"}
    return need


def _far(depth: Tensor, prep: Preprocessing) -> Tensor:
    return depth if prep.depth_far is None else torch.where(depth > prep.depth_far, torch.zeros_like(depth), depth)


def _depth_range(depth: np.ndarray, prep: Preprocessing) -> tuple[Tensor, Tensor]:
    """The min-max normalisation range of one frame's depth (after the far clamp)."""
    t = _far(torch.from_numpy(depth), prep)
    return t.min(), t.max()


def _clean(
    buffers: dict[str, np.ndarray], prep: Preprocessing, depth_range: tuple[Tensor, Tensor] | None = None
) -> dict[str, Tensor]:
    """Tensors of one frame's buffers; depth is normalised by ``depth_range`` (default: its own min and max)."""
    out = {}
    for name, value in buffers.items():
        t = torch.from_numpy(value)
        if name == "depth":
            t = _far(t, prep)
            if prep.depth_normalize:
                lo, hi = depth_range if depth_range is not None else (t.min(), t.max())
                t = (t - lo) / (1e-6 + torch.clamp(hi, min=1.0) - lo)
        elif name == "normal":
            t = normalize_normals(t[None])[0]
        elif name == "color" and prep.color_max is not None:
            t = t.clamp(0.0, prep.color_max)
        out[name] = t
    return out


class FrameDataset(Dataset):
    """Samples of one split: every frame of every sequence (that has history, where history is needed).

    ``scale``: a number (fixed scale) or a ``(low, high)`` range sampled per batch by :class:`Collate`.
    ``patch``: high-resolution patch size for training, ``None`` for full frames.
    ``first_frame``: ``"skip"`` leaves out frames without a previous frame when history is needed;
    ``"zeros"`` keeps them with zero history.
    ``sequence_length``: ``T > 1`` makes each sample ``T`` consecutive frames ending at the item's frame,
    cropped and mirrored alike (``{"steps": [...]}``), for recurrent training.
    """

    def __init__(
        self,
        sequences: Seq[Sequence],
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
    ) -> None:
        if first_frame not in ("skip", "zeros"):
            raise ValueError(f"first_frame must be 'skip' or 'zeros', got {first_frame!r}")
        if sequence_length < 1:
            raise ValueError(f"sequence_length must be >= 1, got {sequence_length}")
        self.sequences = list(sequences)
        self.keys = tuple(keys)
        self.prep = preprocessing or Preprocessing()
        self.scale = scale
        self.patch = patch
        self.flips = flips
        self.first_frame = first_frame
        self.sequence_length = sequence_length
        self.seed = seed
        self.need = requirements(self.keys, self.prep)
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

    def native_lr(self, seq: Sequence) -> int | None:
        """The native low-resolution folder that matches a fixed scale, if any."""
        if isinstance(self.scale, (tuple, list)) or not self.need["lr"]:
            return None
        for height in seq.resolutions[1:]:
            if scale_matches(seq.hr, height, float(self.scale)):
                return height
        return None

    def _frame(self, seq: Sequence, frame: int, lr_height: int | None) -> dict:
        """The uncropped buffers of one frame in each role (zeros for history before the first frame)."""
        need = self.need
        # Native LR depth is normalised with the range of its HR frame, as point-sampled LR depth (cut from the
        # cleaned HR frame) is: the spatial mask compares HR depth with LR depth, and both paths must agree. So
        # the HR depth is read (and dropped after) where only the LR depth is needed.
        hr_of = {"lr": "hr", "prev_lr": "prev"}
        ranged = bool(lr_height) and self.prep.depth_normalize
        extra = {hr: {"depth"} - need[hr] for lr, hr in hr_of.items() if ranged and "depth" in need[lr]}
        # Without a native low-resolution folder, LR roles are point-sampled from their HR frame in Collate.
        reads = {
            "hr": (frame, seq.hr, need["hr"] | (set() if lr_height else need["lr"]) | extra.get("hr", set())),
            "lr": (frame, lr_height, need["lr"] if lr_height else set()),
            "prev": (
                frame - 1,
                seq.hr,
                need["prev"] | (set() if lr_height else need["prev_lr"]) | extra.get("prev", set()),
            ),
            "prev_lr": (frame - 1, lr_height, need["prev_lr"] if lr_height else set()),
            "prev2": (frame - 2, seq.hr, need["prev2"]),
        }
        available = set(seq.frames)
        out: dict = {"sequence": seq.name, "frame": frame}
        shapes: dict[int | None, tuple[int, int]] = {}
        ranges: dict[str, tuple[Tensor, Tensor]] = {}  # HR role -> its depth range, for the native LR role
        for role, (number, height, buffers) in reads.items():
            if not buffers:
                out[role] = {}
            elif number in available:
                raw = seq.read(number, height, sorted(buffers), sanitize=self.prep.sanitize)
                if ranged and role in hr_of.values() and "depth" in raw:
                    ranges[role] = _depth_range(raw["depth"], self.prep)
                clean = _clean(raw, self.prep, ranges.get(hr_of[role]) if role in hr_of else None)
                out[role] = {k: v for k, v in clean.items() if k not in extra.get(role, ())}
                shapes.setdefault(height, next(iter(raw.values())).shape[-2:])
            else:  # history before the first frame, kept with zeros (first_frame="zeros")
                shape = shapes.get(height) or self._shape(seq, height)
                out[role] = {b: torch.zeros(BUFFERS[b], *shape) for b in buffers - extra.get(role, set())}
        if lr_height and seq.hr in shapes and lr_height in shapes:
            hr_shape, lr_shape = shapes[seq.hr], shapes[lr_height]
            expected = lr_size(*hr_shape, float(self.scale))
            if tuple(lr_shape) != expected:
                raise SceneError(
                    f"sequence {seq.name!r}, frame {frame}: the {lr_height}P frame is {lr_shape[1]}x{lr_shape[0]}, "
                    f"but {hr_shape[1]}x{hr_shape[0]} at scale {self.scale} needs {expected[1]}x{expected[0]}"
                )
        return out

    def _shape(self, seq: Sequence, height: int) -> tuple[int, int]:
        """The frame size at ``height`` (from one plane of the first frame), for zero history."""
        plane = seq.read(seq.frames[0], height, ["color"] if seq.has("color", height) else ["depth"])
        return next(iter(plane.values())).shape[-2:]

    def __getitem__(self, index: int | tuple[int, int]) -> dict:
        # (index, epoch) from EpochSampler: all randomness is a function of (seed, epoch, index), so a run that
        # is killed and resumed from its last epoch sees exactly the samples an uninterrupted one would.
        index, epoch = index if isinstance(index, tuple) else (index, None)
        rng = torch.Generator().manual_seed(_mix(self.seed, epoch, index)) if epoch is not None else None
        seq_index, frame = self.items[index]
        seq = self.sequences[seq_index]
        lr_height = self.native_lr(seq)
        steps = [self._frame(seq, f, lr_height) for f in range(frame - self.sequence_length + 1, frame + 1)]
        window = self._window(steps[0], lr_height and seq.hr / lr_height, rng)
        flips = (False, False)
        if self.flips:
            flips = (bool(torch.rand((), generator=rng) < 0.5), bool(torch.rand((), generator=rng) < 0.5))
        for step in steps:
            self._crop(step, window)
            if any(flips):
                for role in ROLES:
                    camera = seq.camera(step["frame"] - _OFFSET[role])
                    camera = seq.camera(step["frame"]) if camera is None else camera
                    step[role] = flip(step[role], horizontal=flips[0], vertical=flips[1], camera=camera)
            step["seed"] = _mix(self.seed, epoch, index) if epoch is not None else None
        return steps[0] if self.sequence_length == 1 else {"steps": steps}

    def _window(self, sample: dict, native_scale: float | None, rng: torch.Generator | None) -> tuple | None:
        """A random patch position shared by every step of a sample: HR ``(y, x, size)`` and LR likewise."""
        if self.patch is None:
            return None
        full = next(iter(sample["hr"].values()), None)
        height, width = full.shape[-2:] if full is not None else (0, 0)
        size = self.patch
        if height < size or width < size:
            raise SceneError(f"patch size {size} is larger than the frame ({height}x{width})")
        if native_scale:  # crop on the low-resolution grid so both patches cover the same pixels
            step = round(native_scale)
            size -= size % step  # e.g. 64 -> 63 at 3x: the largest patch that a native LR patch covers exactly
            y = int(torch.randint(0, (height - size) // step + 1, (), generator=rng)) * step
            x = int(torch.randint(0, (width - size) // step + 1, (), generator=rng)) * step
            return (y, x, size), (y // step, x // step, size // step)
        y = int(torch.randint(0, height - size + 1, (), generator=rng))
        x = int(torch.randint(0, width - size + 1, (), generator=rng))
        return (y, x, size), None

    @staticmethod
    def _crop(sample: dict, window: tuple | None) -> None:
        if window is None:
            return
        for role, box in (
            ("hr", window[0]),
            ("prev", window[0]),
            ("prev2", window[0]),
            ("lr", window[1]),
            ("prev_lr", window[1]),
        ):
            if box is not None:
                y, x, size = box
                sample[role] = {k: v[..., y : y + size, x : x + size] for k, v in sample[role].items()}


class Collate:
    """Stack samples and turn their buffers into the batch's named tensors (runs in loader workers)."""

    def __init__(self, keys: Iterable[str], preprocessing: Preprocessing, scale: float | tuple[float, float]):
        self.keys = set(keys) | {"scale"}
        self.prep = preprocessing
        self.scale = scale

    def pick_scale(self, seed: int | None = None) -> float:
        """The batch's scale: fixed, or drawn from the range (from the first sample's seed when it has one)."""
        if isinstance(self.scale, (tuple, list)):
            low, high = self.scale
            rng = torch.Generator().manual_seed(seed) if seed is not None else None
            return float(low + (high - low) * torch.rand((), generator=rng).item())
        return float(self.scale)

    def __call__(self, samples: list[dict]) -> dict:
        first = samples[0]["steps"][0] if "steps" in samples[0] else samples[0]
        scale = self.pick_scale(first.get("seed"))
        if "steps" in samples[0]:  # sequences: one batch per time step, all at the batch's scale
            length = len(samples[0]["steps"])
            return {"steps": [self.batch([s["steps"][t] for s in samples], scale) for t in range(length)]}
        return self.batch(samples, scale)

    def batch(self, samples: list[dict], scale: float) -> dict:
        def stack(role: str) -> dict[str, Tensor]:
            names = samples[0][role].keys()
            return {name: torch.stack([s[role][name] for s in samples]) for name in names}

        roles = {role: stack(role) for role in ROLES}
        need = requirements(self.keys - {"scale"}, self.prep)
        height, width = next(iter(roles["hr"].values())).shape[-2:] if roles["hr"] else (0, 0)
        for low, high in (("lr", "hr"), ("prev_lr", "prev")):  # no native folder: point-sample the HR frame
            if need[low] and not roles[low]:
                size = lr_size(height, width, scale)
                roles[low] = {name: point_sample(roles[high][name], size) for name in need[low]}
        batch = build_batch(self.keys, roles, self.prep)
        batch["scale"] = torch.full((len(samples),), scale)
        batch["sequence"] = [s["sequence"] for s in samples]
        batch["frame"] = torch.tensor([s["frame"] for s in samples])
        return batch


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
    """

    def __init__(
        self, size: int, seed: int = 0, shuffle: bool = True, repeats: int = 1, rank: int = 0, world_size: int = 1
    ) -> None:
        if repeats < 1:
            raise ValueError(f"data.patches_per_frame must be >= 1, got {repeats}")
        if not 0 <= rank < world_size:
            raise ValueError(f"rank {rank} is not one of {world_size} processes")
        if size * repeats < world_size:  # an empty share: that rank would never reach the others' collectives
            raise ValueError(f"{size * repeats} samples cannot be shared among {world_size} processes")
        self.size, self.seed, self.shuffle, self.epoch, self.repeats = size, seed, shuffle, 0, repeats
        self.rank, self.world_size = rank, world_size

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
        return iter([(int(v) % self.size, self.epoch * self.repeats + int(v) // self.size) for v in order])


def brdf_of(buffers: dict[str, Tensor], prep: Preprocessing) -> Tensor:
    """The safe BRDF factor (1 where F vanishes) of a set of buffers."""
    if prep.brdf == "split_sum":
        raw = split_sum_brdf(
            buffers["base_color"], buffers["metallic"], buffers["specular"], buffers["roughness"], buffers["nov"]
        )
    else:
        raw = extranet_brdf(buffers["base_color"], buffers["metallic"], buffers["specular"])
    return safe_brdf(raw)


def build_batch(keys: set[str], roles: dict[str, dict[str, Tensor]], prep: Preprocessing) -> dict[str, Tensor]:
    """The named batch tensors from stacked ``(N, C, H, W)`` buffers of each role."""
    hr, lr, prev, prev_lr = roles["hr"], roles["lr"], roles["prev"], roles["prev_lr"]
    batch: dict[str, Tensor] = {}
    if "target" in keys:
        batch["target"] = hr["color"]
    if "brdf" in keys:
        batch["brdf"] = brdf_of(hr, prep)
    if "lr" in keys or "lr_brdf" in keys:
        lr_brdf = brdf_of(lr, prep) if (prep.demodulate or "lr_brdf" in keys) else None
        if "lr" in keys:
            batch["lr"] = demodulate(lr["color"], lr_brdf) if prep.demodulate else lr["color"]
        if "lr_brdf" in keys:
            batch["lr_brdf"] = lr_brdf
    if "lr_color" in keys:
        batch["lr_color"] = lr["color"]
    if "gbuffer" in keys:
        batch["gbuffer"] = torch.cat([hr[name] for name in GBUFFER_STACK], dim=1)
    if "spatial_mask" in keys:
        t = prep.spatial_thresholds
        batch["spatial_mask"] = spatial_mask(
            hr, lr, depth_threshold=t["depth"], normal_threshold=t["normal"], albedo_threshold=t["albedo"]
        )
    if "history" in keys or "temporal_mask" in keys:
        motion = hr["motion"]
        if "history" in keys:
            previous = demodulate(prev["color"], brdf_of(prev, prep)) if prep.demodulate else prev["color"]
            batch["history"] = warp_backward(previous, motion)
        if "temporal_mask" in keys:
            names = ("depth", "base_color", "normal")
            stacked = warp_backward(torch.cat([prev[name] for name in names], dim=1), motion)  # one warp for all
            warped = dict(zip(names, stacked.split([1, 3, 3], 1), strict=True))
            batch["temporal_mask"] = temporal_mask(hr, warped)
    if "motion" in keys:
        batch["motion"] = hr["motion"]
    if "lr_gbuffer" in keys:
        batch["lr_gbuffer"] = torch.cat([lr["depth"], lr["normal"]], dim=1)
    if "prev_lr_color" in keys:
        batch["prev_lr_color"] = prev_lr["color"]
    if "prev_lr_gbuffer" in keys:
        batch["prev_lr_gbuffer"] = torch.cat([prev_lr["depth"], prev_lr["normal"]], dim=1)
    if "history2" in keys:  # frame t-2 warped to t-1, then to t
        prev2 = roles["prev2"]
        older = demodulate(prev2["color"], brdf_of(prev2, prep)) if prep.demodulate else prev2["color"]
        batch["history2"] = warp_backward(warp_backward(older, prev["motion"]), hr["motion"])
    return batch
