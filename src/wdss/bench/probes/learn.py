"""``bench learn``: what a network adds over its own start, on scenes it never trained on, over seeds."""

from __future__ import annotations

import copy
import math
import statistics
import time
from collections.abc import Callable, Iterator, Sequence

import torch
from rich.table import Table

from wdss.data.preprocess import prediction_color
from wdss.nets.blocks import from_log, to_log
from wdss.nets.upsamplers.baselines import Upsample


class StartArm(torch.nn.Module):
    """Where a residual network starts, on its own: a copy of the residual upsampler the model adds to (a learned
    kernel is then trained by an optimiser of its own; ``residual=bilinear|joint_bilateral|learned_bilateral``), or,
    for a network without one, bilinear upsampling of the demodulated irradiance. Named ``kernel`` when it learns,
    else after its upsampling (``joint bilateral``, ``bilinear``)."""

    def __init__(self, net: torch.nn.Module) -> None:
        super().__init__()
        upsampler = net.upsampler
        self.kernel = copy.deepcopy(upsampler) if upsampler is not None else Upsample("bilinear", demodulated=True)
        learns = next(self.kernel.parameters(), None) is not None
        self.name = "kernel" if learns else self.kernel.name.replace("_", " ")

    def upsample(self, batch: dict) -> torch.Tensor:
        lr, gbuffer, guide, jitter = batch["lr"], batch["gbuffer"], batch.get("lr_guide"), batch.get("lr_jitter")
        return self.kernel.upsample(lr, gbuffer, batch.get("brdf"), batch.get("lr_brdf"), guide, jitter)

    def forward(self, batch: dict) -> dict:
        irradiance = self.upsample(batch)
        return {"irradiance": irradiance, "color": prediction_color(irradiance, batch), "coefficients": None}


class PlainReference(torch.nn.Module):
    """What a plain CNN learns from the same inputs and the same start: four 3x3 convolutions at full resolution
    on log1p of its start's upsampled LR irradiance (``start``, a :class:`StartArm`: its own copy of the model's
    kernel, trained with it), the G-buffers, the spatial mask (and log1p history when the batch has it), predicting
    a log1p-space correction of that upsampling; the last layer starts at zero. Sized from an example ``batch``."""

    def __init__(self, batch: dict, start: StartArm, width: int = 32) -> None:
        super().__init__()
        self.start = start
        convs = [self.inputs(batch)[1].shape[1], width, width, width, 3]
        layers: list[torch.nn.Module] = []
        for a, b in zip(convs, convs[1:], strict=False):
            layers += [torch.nn.Conv2d(a, b, 3, padding=1), torch.nn.ReLU()]
        self.body = torch.nn.Sequential(*layers[:-1])
        torch.nn.init.zeros_(self.body[-1].weight)
        torch.nn.init.zeros_(self.body[-1].bias)

    def inputs(self, batch: dict) -> tuple[torch.Tensor, torch.Tensor]:
        base = to_log(self.start.upsample(batch))
        parts = [base, batch["gbuffer"], batch["spatial_mask"]]
        if "history" in batch:
            parts.append(to_log(batch["history"]))
        return base, torch.cat(parts, 1)

    def forward(self, batch: dict) -> dict:
        base, x = self.inputs(batch)
        irradiance = from_log(base + self.body(x))
        return {"irradiance": irradiance, "color": prediction_color(irradiance, batch), "coefficients": None}


def _learn_setup(overrides: Sequence[str], seed: int) -> tuple:
    """One seed's configuration, training module and data module (fit and validation splits set up)."""
    from hydra import compose, initialize_config_dir
    from hydra.core.hydra_config import HydraConfig

    from wdss.config.targets import instantiate
    from wdss.paths import CONF_DIR

    with initialize_config_dir(config_dir=str(CONF_DIR), version_base="1.3"):
        preset = [] if any(o.startswith("experiment=") for o in overrides) else ["experiment=cpu"]
        settings = [*preset, "data.num_workers=0", *overrides, f"seed={seed}"]
        cfg = compose("train", overrides=settings, return_hydra_config=True)
    HydraConfig.instance().set_config(cfg)
    torch.manual_seed(seed)
    module = instantiate(cfg.model, tonemap_exposure=cfg.get("tonemap_exposure"))
    if not module.trainable or module.temporal == "recurrent":
        raise SystemExit("bench learn: needs a trainable single-frame model (not a baseline, not temporal=recurrent)")
    # The start's and the reference's inputs too: a model may read other buffers (NSRR reads LR G-buffers only).
    inputs = sorted(set(module.inputs) | {"lr", "gbuffer", "spatial_mask", "lr_jitter"})
    datamodule = instantiate(cfg.data, inputs=inputs, test_inputs=list(module.test_inputs))
    if not datamodule.splits.get("val", ((), {}))[0]:
        raise SystemExit("bench learn: it scores the validation scenes, and data.splits.val names none")
    datamodule.check(["train", "val"])
    datamodule.prepare_data()
    datamodule.setup("fit")
    return cfg, module, datamodule


def _epochs(loader) -> Iterator:
    """The training loader's batches, epoch after epoch (each epoch drawn as training draws it)."""
    epoch = 0
    while True:
        loader.sampler.set_epoch(epoch)
        yield from loader
        epoch += 1


def _held_out_psnr(arms: dict, loaders: dict, metrics: Callable, datamodule) -> dict[str, dict[float, float]]:
    """Each arm's mean tone-mapped PSNR (dB) over every full frame of ``loaders`` (scale -> validation loader)."""
    scores: dict[str, dict[float, float]] = {}
    for name, net in arms.items():
        net.eval()
        with torch.no_grad():
            for scale, loader in loaders.items():
                values = []
                for raw in loader:
                    batch = datamodule.on_after_batch_transfer(raw, 0)
                    psnr = metrics(net(batch)["color"].float(), batch["target"].float(), flip=False)["psnr"]
                    values += [v for v in psnr.tolist() if math.isfinite(v)]  # identical images: infinite
                scores.setdefault(name, {})[scale] = statistics.fmean(values)
        net.train()
    return scores


def bench_learn(
    overrides: Sequence[str], steps: int, every: int, seeds: Sequence[int], scales: Sequence[float]
) -> list[Table]:
    """What the network adds over where it starts, on scenes it never trained on. Three arms train on the same
    patches of the training scenes in the same order, with the same loss, Adam learning rate (constant) and gradient
    clipping, each with its own optimiser and its own copy of the start's weights: the model (its network and its
    learned kernel), the start alone (:class:`StartArm`: that kernel trained by itself; a parameter-free upsampler
    stays as it is) and a plain full-resolution CNN on a start of its own (:class:`PlainReference`). Every ``every``
    steps each arm is scored on every full frame of the validation scenes at each of ``scales``, through the tests'
    metric path (tone-mapped PSNR). Tables: per step, the start's PSNR and each network's gain over its own start
    (means over ``seeds``); at the last step, every arm and gain with its 95% t-interval over seeds (paired)."""
    from wdss.report.summary import interval

    scores: dict[int, list[dict[str, dict[float, float]]]] = {}  # step -> per seed: arm -> scale -> PSNR
    begin, start_name = time.perf_counter(), "start"
    for seed in seeds:
        cfg, module, datamodule = _learn_setup(overrides, seed)
        start = StartArm(module.net)  # copied before any step: every arm starts from the same kernel weights
        start_name = start.name
        loader = datamodule.train_dataloader()
        example = datamodule.on_after_batch_transfer(next(iter(loader)), 0)
        arms = {start.name: start, "model": module, "plain CNN": PlainReference(example, StartArm(module.net))}
        lr, clip = float(cfg.model.optimizer.lr), cfg.trainer.get("gradient_clip_val")
        optimizers = {  # a parameter-free start has nothing to train
            name: torch.optim.Adam(params, lr=lr) for name, net in arms.items() if (params := list(net.parameters()))
        }
        held = {
            scale: datamodule._loader(datamodule._dataset("val", scale, None), datamodule.eval_batch_size, train=False)
            for scale in scales
        }
        stream = _epochs(loader)
        for step in range(steps + 1):
            if step % every == 0 or step == steps:
                scores.setdefault(step, []).append(_held_out_psnr(arms, held, module.metrics, datamodule))
                shown = " | ".join(
                    f"{name} " + " ".join(f"{v:.2f}" for v in per_scale.values())
                    for name, per_scale in scores[step][-1].items()
                )
                print(f"bench learn: seed {seed} step {step}/{steps} ({time.perf_counter() - begin:.0f} s): {shown}")
            if step == steps:
                break
            batch = datamodule.on_after_batch_transfer(next(stream), 0)
            for name, optimizer in optimizers.items():
                loss = module._loss(batch, arms[name](batch))["total"]
                optimizer.zero_grad()
                loss.backward()
                if clip:
                    torch.nn.utils.clip_grad_norm_(arms[name].parameters(), float(clip))
                optimizer.step()

    names = datamodule.splits["val"][0]
    nets = [name for name in scores[0][0] if name != start_name]
    setting = f"Adam lr {lr:g}" + (f", clip {float(clip):g}" if clip else "") + f"; {' '.join(overrides)}"
    seeds_text = " ".join(map(str, seeds))

    def gains(step: int, name: str, scale: float) -> list[float]:
        return [seed[name][scale] - seed[start_name][scale] for seed in scores[step]]

    curve = Table(
        title=f"learn: PSNR (dB) on every frame of the validation scenes ({', '.join(names)}), mean of seeds "
        f"{seeds_text}; {setting}"
    )
    curve.add_column("step", justify="right")
    columns = [(start_name, s) for s in scales] + [(f"{n} - {start_name}", s) for n in nets for s in scales]
    for heading, scale in columns:
        curve.add_column(f"{heading} {scale:g}x", justify="right")
    for step in sorted(scores):
        row = [f"{statistics.fmean(seed[start_name][s] for seed in scores[step]):.2f}" for s in scales]
        row += [f"{statistics.fmean(gains(step, n, s)):+.2f}" for n in nets for s in scales]
        curve.add_row(str(step), *row)

    def cell(values: list[float], sign: str) -> str:
        mean, half = interval(values)
        spread = f" +- {half:.2f}" if math.isfinite(half) else ""
        return f"{mean:{sign}.2f}{spread} ({' '.join(f'{v:{sign}.2f}' for v in values)})"

    final = Table(title=f"learn: step {steps}, mean +- 95% half-width over seeds {seeds_text} (each seed)")
    final.add_column("arm")
    for scale in scales:
        final.add_column(f"PSNR {scale:g}x", justify="right")
    for name in scores[steps][0]:
        final.add_row(name, *(cell([seed[name][s] for seed in scores[steps]], "") for s in scales))
    for name in nets:
        final.add_row(f"{name} - {start_name}", *(cell(gains(steps, name, s), "+") for s in scales))
    return [curve, final]
