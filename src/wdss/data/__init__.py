"""Scene data: EXR layouts, packed stores, need-driven reading, preprocessing and the LightningDataModule.

Nothing here knows about models: the model declares the batch keys it consumes, and the data side reads
and computes exactly those (see :mod:`wdss.data.datamodule` for the keys).
"""

from wdss.data.datamodule import SceneDataModule
from wdss.data.dataset import BATCH_KEYS, GBUFFER_STACK, Collate, FrameDataset, Preprocessing, requirements
from wdss.data.exr import ExrError, read_exr, write_exr
from wdss.data.layouts import BUFFERS, DFASRLayout, SceneError, Sequence, UnrealLayout, discover_sequences
from wdss.data.packed import PackedSequence
from wdss.data.preprocess import RawBatch
from wdss.ops.brdf import demodulate, extranet_brdf, ggx_lut, remodulate, safe_brdf, split_sum_brdf
from wdss.ops.sampling import flip, lr_size, point_sample
from wdss.ops.tonemap import gamma, hable, reinhard, srgb, tonemap
from wdss.ops.warp import spatial_mask, temporal_mask, warp_backward

__all__ = [
    "BATCH_KEYS",
    "BUFFERS",
    "GBUFFER_STACK",
    "Collate",
    "DFASRLayout",
    "ExrError",
    "FrameDataset",
    "PackedSequence",
    "Preprocessing",
    "RawBatch",
    "SceneDataModule",
    "SceneError",
    "Sequence",
    "UnrealLayout",
    "demodulate",
    "discover_sequences",
    "extranet_brdf",
    "flip",
    "gamma",
    "ggx_lut",
    "hable",
    "lr_size",
    "point_sample",
    "read_exr",
    "reinhard",
    "remodulate",
    "requirements",
    "safe_brdf",
    "spatial_mask",
    "split_sum_brdf",
    "srgb",
    "temporal_mask",
    "tonemap",
    "warp_backward",
    "write_exr",
]
