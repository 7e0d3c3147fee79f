"""The contract every network of wdss keeps, so that training, evaluation, benchmarks and export read what a network
declares instead of probing it for attributes it may not have.

A network (:class:`SuperResolutionNet`) declares:

- ``inputs``: the batch keys its ``forward`` reads (:mod:`wdss.data.batch` defines them); the reader loads
  those and nothing else, and names a missing one.
- ``forward(**batch)``: a dict with ``irradiance`` (N, 3, H, W, linear, demodulated: the module remodulates it with
  ``brdf``) or, for a network that works on tone-mapped colour, ``display`` (N, 3, H, W in [0, 1]) and
  ``irradiance`` None; and ``coefficients``: the predicted wavelet subbands, or None.
- ``fixed_scale``: True for a network built for one scale (``scale``; FuseSR), which benchmarks and exports run at
  that scale only; False: any scale the batch's ``scale`` says.
- ``needs_training``: True while its weights are random and no published ones were given: the entry points refuse
  to report numbers from it.
- ``loads_published_weights``: True for a baseline that can start from its published weights (Real-ESRGAN), so
  that a run says which weights it reports (the MLflow tag ``weights``).
- ``input_log``: True when it takes log1p of its HDR inputs itself (the export sidecar says so).
- ``upsampler`` and ``residual``: the upsampler its output is a residual over (a module, e.g. the learned kernel)
  and its name (``none`` without one), which the benchmarks separate from what the network adds.

A residual upsampler (the ``residual`` config group builds one: :class:`~wdss.nets.upsamplers.baselines.Upsample`,
:class:`~wdss.nets.upsamplers.joint_bilateral.JointBilateralUpsample`,
:class:`~wdss.nets.upsamplers.learned_bilateral.LearnedBilateralUpsample`) declares ``upsample_inputs`` (the batch
keys it reads), ``name`` (what runs and tables call it) and
``upsample(lr, gbuffer, brdf, lr_brdf, lr_guide, lr_jitter)``: the LR irradiance on the HR grid of ``gbuffer``,
float32; the network it serves asks it for those rather than for its class.
"""

from __future__ import annotations

from torch import nn

__all__ = ["SuperResolutionNet"]


class SuperResolutionNet(nn.Module):
    """Base of every network wdss builds from ``model.net`` (the defaults of the contract above)."""

    fixed_scale: bool = False
    scale: float | None = None
    needs_training: bool = False
    loads_published_weights: bool = False
    input_log: bool = False
    residual: str = "none"

    def __init__(self) -> None:
        super().__init__()
        # An instance attribute, never a class one: a class attribute would shadow the submodule a network
        # registers under this name (nn.Module keeps submodules out of the instance dict).
        self.upsampler: nn.Module | None = None

    @property
    def inputs(self) -> tuple[str, ...]:
        raise NotImplementedError(f"{type(self).__name__} does not declare its inputs (wdss.nets.base)")
