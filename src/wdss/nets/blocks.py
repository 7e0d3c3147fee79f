"""Building blocks of the WDSS network (docs/reference.md section 2): all 3x3 convolutions with bias, no norms."""

from __future__ import annotations

import torch
import torch.nn.functional as F
from torch import Tensor, nn

__all__ = ["DoubleResidual", "GatedConv", "RIRBlock", "conv3x3", "fold_rir_blocks", "from_log", "scale_exit", "to_log"]


def conv3x3(cin: int, cout: int, dilation: int = 1) -> nn.Conv2d:
    return nn.Conv2d(cin, cout, 3, padding=dilation, dilation=dilation)


# The log1p space the networks read irradiance (and colour) in and predict it in.
LOG_MAX = 20.0  # log1p(4.9e8): far above any radiance, far below float32 overflow in expm1


def to_log(x: Tensor) -> Tensor:
    """``log1p`` of non-negative values (negatives clamped to 0)."""
    return torch.log1p(x.clamp_min(0))


def from_log(x: Tensor) -> Tensor:
    """The inverse of :func:`to_log`, clamped to ``[0, expm1(LOG_MAX)]``."""
    return torch.expm1(x.clamp(0.0, LOG_MAX))


EXIT_SCALE = 0.1


@torch.no_grad()
def scale_exit(conv: nn.Conv2d, scale: float = EXIT_SCALE) -> None:
    """Shrink the last convolution of a network that adds to a skip, so that it starts near the skip. Not to zero:
    a zero exit passes no gradient to the layers before it, which then stay at their initialisation for long."""
    conv.weight.mul_(scale)
    if conv.bias is not None:
        conv.bias.zero_()


class DoubleResidual(nn.Module):
    """``x + ReLU(conv(ReLU(conv(x))))`` (DFASR's G-buffer encoder block)."""

    def __init__(self, channels: int) -> None:
        super().__init__()
        self.conv1 = conv3x3(channels, channels)
        self.conv2 = conv3x3(channels, channels)

    def forward(self, x: Tensor) -> Tensor:
        return x + F.relu(self.conv2(F.relu(self.conv1(x))))


class RIRBlock(nn.Module):
    """Re-parameterisable residual-in-residual block: ``ReLU(x + reduce(e + conv3x3(e)))``, ``e = expand(x)``.

    Training form: a 1x1 expansion to ``expansion * c`` (no bias, so that zero padding means the same
    before and after folding), a 3x3 convolution with an identity around it, a 1x1 reduction, and an identity
    around the whole. Everything before the ReLU is linear, so :meth:`reparameterize` folds it into one 3x3
    convolution with the same outputs, borders included.
    """

    def __init__(self, channels: int, expansion: int = 2) -> None:
        super().__init__()
        hidden = channels * expansion
        self.expand = nn.Conv2d(channels, hidden, 1, bias=False)
        self.conv = conv3x3(hidden, hidden)
        self.reduce = nn.Conv2d(hidden, channels, 1)
        self.fused: nn.Conv2d | None = None

    def forward(self, x: Tensor) -> Tensor:
        if self.fused is not None:
            return F.relu(self.fused(x))
        e = self.expand(x)
        return F.relu(x + self.reduce(e + self.conv(e)))

    @torch.no_grad()
    def reparameterize(self) -> None:
        """Fold expand -> (identity + 3x3) -> reduce -> + identity into one 3x3 convolution."""
        channels, hidden = self.expand.in_channels, self.expand.out_channels
        eye_h = torch.eye(hidden, dtype=self.conv.weight.dtype, device=self.conv.weight.device)
        inner = self.conv.weight.clone()
        inner[:, :, 1, 1] += eye_h  # identity + 3x3 on e
        reduce = self.reduce.weight[:, :, 0, 0]
        weight = torch.einsum("oh,hikl,ic->ockl", reduce, inner, self.expand.weight[:, :, 0, 0])
        weight[:, :, 1, 1] += torch.eye(channels, dtype=weight.dtype, device=weight.device)
        fused = nn.Conv2d(channels, channels, 3, padding=1).to(weight.device, weight.dtype)
        fused.weight.copy_(weight)
        fused.bias.copy_(reduce @ self.conv.bias + self.reduce.bias)
        self.fused = fused


def fold_rir_blocks(net: nn.Module) -> None:
    """Fold every RIR block of ``net`` into its 3x3 convolution, in place, for inference (the same outputs)."""
    for block in net.modules():
        if isinstance(block, RIRBlock) and block.fused is None:
            block.reparameterize()


class GatedConv(nn.Module):
    """Lightweight gated convolution: ``conv(x) * sigmoid(conv_to_1_channel(x))``."""

    def __init__(self, cin: int, cout: int) -> None:
        super().__init__()
        self.feature = conv3x3(cin, cout)
        self.gate = conv3x3(cin, 1)

    def forward(self, x: Tensor) -> Tensor:
        return self.feature(x) * torch.sigmoid(self.gate(x))
