"""Per-pixel preprocessing of a stacked batch: raw buffers -> the batch's named tensors, wherever it runs.

The loader's workers read, crop and mirror raw buffers (:mod:`wdss.data.dataset`) and stack them into a
:class:`RawBatch`. :meth:`RawBatch.build` then does all the per-pixel tensor work: it cleans the buffers (far
depth, depth normalised by each frame's range, unit normals, colour clip), point-samples the low-resolution
frame where no native one was read, computes BRDF factors, demodulates, warps the history and computes the
masks. It runs either in the workers (CPU machines) or on the accelerator after the transfer
(:meth:`wdss.data.datamodule.SceneDataModule.on_after_batch_transfer`): the same function on the same raw
batch, so both placements give one batch.

Previous frames of a training patch are read with a margin (``margins``: pixels on every side, the extent of
the motion vectors in the patch plus one for the bilinear taps), so that history warped from outside the
patch is history, not zeros; the warp samples them with that offset.
"""

from __future__ import annotations

from collections.abc import Iterable, Mapping
from dataclasses import dataclass, field, replace

import numpy as np
import torch
from torch import Tensor

from wdss.data.batch import GBUFFER_STACK, LR_GEOMETRY, LR_GUIDE
from wdss.ops.brdf import BRDF_KNEE, demodulate, extranet_brdf, safe_brdf, split_sum_brdf
from wdss.ops.sampling import lr_size, point_sample
from wdss.ops.warp import normalize_normals, spatial_mask, temporal_mask, warp_backward

__all__ = [
    "GBUFFER_STACK",
    "LR_GUIDE",
    "Preprocessing",
    "RawBatch",
    "brdf_of",
    "build_batch",
    "clean",
    "depth_range",
    "irradiance_of",
    "lr_guide",
    "prediction_color",
    "target_irradiance",
]

# The same switch where the command is not training: upscale and export take overrides of the training's preprocessing.
SANITIZE_ELSEWHERE = "wdss.upscale and wdss.export: +preprocessing.sanitize=true"


@dataclass
class Preprocessing:
    """How buffers become batch tensors (the ``data.preprocessing`` config)."""

    brdf: str = "extranet"  # extranet | split_sum
    # F below about this blends continuously towards 1 (wdss.ops.brdf.safe_brdf); 0: the hard switch at 1e-4,
    # which anti-aliased G-buffers break (every silhouette against the sky divides by ~0.01).
    brdf_knee: float = BRDF_KNEE
    demodulate: bool = True  # lr and history are irradiance (colour / F) rather than colour
    # Emitted light (the emission buffer) is subtracted from the colour before demodulation and added back at
    # high resolution: an emitter's colour is not F times an irradiance. true: every sequence must have the
    # buffer; auto: where a sequence has it (others emit nothing); false: never (the paper's demodulation).
    emission: bool | str = "auto"
    depth_far: float | None = 100.0  # depth beyond this is background: set to 0 (the authors' loader)
    depth_normalize: bool = True  # per-frame min-max normalisation of depth (DFASR); LR by its HR frame's range
    color_max: float | None = None  # clip HDR colour to [0, color_max] at load (the authors used 10)
    sanitize: bool = False  # replace non-finite values by 0 and count them, instead of failing
    spatial_thresholds: dict = field(default_factory=lambda: {"depth": 0.01, "normal": 0.9, "albedo": 0.1})

    def __post_init__(self) -> None:
        if self.brdf not in ("extranet", "split_sum"):
            raise ValueError(f"data.preprocessing.brdf must be 'extranet' or 'split_sum', got {self.brdf!r}")
        if self.emission not in (True, False, "auto"):
            raise ValueError(f"data.preprocessing.emission must be true, false or auto, got {self.emission!r}")
        if not isinstance(self.brdf_knee, int | float) or isinstance(self.brdf_knee, bool) or self.brdf_knee < 0:
            raise ValueError(f"data.preprocessing.brdf_knee must be a number >= 0, got {self.brdf_knee!r}")

    @property
    def separates_emission(self) -> bool:
        """Whether the emission buffer is read: subtracted before demodulation, added back to the prediction."""
        return self.demodulate and self.emission is not False

    @property
    def brdf_buffers(self) -> set[str]:
        extra = {"roughness", "nov"} if self.brdf == "split_sum" else set()
        return {"base_color", "metallic", "specular"} | extra


def _far(depth: Tensor, far: float | None) -> Tensor:
    return depth if far is None else torch.where(depth > far, torch.zeros_like(depth), depth)


def depth_range(depth: np.ndarray | Tensor, far: float | None) -> tuple[float, float]:
    """The min-max normalisation range of one whole frame's depth, after the far clamp (float32 values)."""
    if not isinstance(depth, Tensor):  # a cached frame is read-only, which torch would warn about
        depth = np.require(depth, np.float32, ["W"])
    t = _far(torch.as_tensor(depth), far)
    return float(t.min()), float(t.max())


def clean(buffers: dict[str, Tensor], prep: Preprocessing, ranges: Tensor | None) -> dict[str, Tensor]:
    """Stacked ``(N, C, H, W)`` buffers cleaned: far depth set to 0 and normalised by each sample's frame range
    (``ranges``: ``(N, 2)`` min and max), normals of unit length, colour clipped to ``color_max``."""
    out = {}
    for name, t in buffers.items():
        if name == "depth":
            t = _far(t, prep.depth_far)
            if prep.depth_normalize:
                lo, hi = (ranges[:, i].to(t.dtype).view(-1, 1, 1, 1) for i in (0, 1))
                t = (t - lo) / (1e-6 + torch.clamp(hi, min=1.0) - lo)
        elif name == "normal":
            t = normalize_normals(t)
        elif name == "color" and prep.color_max is not None:
            t = t.clamp(0.0, prep.color_max)
        out[name] = t
    return out


def _crop(t: Tensor, margin: int, height: int, width: int) -> Tensor:
    return t[..., margin : margin + height, margin : margin + width] if margin else t


@dataclass
class RawBatch:
    """A stacked batch of raw buffers per role and what turns it into the batch (:meth:`build`).

    ``roles``: role -> buffer -> ``(N, C, H, W)`` float16 or float32 as read (``prev`` and ``prev2`` with their
    ``margins``);
    ``ranges``: role -> ``(N, 2)`` depth ranges of each sample's whole frame; ``sampled``: LR role -> buffers to
    point-sample from its HR role. Moves to a device with :meth:`to` (Lightning calls it) and pins with
    :meth:`pin_memory` (the DataLoader does).
    """

    keys: tuple[str, ...]
    prep: Preprocessing
    scale: float
    roles: dict[str, dict[str, Tensor]]
    ranges: dict[str, Tensor]
    margins: dict[str, int]
    sampled: dict[str, tuple[str, ...]]
    sequence: list[str]
    frame: Tensor
    lr_jitter: Tensor  # (N, 2): where each sample's LR pixels were shaded, from their centres (0: point-sampled)

    def _apply(self, fn) -> RawBatch:
        roles = {role: {k: fn(v) for k, v in buffers.items()} for role, buffers in self.roles.items()}
        ranges = {k: fn(v) for k, v in self.ranges.items()}
        return replace(self, roles=roles, ranges=ranges, frame=fn(self.frame), lr_jitter=fn(self.lr_jitter))

    def to(self, device: torch.device | str, non_blocking: bool = False) -> RawBatch:
        return self._apply(lambda t: t.to(device, non_blocking=non_blocking))

    def pin_memory(self) -> RawBatch:
        return self._apply(lambda t: t.pin_memory())

    def __len__(self) -> int:
        return len(self.sequence)

    def build(self) -> dict:
        """The named batch tensors (:mod:`wdss.data.batch`), on the raw batch's device."""
        prep = self.prep
        roles = {
            role: clean({k: v.float() for k, v in buffers.items()}, prep, self.ranges.get(role))
            for role, buffers in self.roles.items()
        }
        height, width = next(iter(roles["hr"].values())).shape[-2:] if roles["hr"] else (0, 0)
        for low, high in (("lr", "hr"), ("prev_lr", "prev")):  # no native folder: point-sample the HR frame
            if self.sampled.get(low):
                size = lr_size(height, width, self.scale)
                margin = self.margins.get(high, 0)
                roles[low] = {
                    n: point_sample(_crop(roles[high][n], margin, height, width), size) for n in self.sampled[low]
                }
        batch = build_batch(set(self.keys), roles, prep, self.margins, self.lr_jitter)
        batch["scale"] = torch.full((len(self),), self.scale, device=self.frame.device)
        batch["sequence"] = list(self.sequence)
        batch["frame"] = self.frame
        return batch


def brdf_of(buffers: dict[str, Tensor], prep: Preprocessing) -> Tensor:
    """The safe BRDF factor (1 where F vanishes) of a set of buffers."""
    if prep.brdf == "split_sum":
        raw = split_sum_brdf(
            buffers["base_color"], buffers["metallic"], buffers["specular"], buffers["roughness"], buffers["nov"]
        )
    else:
        raw = extranet_brdf(buffers["base_color"], buffers["metallic"], buffers["specular"])
    return safe_brdf(raw, knee=float(prep.brdf_knee))


def irradiance_of(buffers: dict[str, Tensor], prep: Preprocessing, brdf: Tensor | None = None) -> Tensor:
    """What a frame's colour becomes as an input: its colour less its emitted part (where emission is separated;
    clamped at 0, as a denoised colour may fall a little below its exact emission) over its BRDF factor (``brdf``,
    or the buffers' own), or the colour itself when ``prep.demodulate`` is off."""
    if not prep.demodulate:
        return buffers["color"]
    color = buffers["color"]
    if prep.separates_emission:
        color = (color - buffers["emission"]).clamp_min(0.0)
    return demodulate(color, brdf_of(buffers, prep) if brdf is None else brdf)


def lr_guide(lr: Mapping[str, Tensor]) -> Tensor:
    """The G-buffer the LR colour was shaded with, ``(N, 7, h, w)`` (albedo, depth, normal; cleaned as the HR stack
    is): the LR role's own buffers. Which those are is the data's sampling convention, decided once where the frame
    is read (:meth:`wdss.data.dataset.FrameDataset.native_lr`): a native LR folder's own G-buffer (rendered at the
    LR sample positions, as an engine's LR frame is), else the HR G-buffer point-sampled at the LR pixels, exactly
    the pixels the point-sampled LR colour came from. Every LR-side guide of a model reads this key rather than
    sampling the HR stack itself, which is right only for point-sampled data."""
    return torch.cat([lr[name] for name in LR_GUIDE], dim=1)


def prediction_color(irradiance: Tensor | None, batch: Mapping[str, Tensor]) -> Tensor | None:
    """A predicted irradiance remodulated with the batch's HR BRDF factor, plus its HR emission where the data
    separates emission (``None`` stays ``None``: display-space models predict no irradiance)."""
    if irradiance is None:
        return None
    color = irradiance * batch["brdf"]
    return color + batch["emission"] if "emission" in batch else color


def target_irradiance(batch: Mapping[str, Tensor]) -> Tensor:
    """The HR target's irradiance, what :func:`prediction_color` remodulates: (target - emission) / F."""
    target = batch["target"] - batch["emission"] if "emission" in batch else batch["target"]
    return target / batch["brdf"]


def build_batch(
    keys: Iterable[str],
    roles: dict[str, dict[str, Tensor]],
    prep: Preprocessing,
    margins: dict[str, int] | None = None,
    lr_jitter: Tensor | None = None,
) -> dict[str, Tensor]:
    """The named batch tensors from cleaned, stacked ``(N, C, H, W)`` buffers of each role.

    ``margins``: pixels on every side by which ``prev`` and ``prev2`` extend beyond the current frame's window;
    ``lr_jitter`` (N, 2): where the LR pixels were shaded, from their centres (the spatial mask places them there;
    the key of that name passes it on; ``None``: at their centres).
    """
    keys = set(keys)
    m1, m2 = (margins or {}).get("prev", 0), (margins or {}).get("prev2", 0)
    batch = _hr_keys(keys, roles["hr"], prep)
    batch |= _lr_keys(keys, roles, prep, lr_jitter)
    batch |= _guide_keys(keys, roles["hr"], roles["lr"], prep, lr_jitter)
    batch |= _history_keys(keys, roles["hr"], roles["prev"], prep, m1)
    batch |= _other_keys(keys, roles, prep, m1, m2)
    return batch


def _hr_keys(keys: set[str], hr: dict[str, Tensor], prep: Preprocessing) -> dict[str, Tensor]:
    """The HR frame's keys: the target, its BRDF factor and its emission (where it is separated)."""
    batch: dict[str, Tensor] = {}
    if "target" in keys:
        batch["target"] = hr["color"]
    if "brdf" in keys:
        batch["brdf"] = brdf_of(hr, prep)
    if "emission" in keys and prep.separates_emission:
        batch["emission"] = hr["emission"]
    return batch


def _lr_keys(
    keys: set[str], roles: dict[str, dict[str, Tensor]], prep: Preprocessing, lr_jitter: Tensor | None
) -> dict[str, Tensor]:
    """The LR frame's keys: its irradiance, BRDF factor, colour and guide, and where its pixels were shaded."""
    lr = roles["lr"]
    batch: dict[str, Tensor] = {}
    if "lr" in keys or "lr_brdf" in keys:
        lr_brdf = brdf_of(lr, prep) if (prep.demodulate or "lr_brdf" in keys) else None
        if "lr" in keys:
            batch["lr"] = irradiance_of(lr, prep, lr_brdf)
        if "lr_brdf" in keys:
            batch["lr_brdf"] = lr_brdf
    if "lr_color" in keys:
        batch["lr_color"] = lr["color"]
    if "lr_guide" in keys:
        batch["lr_guide"] = lr_guide(lr)
    if "lr_jitter" in keys:
        any_buffer = next(t for buffers in roles.values() for t in buffers.values())
        jitter = torch.zeros(len(any_buffer), 2) if lr_jitter is None else lr_jitter
        batch["lr_jitter"] = jitter.to(any_buffer.device, torch.float32)
    return batch


def _guide_keys(
    keys: set[str], hr: dict[str, Tensor], lr: dict[str, Tensor], prep: Preprocessing, lr_jitter: Tensor | None
) -> dict[str, Tensor]:
    """The HR G-buffer and the spatial mask (the HR G-buffer against the LR frame's own)."""
    batch: dict[str, Tensor] = {}
    if "gbuffer" in keys:
        batch["gbuffer"] = torch.cat([hr[name] for name in GBUFFER_STACK], dim=1)
    if "spatial_mask" in keys:
        t = prep.spatial_thresholds
        batch["spatial_mask"] = spatial_mask(
            hr,
            lr,
            depth_threshold=t["depth"],
            normal_threshold=t["normal"],
            albedo_threshold=t["albedo"],
            jitter=lr_jitter,
        )
    return batch


def _history_keys(
    keys: set[str], hr: dict[str, Tensor], prev: dict[str, Tensor], prep: Preprocessing, m1: int
) -> dict[str, Tensor]:
    """The previous frame warped by the motion vectors: its irradiance (the history) and the temporal mask of its
    G-buffer against the current one (``prev`` extends ``m1`` pixels beyond the current window)."""
    batch: dict[str, Tensor] = {}
    if "history" in keys or "temporal_mask" in keys:
        motion = hr["motion"]
        if "history" in keys:
            previous = irradiance_of(prev, prep)
            batch["history"] = warp_backward(previous, motion, origin=(m1, m1))
        if "temporal_mask" in keys:
            names = ("depth", "base_color", "normal")
            stacked = torch.cat([prev[name] for name in names], dim=1)  # one warp for all
            warped = dict(zip(names, warp_backward(stacked, motion, origin=(m1, m1)).split([1, 3, 3], 1), strict=True))
            batch["temporal_mask"] = temporal_mask(hr, warped)
    return batch


def _other_keys(
    keys: set[str], roles: dict[str, dict[str, Tensor]], prep: Preprocessing, m1: int, m2: int
) -> dict[str, Tensor]:
    """The motion vectors, the LR G-buffer, the previous LR frame, and the frame before the previous one warped to
    the current one (``prev2`` extends ``m2`` pixels beyond the current window)."""
    hr, lr, prev, prev_lr = roles["hr"], roles["lr"], roles["prev"], roles["prev_lr"]
    batch: dict[str, Tensor] = {}
    if "motion" in keys:
        batch["motion"] = hr["motion"]
    if "lr_gbuffer" in keys:
        batch["lr_gbuffer"] = torch.cat([lr[name] for name in LR_GEOMETRY], dim=1)
    if "prev_lr_color" in keys:
        batch["prev_lr_color"] = prev_lr["color"]
    if "prev_lr_gbuffer" in keys:
        batch["prev_lr_gbuffer"] = torch.cat([prev_lr[name] for name in LR_GEOMETRY], dim=1)
    if "history2" in keys:  # frame t-2 warped to t-1 (on t-1's window), then to t
        prev2 = roles["prev2"]
        older = irradiance_of(prev2, prep)
        onto_prev = warp_backward(older, prev["motion"], origin=(m2 - m1, m2 - m1))
        batch["history2"] = warp_backward(onto_prev, hr["motion"], origin=(m1, m1))
    return batch
