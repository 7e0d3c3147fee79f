"""``bench guidance``: which data property breaks G-buffer guidance, per scale and method."""

from __future__ import annotations

import statistics
from collections.abc import Sequence

import torch
from rich.table import Table

from wdss.data.preprocess import prediction_color


def bench_guidance(
    root: str,
    names: Sequence[str] | None,
    scales: Sequence[float],
    properties: Sequence[str],
    checkpoints: Sequence[str] = (),
    knee: float | None = None,
) -> Table:
    """Which data property breaks guidance? Per scale and property (:mod:`wdss.data.properties`; ``none``: the frames
    as they are; ``a+b``: together; ``all``: every one), the mean PSNR over every frame of the sequences of
    ``bilinear_demodulated``, ``joint_bilateral`` and each checkpoint (``name=path``), all on the same frames with the
    same property through the same metric path (Hable tone map, as the modules test), with each method's margin
    over bilinear. The LR is native where the data has it. ``knee``: ``data.preprocessing.brdf_knee`` (default: the
    current one; a checkpoint trained with another sees slightly different inputs)."""
    from wdss.checkpoint import read_checkpoint
    from wdss.data.dataset import Collate, FrameDataset
    from wdss.data.layouts import discover_sequences
    from wdss.data.preprocess import Preprocessing
    from wdss.data.properties import PROPERTIES, with_properties
    from wdss.nets.upsamplers.baselines import Upsample
    from wdss.nets.upsamplers.joint_bilateral import JointBilateralUpsample
    from wdss.training.metrics import ImageMetrics
    from wdss.training.module import SuperResolutionModule

    chosen = {p: list(PROPERTIES) if p == "all" else [] if p == "none" else p.split("+") for p in properties}
    for parts in chosen.values():
        if unknown := [n for n in parts if n not in PROPERTIES]:
            raise SystemExit(f"bench guidance: unknown properties {unknown}; known: none, all, {', '.join(PROPERTIES)}")
    methods: dict[str, torch.nn.Module] = {
        "bilinear_demodulated": Upsample("bilinear", demodulated=True),
        "joint_bilateral": JointBilateralUpsample(),
    }
    for item in checkpoints:
        name, _, path = item.partition("=")
        if not path:
            raise SystemExit(f"bench guidance: a checkpoint is name=path, got {item!r}")
        read_checkpoint(path)  # a wdss checkpoint whose model config builds only allowlisted callables
        methods[name] = SuperResolutionModule.load_from_checkpoint(path, map_location="cpu", weights_only=True).eval()
    keys = {"target", "brdf", "emission", "lr"}.union(*(set(m.inputs) for m in methods.values()))
    keys = tuple(sorted(keys))
    prep = Preprocessing() if knee is None else Preprocessing(brdf_knee=knee)
    metrics = ImageMetrics("hable", flip=False)
    sequences = discover_sequences(root, names)
    table = Table(title=f"guidance: PSNR (dB) with each data property, Hable; brdf_knee {prep.brdf_knee:g}")
    for column in ("scale", "property", *methods):
        table.add_column(column, justify="right")
    for scale in scales:
        dataset = FrameDataset(sequences, keys, scale=scale, preprocessing=prep)
        collate = Collate(keys, prep, scale)
        for label, parts in chosen.items():
            generator = torch.Generator().manual_seed(0)
            scores: dict[str, list[float]] = {name: [] for name in methods}
            with torch.no_grad():
                for index in range(len(dataset)):
                    batch = with_properties(collate.raw([dataset[index]], scale), parts, generator).build()
                    target = batch["target"].float()
                    for name, method in methods.items():
                        if isinstance(method, SuperResolutionModule):
                            color = method(batch)["color"]
                        else:
                            out = method(**{k: batch[k] for k in (*method.inputs, "brdf")})
                            color = prediction_color(out["irradiance"], batch)
                        scores[name].append(float(metrics(color.float(), target, flip=False)["psnr"].mean()))
            means = {name: statistics.fmean(values) for name, values in scores.items()}
            base = means["bilinear_demodulated"]
            cells = [f"{means[n]:.2f}" if n == "bilinear_demodulated" else f"{means[n]:.2f} ({means[n] - base:+.2f})"
                     for n in methods]  # fmt: skip
            table.add_row(f"{scale:g}x", label, *cells)
    return table
