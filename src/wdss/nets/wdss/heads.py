"""The WDSS heads (the paper's architecture ablation): how the fusion branch and the Fourier INR share the channels
of the HR/2 cells before the exit convolution, and how their outputs merge.

A head holds no weights: :class:`~wdss.nets.wdss.network.WDSSNet` builds the fusion branch and the INR with the widths
its head gives for the channel count it computes, and merges their outputs as the head says. The ``head`` config
group (``conf/head/*.yaml``) chooses one by ``_target_``.
"""

from __future__ import annotations

from typing import ClassVar

import torch
from torch import Tensor

__all__ = ["HEADS", "FusionLL", "Head", "MultiINR", "SharedINR"]


class Head:
    """What a head declares; by default fusion and INR each predict every channel, summed, from one INR MLP."""

    name: ClassVar[str]  # the config group's option: what errors and tables call it
    needs_subbands: ClassVar[bool] = False  # True: the head splits wavelet subbands (a transform must give some)
    inr_groups: ClassVar[int] = 1  # INR MLPs, one per subband group, sharing the Fourier mapping

    def widths(self, channels: int) -> tuple[int, int]:
        """The fusion branch's and the INR's output channels, for ``channels`` (band-major) before the exit."""
        return channels, channels

    def merge(self, fusion: Tensor, inr: Tensor) -> Tensor:
        """The head's output from the fusion branch's and the INR's."""
        return fusion + inr

    def __repr__(self) -> str:
        return f"{type(self).__name__}()"

    def __eq__(self, other: object) -> bool:  # no state: a head is its class
        return type(self) is type(other)

    def __hash__(self) -> int:
        return hash(type(self))


class SharedINR(Head):
    """Fusion and INR outputs summed, all subbands from one INR MLP (the paper's network)."""

    name = "shared_inr"


class MultiINR(Head):
    """One INR MLP per subband, sharing the Fourier mapping (paper ablation "multi-INR"); fusion and INR summed."""

    name = "multi_inr"
    needs_subbands = True
    inr_groups = 4


class FusionLL(Head):
    """The fusion branch predicts LL, the INR the detail subbands (paper ablation "fusion->LL"), concatenated."""

    name = "fusion_ll"
    needs_subbands = True

    def widths(self, channels: int) -> tuple[int, int]:
        ll = channels // 4  # LL is the first quarter of band-major channels
        return ll, channels - ll

    def merge(self, fusion: Tensor, inr: Tensor) -> Tensor:
        return torch.cat([fusion, inr], 1)


# Every head, the paper's first (benchmarks and tests that cover them all).
HEADS: tuple[type[Head], ...] = (SharedINR, MultiINR, FusionLL)
