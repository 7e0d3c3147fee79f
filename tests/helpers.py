"""Tiny networks and synthetic batches for model tests."""

from __future__ import annotations

import torch
from torch import nn

from wdss.nets.upsamplers.baselines import Upsample
from wdss.nets.upsamplers.joint_bilateral import JointBilateralUpsample
from wdss.nets.upsamplers.learned_bilateral import LearnedBilateralUpsample
from wdss.nets.wdss.heads import HEADS, Head
from wdss.nets.wdss.network import WIDTHS
from wdss.ops.sampling import lr_size

TINY = WIDTHS["tiny"]


def head(name: str) -> Head:
    """The head that conf/head/<name>.yaml builds."""
    return {h.name: h for h in HEADS}[name]()


def head_config(name: str) -> dict:
    """The ``_target_`` node of conf/head/<name>.yaml."""
    kind = type(head(name))
    return {"_target_": f"{kind.__module__}.{kind.__qualname__}"}


def upsampler(name: str, **kernel_options: bool) -> nn.Module | None:
    """The residual upsampler that conf/residual/<name>.yaml builds (None for ``none``); ``kernel_options``
    (``tap_brdf``, ``never_raise``, ``raise_within_albedo``) go to the learned kernel and do nothing otherwise."""
    if name == "learned_bilateral":
        return LearnedBilateralUpsample(**kernel_options)
    if name == "joint_bilateral":
        return JointBilateralUpsample()
    return {"none": None, "bilinear": Upsample("bilinear", demodulated=True)}[name]


def batch(n: int = 2, size: tuple[int, int] = (16, 20), scale: float = 2.0, seed: int = 0) -> dict:
    g = torch.Generator().manual_seed(seed)
    h, w = size
    lh, lw = lr_size(h, w, scale)
    brdf = 0.2 + 0.8 * torch.rand(n, 3, h, w, generator=g)
    irradiance = torch.rand(n, 3, h, w, generator=g) * 2
    return {
        "lr": torch.nn.functional.interpolate(irradiance, size=(lh, lw), mode="nearest-exact"),
        "lr_color": torch.nn.functional.interpolate(irradiance * brdf, size=(lh, lw), mode="nearest-exact"),
        "gbuffer": torch.rand(n, 11, h, w, generator=g),
        "spatial_mask": (torch.rand(n, 1, h, w, generator=g) > 0.8).float(),
        "history": irradiance.roll(1, -1),
        "temporal_mask": torch.rand(n, 5, h, w, generator=g),
        "brdf": brdf,
        "target": irradiance * brdf,
        "scale": torch.full((n,), scale),
        "lr_jitter": torch.zeros(n, 2),  # the LR pixels shaded at their centres
        "sequence": ["synthetic"] * n,
        "frame": torch.arange(n),
    }


def losses_over_steps(module, data: dict, steps: int = 2) -> list[float]:
    """The loss before each of ``steps`` optimiser steps on one fixed batch."""
    optimizer = module.configure_optimizers()
    losses = []
    for _ in range(steps):
        terms = module._loss(data, module(data))
        losses.append(float(terms["total"].detach()))
        optimizer.zero_grad()
        terms["total"].backward()
        optimizer.step()
    return losses


def tiny_checkpoint(path, *overrides: str):
    """A checkpoint at ``path`` of a tiny, randomly initialised model of ``wdss.train``'s config with ``overrides``
    (e.g. ``variant=dfasr``), written as training writes one (``Trainer.save_checkpoint``)."""
    import lightning as L

    from tests.test_train import compose_train
    from wdss.config.targets import instantiate

    widths = [
        f"size.wdss.{k}=[{','.join(map(str, v))}]" if isinstance(v, tuple) else f"size.wdss.{k}={v}"
        for k, v in TINY.items()
    ]
    cfg = compose_train([*overrides, *widths])
    torch.manual_seed(0)
    module = instantiate(cfg.model, tonemap_exposure=None)
    trainer = L.Trainer(logger=False, enable_checkpointing=False, enable_progress_bar=False, enable_model_summary=False)
    trainer.strategy.connect(module)
    trainer.save_checkpoint(path)
    return path


def fixture_batches(keys, scale: float = 2.0, root=None) -> list[dict]:
    """Batches of one frame each, in order, of the committed fixture sequence (or the sequence at ``root``), read
    through wdss's data path with the default preprocessing (a frame without a previous one has zero history)."""
    from wdss.data.dataset import Collate, FrameDataset, Preprocessing
    from wdss.data.layouts import Sequence
    from wdss.paths import PROJECT_ROOT

    sequence = Sequence(root or PROJECT_ROOT / "tests" / "fixtures" / "rendered" / "fixture_000")
    prep = Preprocessing()
    dataset = FrameDataset([sequence], keys, scale=scale, patch=None, preprocessing=prep, first_frame="zeros")
    collate = Collate(dataset.keys, prep, scale)
    return [collate([dataset[index]]) for index in range(len(dataset))]
