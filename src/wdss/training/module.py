"""The LightningModule: a network (or baseline) -> remodulation -> loss, metrics per scale.

The module is built from plain config mappings (``_target_`` dicts) for the network, optimiser and
scheduler, and stores them as hyper-parameters, so a checkpoint alone rebuilds the model:
``SuperResolutionModule.load_from_checkpoint(path, weights_only=True)``.

The module logs its scalar metrics through Lightning (``self.log``) and knows nothing of MLflow: what it shows
beyond them (validation panels, test frames, per-frame metric histories, videos) it hands to callbacks
(:mod:`wdss.callbacks`) as the outputs of :meth:`~SuperResolutionModule.validation_step` and
:meth:`~SuperResolutionModule.test_step` and as :attr:`~SuperResolutionModule.temporal_stability`.
"""

from __future__ import annotations

import inspect
from collections.abc import Mapping
from typing import Any

import lightning as L
import torch
from omegaconf import DictConfig, OmegaConf
from torch import Tensor, nn

from wdss.config.targets import check_targets, instantiate, moved, refuse_interpolation
from wdss.data.preprocess import prediction_color, target_irradiance
from wdss.ops.tonemap import ToneMap
from wdss.ops.warp import warp_backward
from wdss.training.losses import WDSSLoss
from wdss.training.metrics import LPIPS, ImageMetrics
from wdss.training.temporal_metrics import TemporalStability

__all__ = ["SuperResolutionModule"]


def _plain(config: Any) -> Any:
    return OmegaConf.to_container(config, resolve=True) if isinstance(config, DictConfig) else config


class SuperResolutionModule(L.LightningModule):
    """Train and evaluate one super-resolution model.

    ``net``: a ``_target_`` mapping of a network that keeps :class:`~wdss.nets.base.SuperResolutionNet`'s contract
    (its ``inputs``, a forward returning ``{"irradiance", "coefficients"}``: :class:`~wdss.nets.wdss.network.WDSSNet`,
    a baseline) or such a module.
    ``loss_weights``: see :class:`~wdss.training.losses.WDSSLoss`. ``optimizer``/``scheduler``: ``_partial_``
    ``_target_`` mappings. ``lpips``: ``{"backbone": path, "linear": path}`` of local weight files, or None.
    ``temporal``: ``gt_history``, ``recurrent`` or ``none`` (default: whatever the network's branch implies).
    ``flip``: FLIP (LDR and HDR) among the test metrics; ``flip_in_validation``: in validation too (off by default:
    FLIP is most of a CPU validation's time, and checkpoints are chosen by ``val/psnr``).
    ``image_every_n_epochs``: how often the validation panels are logged (0: never), read by
    :class:`~wdss.callbacks.images.ValidationPanels`.

    After a test, :attr:`temporal_stability` holds the :class:`~wdss.training.temporal_metrics.TemporalStability`
    of each scale label (``2x``), pooled over the DDP ranks' frames.
    """

    def __init__(
        self,
        net: Mapping[str, Any] | nn.Module,
        loss_weights: Mapping[str, float] | None = None,
        optimizer: Mapping[str, Any] | None = None,
        scheduler: Mapping[str, Any] | None = None,
        tonemap_name: str = "hable",
        flip: bool = True,
        flip_in_validation: bool = False,
        lpips: Mapping[str, str] | None = None,
        image_every_n_epochs: int = 1,
        trainable: bool = True,
        temporal: str | None = None,
        detach_history: bool = False,
        loss_space: str = "linear",
        tonemap_exposure: float | str | None = None,
        warmup_steps: int = 0,
        upsampler_lr_scale: float = 1.0,
    ) -> None:
        super().__init__()
        # Plain containers only: checkpoints then load with weights_only=True and rebuild the network.
        hparams = {
            "loss_weights": dict(_plain(loss_weights) or {"l1": 1.0}),
            "optimizer": _plain(optimizer) or {"_target_": "torch.optim.Adam", "_partial_": True, "lr": 1e-4},
            "scheduler": _plain(scheduler),
            "tonemap_name": tonemap_name,
            "flip": flip,
            "flip_in_validation": flip_in_validation,
            "lpips": _plain(lpips),
            "image_every_n_epochs": image_every_n_epochs,
            "trainable": trainable,
            "temporal": temporal,
            "detach_history": detach_history,
            "loss_space": loss_space,
            "tonemap_exposure": tonemap_exposure,
            "warmup_steps": int(warmup_steps),
            "upsampler_lr_scale": float(upsampler_lr_scale),
        }
        if not isinstance(net, nn.Module):
            hparams["net"] = _plain(net)
        hparams = moved(hparams)  # a checkpoint written before the layout's move names its network by the old path
        # A checkpoint's hyper-parameters are data: a config's interpolations were resolved above (_plain, or by
        # the instantiate that built this module), so one left is refused, as is a target off its slot's list,
        # before anything is built.
        refuse_interpolation(hparams)
        for key in ("net", "optimizer", "scheduler"):
            check_targets(hparams.get(key), key)
        self.net = net if isinstance(net, nn.Module) else instantiate(hparams["net"], at="net")
        if temporal is None:  # follow the network: a temporal branch trains on ground-truth history by default
            temporal = "gt_history" if "history" in self.net.inputs else "none"
            hparams["temporal"] = temporal
        self.save_hyperparameters(hparams)
        lpips_model = LPIPS(lpips["backbone"], lpips["linear"]) if lpips else None
        self.tone = ToneMap(tonemap_name, tonemap_exposure)  # metrics, pictures and a tone-mapped loss alike
        self.criterion = WDSSLoss(hparams["loss_weights"], lpips=lpips_model, space=loss_space, tone=self.tone)
        self.metrics = ImageMetrics(tonemap_name, flip=flip, lpips=lpips_model, exposure=tonemap_exposure)
        self.optimizer_config = hparams["optimizer"]
        self.scheduler_config = hparams["scheduler"]
        self.trainable = trainable and any(p.requires_grad for p in self.net.parameters())
        self._forward_args = tuple(inspect.signature(self.net.forward).parameters)
        self.temporal = temporal
        self._check_temporal()
        self._state: tuple[str, int, Tensor] | None = None  # recurrent evaluation: the last output, by frame
        self._stability: dict[str, TemporalStability] = {}  # test: this rank's temporal sums by scale label
        self.temporal_stability: dict[str, TemporalStability] = {}  # after a test: every rank's, pooled

    def _check_temporal(self) -> None:
        if self.temporal not in ("gt_history", "recurrent", "none"):
            raise ValueError(f"model.temporal must be gt_history, recurrent or none, got {self.temporal!r}")
        has_branch = "history" in self.net.inputs
        if has_branch != (self.temporal != "none"):
            raise ValueError(
                f"model.temporal={self.temporal} but the network {'has' if has_branch else 'has no'} temporal branch"
            )
        if self.criterion.weights.get("temporal") and self.temporal != "recurrent":
            raise ValueError(
                "loss.weights.temporal > 0 compares consecutive outputs, which only temporal=recurrent produces "
                "(with gt_history the model never sees its previous output); set it to 0 or use recurrent"
            )

    # ------------------------------------------------------------------------------------------ model

    @property
    def inputs(self) -> tuple[str, ...]:
        """Batch keys to ask the data for: the network's, the BRDF, the target and (for masked L1) the mask."""
        keys = set(self.net.inputs) | {"brdf", "target"}
        if "lr" in keys:  # a prediction of demodulated irradiance: the emission the data separated comes back at HR
            keys.add("emission")
        if self.criterion.weights.get("masked_l1"):
            keys.add("spatial_mask")
        if self.temporal == "recurrent":  # the history is the model's own previous output, warped
            keys = (keys - {"history"}) | {"motion"}
        return tuple(sorted(keys))

    @property
    def test_inputs(self) -> tuple[str, ...]:
        """Batch keys of the test split: :attr:`inputs`, and what the temporal metrics warp and mask with."""
        return tuple(sorted(set(self.inputs) | {"motion", "gbuffer"}))

    def forward(self, batch: Mapping[str, Any], *, subbands: bool = True) -> dict[str, Tensor | None]:
        """The network's outputs and ``color``, the remodulated HR colour. ``subbands=False``: only the image is
        needed (inference), which lets a network that can skip its coefficients take its faster path."""
        # Pass the batch tensors the network's forward names (inputs, and scale or brdf where it takes them).
        wanted: dict[str, Any] = {k: batch[k] for k in self._forward_args if k in batch}
        if not subbands and "subbands" in self._forward_args:
            wanted["subbands"] = False
        out = dict(self.net(**wanted))
        # Single-image baselines return a display image (tone-mapped space) instead of irradiance.
        out["color"] = prediction_color(out.get("irradiance"), batch)
        return out

    # ------------------------------------------------------------------------------------------ steps

    def _loss(
        self, batch: Mapping[str, Any], out: Mapping[str, Tensor | None], temporal: tuple[Tensor, Tensor] | None = None
    ) -> dict[str, Tensor]:
        if out.get("display") is not None:  # display-space models learn the tone-mapped target
            target = self.tone(batch["target"], batch["target"])
            return self.criterion(out["display"], target, spatial_mask=batch.get("spatial_mask"))
        target_coefficients = None
        if out.get("coefficients") is not None and self.criterion.weights.get("wavelet"):
            target_coefficients = self.net.target_coefficients(target_irradiance(batch))
        return self.criterion(
            out["color"],
            batch["target"],
            coefficients=out["coefficients"],
            target_coefficients=target_coefficients,
            spatial_mask=batch.get("spatial_mask"),
            temporal=temporal,
        )

    def _with_history(self, batch: Mapping[str, Any], previous: Tensor | None) -> dict[str, Any]:
        """The batch with ``history`` = the previous output warped by the motion vectors; at the start of a
        sequence, the LR irradiance upsampled bilinearly (as DFASR starts), not zeros."""
        step = dict(batch)
        if previous is None:
            size = batch["brdf"].shape[-2:]  # the HR size, also where there is no target (wdss.upscale)
            step["history"] = torch.nn.functional.interpolate(
                batch["lr"], size=size, mode="bilinear", align_corners=False
            )
        else:
            step["history"] = warp_backward(
                previous.detach() if self.hparams.detach_history else previous, batch["motion"]
            )
        return step

    def _sequence_loss(self, steps: list[Mapping[str, Any]]) -> dict[str, Tensor]:
        """Recurrent training over T frames: mean of per-step losses, the temporal term from step 2 on."""
        totals: dict[str, Tensor] = {}
        previous: dict[str, Tensor | None] | None = None
        for index, step in enumerate(steps):
            step = self._with_history(step, previous["irradiance"] if previous else None)
            out = self(step)
            temporal = None
            if previous is not None:
                temporal = (
                    warp_backward(previous["color"], step["motion"]),
                    warp_backward(steps[index - 1]["target"], step["motion"]),
                )
            for name, value in self._loss(step, out, temporal).items():
                totals[name] = totals.get(name, 0.0) + value / len(steps)
            previous = out
        return totals

    def training_step(self, batch: Mapping[str, Any], batch_idx: int) -> Tensor:
        if "steps" in batch:
            if self.temporal != "recurrent":
                raise ValueError("sequence batches (data.sequence_length > 1) are for temporal=recurrent")
            terms = self._sequence_loss(batch["steps"])
            batch = batch["steps"][-1]
        else:
            if self.temporal == "recurrent":
                batch = self._with_history(batch, None)
            terms = self._loss(batch, self(batch))
        if not torch.isfinite(terms["total"]):
            raise FloatingPointError(
                f"non-finite training loss at step {self.global_step} (batch {batch_idx}: sequences "
                f"{batch.get('sequence')}, frames {batch.get('frame', torch.empty(0)).tolist()}, scale "
                f"{float(batch['scale'][0]):.3g}): "
                + ", ".join(f"{k}={float(v):.4g}" for k, v in terms.items())
                # Loaded data is finite (checked per file), so the usual cause is HDR colour too bright for the loss.
                + f"; the brightest target value is {float(batch['target'].max()):.4g}: HDR colour can overflow the "
                "loss, clip it at load with data.preprocessing.color_max (e.g. 10)"
            )
        n = batch["target"].shape[0]
        self.log("train/loss", terms["total"], prog_bar=True, batch_size=n)
        for name, value in terms.items():
            if name != "total":
                self.log(f"train/{name}", value, batch_size=n)
        return terms["total"]

    def _evaluate(self, batch: Mapping[str, Any], stage: str, suffix: str) -> dict[str, Tensor]:
        if self.temporal == "recurrent":  # frames arrive in order: feed back the previous output of the sequence
            state, key = self._state, (batch["sequence"][0], int(batch["frame"][0]))
            follows = state is not None and state[0] == key[0] and state[1] == key[1] - 1 and len(batch["frame"]) == 1
            batch = self._with_history(batch, state[2] if follows else None)
        out = self(batch)
        if self.temporal == "recurrent":
            self._state = (batch["sequence"][0], int(batch["frame"][0]), out["irradiance"].detach())
        # FLIP is most of a CPU validation's cost, and checkpoints are chosen by val/psnr: test always has it.
        flip = stage == "test" or bool(self.hparams.get("flip_in_validation", False))
        if out.get("display") is not None:
            values = self.metrics.display(out["display"].float(), batch["target"].float(), flip=flip)
        else:
            values = self.metrics(out["color"].float(), batch["target"].float(), flip=flip)
        n = batch["target"].shape[0]
        # sync_dist: under DDP each rank evaluates its share of the frames; Lightning reduces a mean as the sum of
        # the ranks' batch-size-weighted sums over their summed batch sizes, so the value is that of one process.
        # Every rank must log the same names (each name is one collective), hence psnr_infinite even when 0.
        for name, per_image in values.items():
            finite = per_image[torch.isfinite(per_image)]
            # Identical images have infinite PSNR: average the finite ones, and say so with a count.
            if name == "psnr":
                self.log(
                    f"{stage}/psnr_infinite{suffix}",
                    float(per_image.numel() - finite.numel()),
                    reduce_fx="sum",
                    batch_size=n,
                    add_dataloader_idx=False,
                    sync_dist=True,
                )
            value = finite.mean() if finite.numel() else per_image.mean()
            self.log(
                f"{stage}/{name}{suffix}",
                value,
                batch_size=n,
                add_dataloader_idx=False,
                prog_bar=name == "psnr",
                sync_dist=True,
            )
        if stage == "val":
            self.log("val/loss", self._loss(batch, out)["total"], batch_size=n, sync_dist=True)
        return out

    def validation_step(self, batch: Mapping[str, Any], batch_idx: int) -> dict[str, Tensor | None]:
        """Validation metrics; returns the outputs of :meth:`forward` (``color`` or ``display``, and the network's
        ``coefficients``), which the validation panels draw (:class:`~wdss.callbacks.images.ValidationPanels`)."""
        return self._evaluate(batch, "val", "")

    def on_test_epoch_start(self) -> None:
        self._stability, self.temporal_stability = {}, {}

    def test_step(self, batch: Mapping[str, Any], batch_idx: int, dataloader_idx: int = 0) -> dict[str, Tensor]:
        """Per-frame metrics; the temporal ones accumulate over each sequence, whose frames arrive in order.

        Returns ``shown`` and ``shown_target``, the tone-mapped prediction and target ``(N, 3, H, W)`` in [0, 1] as
        the metrics see them (test frames, videos), and ``color``, the linear prediction (written outputs), where
        the model predicts one."""
        label = f"{float(batch['scale'][0]):g}x"
        out = self._evaluate(batch, "test", f"_{label}")  # MLflow forbids '@' in metric names
        target = batch["target"].float()
        display = out.get("display")
        shown = (display if display is not None else self.tone(out["color"].float(), target)).detach().float()
        shown_target = self.tone(target, target)
        stability = self._stability.setdefault(label, TemporalStability())
        if "motion" in batch and "gbuffer" in batch:
            for index, sequence in enumerate(batch["sequence"]):
                one, frame = slice(index, index + 1), int(batch["frame"][index])
                stability.update(
                    sequence, frame, shown[one], shown_target[one], batch["motion"][one], batch["gbuffer"][one]
                )
        result = {"shown": shown, "shown_target": shown_target}
        if out.get("color") is not None:
            result["color"] = out["color"].detach()
        return result

    def on_test_epoch_end(self) -> None:
        """Log the temporal metrics of every scale (means over sequences); keep the pooled sums, whose per-frame
        values :class:`~wdss.callbacks.frame_metrics.FrameMetrics` logs, in :attr:`temporal_stability`."""
        self.temporal_stability = self._pooled_stability()
        for label, stability in self.temporal_stability.items():
            for name, value in stability.compute().items():
                self.log(f"test/{name}_{label}", value, add_dataloader_idx=False, sync_dist=True)

    def _pooled_stability(self) -> dict[str, TemporalStability]:
        """Every rank's temporal sums pooled (under DDP each rank saw a block of the frames), the same on all ranks."""
        if self.trainer.world_size == 1:
            return self._stability
        import torch.distributed as dist

        shares: list[dict[str, dict]] = [{} for _ in range(self.trainer.world_size)]
        dist.all_gather_object(shares, {label: s.sequences for label, s in self._stability.items()})
        pooled: dict[str, TemporalStability] = {}
        for share in shares:  # in rank order: every rank pools, and then logs, the same names in the same order
            for label, sequences in share.items():
                pooled.setdefault(label, TemporalStability()).add(sequences)
        return pooled

    # ------------------------------------------------------------------------------------------ optimisation

    def configure_optimizers(self) -> Any:
        if not self.trainable:
            return None
        optimizer = self._optimizer()
        if not self.scheduler_config:
            return optimizer
        scheduler = instantiate(self.scheduler_config, at="scheduler")(optimizer)
        return {"optimizer": optimizer, "lr_scheduler": {"scheduler": scheduler, "interval": "epoch"}}

    def _optimizer(self) -> torch.optim.Optimizer:
        """The configured optimiser over the network; with ``upsampler_lr_scale`` != 1 the residual upsampler's own
        parameters (the learned kernel the network adds to) form a second group at that multiple of the lr."""
        build = instantiate(self.optimizer_config, at="optimizer")
        scale = self.hparams.get("upsampler_lr_scale", 1.0)  # absent from checkpoints written before the option
        upsampler = self.net.upsampler
        kernel = list(upsampler.parameters()) if upsampler is not None and upsampler is not self.net else []
        if scale == 1.0 or not kernel:
            return build(self.net.parameters())
        own = {id(p) for p in kernel}
        rest = [p for p in self.net.parameters() if id(p) not in own]
        optimizer = build([{"params": rest}, {"params": kernel}] if rest else [{"params": kernel}])
        optimizer.param_groups[-1]["lr"] *= scale
        return optimizer

    def optimizer_step(self, epoch: int, batch_idx: int, optimizer: Any, optimizer_closure: Any = None) -> None:
        # Linear learning-rate warm-up over the first warmup_steps optimiser steps (Lightning's recipe: scale the
        # groups' lr before stepping); the epoch scheduler takes over after it, from the same initial lr.
        warmup = self.hparams.warmup_steps
        if warmup and self.trainer.global_step <= warmup:
            scale = min(1.0, (self.trainer.global_step + 1) / warmup)
            for group in optimizer.param_groups:
                group.setdefault("initial_lr", group["lr"])
                group["lr"] = group["initial_lr"] * scale
        super().optimizer_step(epoch, batch_idx, optimizer, optimizer_closure)
