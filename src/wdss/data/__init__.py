"""Scene data: EXR layouts, packed stores, need-driven reading, preprocessing and the LightningDataModule.

Nothing here knows about models: the model declares the batch keys it consumes, and the data side reads
and computes exactly those (:mod:`wdss.data.batch` defines the keys; :mod:`wdss.data.source` the interface a
sequence is read through, EXR files and packed stores alike).
"""

from wdss.data.batch import BATCH_KEYS, GBUFFER_STACK, KEYS, BatchError, check_batch
from wdss.data.datamodule import SceneDataModule
from wdss.data.dataset import Collate, FrameDataset, Preprocessing, requirements
from wdss.data.exr import ExrError, read_exr, write_exr
from wdss.data.layouts import BUFFERS, DFASRLayout, SceneError, Sequence, UnrealLayout, discover_sequences
from wdss.data.packed import PackedSequence
from wdss.data.preprocess import RawBatch
from wdss.data.source import FrameSource
from wdss.ops.brdf import demodulate, extranet_brdf, ggx_lut, remodulate, safe_brdf, split_sum_brdf
from wdss.ops.sampling import flip, lr_size, point_sample
from wdss.ops.tonemap import gamma, hable, reinhard, srgb, tonemap
from wdss.ops.warp import spatial_mask, temporal_mask, warp_backward

__all__ = [
    "BATCH_KEYS",
    "BUFFERS",
    "GBUFFER_STACK",
    "KEYS",
    "BatchError",
    "Collate",
    "DFASRLayout",
    "ExrError",
    "FrameDataset",
    "FrameSource",
    "PackedSequence",
    "Preprocessing",
    "RawBatch",
    "SceneDataModule",
    "SceneError",
    "Sequence",
    "UnrealLayout",
    "check_batch",
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
