"""``bench data``: what a loader worker delivers (EXR, packed stores) against what a training step consumes."""

from __future__ import annotations

import statistics
import time

import torch
from rich.table import Table

from wdss.bench.timing import interleaved_ms, paired_ratio


def _training_module(widths: str):
    """The default training configuration's LightningModule (the paper's WDSS at ``widths``: paper or small)."""
    from hydra import compose, initialize_config_dir
    from hydra.core.hydra_config import HydraConfig

    from wdss.config.targets import instantiate
    from wdss.paths import CONF_DIR

    with initialize_config_dir(config_dir=str(CONF_DIR), version_base="1.3"):
        cfg = compose("train", overrides=[f"size={widths}"], return_hydra_config=True)
    HydraConfig.instance().set_config(cfg)
    torch.manual_seed(int(cfg.seed))
    return instantiate(cfg.model, tonemap_exposure=cfg.get("tonemap_exposure")).train()


def bench_data(
    size: tuple[int, int],
    patch: int,
    batch: int,
    frames: int,
    repeats: int,
    scale: float,
    step_repeats: int,
    fetch_steps: int,
    workers: int,
    widths: str = "paper",
) -> list[Table]:
    """What a loader worker delivers against what a training step consumes, on synthetic frames of ``size``.

    Table 1: samples/s of one worker (one thread) cutting ``patch``-sized patches for a temporal model's every
    buffer (all batch keys: current, previous and second previous frame, native LR), from zip EXR files (half) and
    from packed stores (lz4 and zstd tiles; untiled raw), with the per-pixel preprocessing in the worker (``loader``) or
    left to the device (``device``: the worker reads and stacks; the build then runs on the GPU, not timed here).
    Every source is timed in the same interleaved rounds (:func:`interleaved_ms`), ratios are medians of per-round
    ratios. The last column is samples/s over what a training step (``widths`` WDSS, batch ``batch``, forward and
    backward, this CPU) consumes, measured after the rounds in the same run.

    Table 2: a DataLoader with ``workers`` workers (packed, raw; preprocessing in the workers, as on a CPU) feeding
    ``fetch_steps`` training steps: the time each step waits in ``next()`` for its batch (the GPU-idle equivalent),
    without and with the first batch (the workers' start-up).
    """
    import tempfile
    from pathlib import Path

    from wdss.data import BATCH_KEYS, Collate, FrameDataset, Preprocessing

    prep = Preprocessing()
    with tempfile.TemporaryDirectory() as tmp:
        sources = _sources(Path(tmp), size, frames, scale)
        datasets = {
            label: FrameDataset([seq], BATCH_KEYS, scale=(scale, scale), patch=patch, preprocessing=prep, flips=False)
            for label, seq in sources.items()
        }
        times = _worker_times(datasets, Collate(BATCH_KEYS, prep, (scale, scale)), batch, scale, repeats)
        module = _training_module(widths)
        step_set = FrameDataset([sources["packed raw"]], module.inputs, scale=(scale, scale), patch=patch)
        step_batch = Collate(module.inputs, prep, (scale, scale))(
            [step_set[(i % len(step_set), i)] for i in range(batch)]
        )
        step = _training_step(module)
        step_ms = statistics.median(interleaved_ms({"step": lambda: step(step_batch)}, step_repeats, warmup=1)["step"])
        worker = _worker_table(times, list(datasets), size, patch, scale, batch, repeats, widths, step_ms)
        datamodule = _packed_datamodule(Path(tmp), module.inputs, scale, patch, batch, frames, fetch_steps, workers)
        waits, steps = _fetched_steps(datamodule, step, fetch_steps)
    return [worker, _fetch_table(waits, steps, size, patch, batch, workers, widths)]


def _sources(tmp, size: tuple[int, int], frames: int, scale: float) -> dict:
    """A synthetic sequence of ``frames`` (+2 of history) as zip EXR files (half) and as packed stores (lz4, zstd,
    raw), by label."""
    from wdss.data import Sequence
    from wdss.data.pack import pack_sequence
    from wdss.data.synthetic import write_sequence

    path = write_sequence(
        tmp / "scenes" / "seq", frames=range(1, frames + 3), size=size, scales=(round(scale),), compression="zip",
        half=True,
    )  # fmt: skip
    sources = {"EXR (zip, half)": Sequence(path)}
    for label, codec in (("packed lz4", "lz4"), ("packed zstd", "zstd"), ("packed raw", "none")):
        sources[label] = pack_sequence(Sequence(path), tmp / f"{codec}.packed" / "seq", codec=codec, verify=1)
    return sources


def _worker_times(datasets: dict, collate, batch: int, scale: float, repeats: int) -> dict[str, list[float]]:
    """ms per batch of one worker (one thread) reading each source raw, and of building the raw batch, timed in the
    same interleaved rounds."""
    draws = dict.fromkeys(datasets, 0)
    raws: dict = {}

    def read(label: str) -> None:  # a batch of samples, each a fresh random patch, stacked raw
        dataset = datasets[label]
        samples = [dataset[((draws[label] + i) % len(dataset), draws[label] + i)] for i in range(batch)]
        draws[label] += batch
        raws[label] = collate.raw(samples, scale)

    runners = {label: (lambda lb=label: read(lb)) for label in datasets}
    runners["build"] = lambda: raws["packed raw"].build()
    threads = torch.get_num_threads()
    torch.set_num_threads(1)  # one worker, one thread (DataLoader workers run one each)
    try:
        read("packed raw")
        return interleaved_ms(runners, repeats, warmup=1)
    finally:
        torch.set_num_threads(threads)


def _training_step(module):
    """One forward and backward pass of ``module`` on a batch (no optimiser step: what the loader must keep up with)."""

    def step(batch_: dict) -> None:
        loss = module._loss(batch_, module(batch_))["total"]
        module.zero_grad(set_to_none=True)
        loss.backward()

    return step


def _worker_table(
    times: dict, labels: list[str], size: tuple[int, int], patch: int, scale: float, batch: int, repeats: int,
    widths: str, step_ms: float,
) -> Table:  # fmt: skip
    """Table 1 of :func:`bench_data`: each source and preprocessing placement against the EXR loader and the step."""
    from wdss.data import BATCH_KEYS

    height, width = size
    consumed = batch / (step_ms / 1e3)  # samples/s a training step takes
    table = Table(
        title=f"one loader worker: {patch}x{patch} patches from {width}x{height} at {scale:g}x, all buffers of a "
        f"temporal model ({len(BATCH_KEYS)} keys), batches of {batch}, {repeats} interleaved rounds; training "
        f"step: {widths} widths, batch {batch}, forward + backward on this CPU, {step_ms / 1e3:.1f} s"
    )
    for column in ("source", "preprocessing", "ms / sample", "samples / s", "x EXR loader", "x step consumption"):
        table.add_column(column, justify="left" if column in ("source", "preprocessing") else "right")
    build = times["build"]
    reference = [r + b for r, b in zip(times["EXR (zip, half)"], build, strict=True)]
    for label in labels:
        for placement in ("loader", "device"):
            per = times[label] if placement == "device" else [r + b for r, b in zip(times[label], build, strict=True)]
            ms = statistics.median(per) / batch
            rate = 1e3 / ms
            table.add_row(
                label, placement, f"{ms:.1f}", f"{rate:.1f}", f"{paired_ratio(reference, per):.1f}x",
                f"{rate / consumed:.1f}x",
            )  # fmt: skip
    table.add_row("training step", "-", f"{step_ms / batch:.0f}", f"{consumed:.2f}", "-", "1.0x")
    return table


def _packed_datamodule(tmp, inputs, scale: float, patch: int, batch: int, frames: int, fetch_steps: int, workers: int):
    """A data module on the raw packed store, preprocessing in ``workers`` loader workers, with enough patches per
    frame for ``fetch_steps`` + 1 batches."""
    from wdss.data import SceneDataModule

    per_frame = -(-batch * (fetch_steps + 1) // frames)
    datamodule = SceneDataModule(
        tmp / "scenes", {"train": ["seq"]}, inputs, format="packed", packed_root=tmp / "none.packed",
        preprocess_on="loader", scale=[scale, scale], patch_size=patch, batch_size=batch,
        patches_per_frame=per_frame, num_workers=workers, flips=False,
    )  # fmt: skip
    datamodule.setup("fit")
    return datamodule


def _fetched_steps(datamodule, step, fetch_steps: int) -> tuple[list[float], list[float]]:
    """Seconds each of ``fetch_steps`` + 1 training steps waited in ``next()`` for its batch, and spent stepping."""
    loader = iter(datamodule.train_dataloader())
    waits, steps = [], []
    for _ in range(fetch_steps + 1):
        start = time.perf_counter()
        fetched = next(loader)
        waits.append(time.perf_counter() - start)
        start = time.perf_counter()
        step(fetched)
        steps.append(time.perf_counter() - start)
    del loader
    return waits, steps


def _fetch_table(
    waits: list[float], steps: list[float], size: tuple[int, int], patch: int, batch: int, workers: int, widths: str
) -> Table:
    """Table 2 of :func:`bench_data`: the step waiting on a DataLoader of ``workers`` workers."""
    height, width = size
    fetch_steps = len(waits) - 1
    idle = sum(waits[1:]) / (sum(waits[1:]) + sum(steps[1:])) if fetch_steps else float("nan")
    first = sum(waits) / (sum(waits) + sum(steps))
    fetch = Table(
        title=f"training from the packed store (raw), {workers} loader workers preprocessing, {widths} widths, "
        f"batch {batch}, {patch}x{patch} from {width}x{height}: time each step waits for its batch"
    )
    for column in ("steps", "first fetch s", "median wait ms", "median step s", "idle %", "idle % incl. first"):
        fetch.add_column(column, justify="right")
    fetch.add_row(
        str(fetch_steps), f"{waits[0]:.2f}", f"{statistics.median(waits[1:]) * 1e3:.1f}" if fetch_steps else "-",
        f"{statistics.median(steps):.1f}", f"{idle:.2%}", f"{first:.2%}",
    )  # fmt: skip
    return fetch
