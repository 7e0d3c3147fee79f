"""Benchmarks: ``python -m wdss.bench wavelets|data|model|inference|stability|render|noise|learn|bandlimit|guidance``.

Every benchmark reports medians of repeated runs and ratios measured in the same process, never absolute
targets: timing on shared machines is noisy, so comparisons are only made within one run.
"""

from __future__ import annotations

import argparse
import copy
import math
import statistics
import sys
import time
from collections.abc import Callable, Iterator, Sequence
from pathlib import Path

import torch
from rich.console import Console
from rich.table import Table

from wdss.config.sizes import model_net_settings, size_widths
from wdss.data.preprocess import prediction_color
from wdss.memory import memory_retained, restart_with_retained_memory
from wdss.nets.blocks import from_log, to_log
from wdss.nets.upsamplers.baselines import Upsample

BASES = ("haar", "db4", "sym4")
TABLE_WIDTH = 160  # columns of a table printed off a terminal
SYSTEM_MALLOC = "time under glibc's default malloc, which unmaps large blocks when freed (see wdss.memory)"


def median_ms(fn: Callable[[], object], *, repeats: int, warmup: int = 1) -> float:
    """Median wall-clock milliseconds of ``fn()`` over ``repeats`` runs after ``warmup`` runs."""
    return statistics.median(interleaved_ms({"fn": fn}, repeats, warmup)["fn"])


def _synchronize() -> None:
    if torch.cuda.is_available():
        torch.cuda.synchronize()


def interleaved_ms(runners: dict, repeats: int, warmup: int = 1) -> dict:
    """Wall-clock milliseconds of every zero-argument runner over ``repeats`` rounds, each round running every
    runner once (A B C A B C ...), so that a slow spell of a shared machine hits them alike rather than one of them.
    Each round starts one runner later: none always runs right after the same one (whose freed memory and caches
    it would inherit)."""
    order = list(runners)
    times: dict = {key: [] for key in order}
    for _ in range(warmup):
        for run in runners.values():
            run()
    for round_ in range(repeats):
        shift = round_ % len(order)
        for key in order[shift:] + order[:shift]:
            _synchronize()
            start = time.perf_counter()
            runners[key]()
            _synchronize()
            times[key].append((time.perf_counter() - start) * 1e3)
    return times


def median_interval(values: Sequence[float], confidence: float = 0.95) -> tuple[float, float] | None:
    """A distribution-free interval of the median: the order statistics ``(j, n + 1 - j)`` (1-based) for the largest
    ``j`` whose coverage ``1 - 2 P(Binomial(n, 1/2) < j)`` is at least ``confidence``; None when even the extremes
    cover less (fewer than 6 values at 95 %)."""
    n = len(values)
    ordered = sorted(values)
    below, j = 0.0, 0  # below = P(B < j + 1) as j grows
    while j < n // 2:
        below += math.comb(n, j) / 2**n
        if 2 * below > 1 - confidence:
            break
        j += 1
    return (ordered[j - 1], ordered[n - j]) if j else None


def ratio_cell(times: Sequence[float], reference: Sequence[float]) -> str:
    """The paired ratio and, when the rounds allow one, its 95 % interval (of the per-round ratios' median)."""
    ratios = [t / r for t, r in zip(times, reference, strict=True)]
    interval = median_interval(ratios)
    tail = f" [{interval[0]:.3f}, {interval[1]:.3f}]" if interval and interval[0] != interval[1] else ""
    return f"{statistics.median(ratios):.3f}{tail}"


def paired_ratio(times: Sequence[float], reference: Sequence[float]) -> float:
    """The median over rounds of ``times / reference`` in the same round."""
    return statistics.median(t / r for t, r in zip(times, reference, strict=True))


# --------------------------------------------------------------------------------------------------------
# wavelets
# --------------------------------------------------------------------------------------------------------


def _ptwt_swt2_roundtrip(x: torch.Tensor, wavelet: str) -> torch.Tensor:
    """A level-1 2-D SWT composed from ptwt's 1-D ``swt``/``iswt``: along W, then along H per branch."""
    import ptwt

    low_w, high_w = ptwt.swt(x, wavelet, level=1, axis=-1)
    bands = [band for branch in (low_w, high_w) for band in ptwt.swt(branch, wavelet, level=1, axis=-2)]
    low = ptwt.iswt(bands[:2], wavelet, axis=-2)
    high = ptwt.iswt(bands[2:], wavelet, axis=-2)
    return ptwt.iswt([low, high], wavelet, axis=-1)


def _ptwt_dwt2_roundtrip(x: torch.Tensor, wavelet: str) -> torch.Tensor:
    import ptwt

    return ptwt.waverec2(ptwt.wavedec2(x, wavelet, mode="periodic", level=1), wavelet)


def bench_wavelets(shape: Sequence[int], repeats: int, device: str, bases: Sequence[str] = BASES) -> Table:
    from wdss.wavelets import WaveletTransform

    x = torch.rand(*shape, device=device)
    table = Table(title=f"wavelet analysis + synthesis, {tuple(shape)} float32 on {device}, median of {repeats}")
    for column in ("transform", "basis", "wdss ms", "ptwt ms", "ptwt / wdss"):
        table.add_column(column, justify="right" if "ms" in column or "/" in column else "left")
    with torch.inference_mode():
        for transform, reference in (("dwt", _ptwt_dwt2_roundtrip), ("swt", _ptwt_swt2_roundtrip)):
            for basis in bases:
                module = WaveletTransform(transform, basis).to(device)
                ours = median_ms(lambda m=module: m.synthesis(m.analysis(x)), repeats=repeats)
                theirs = median_ms(lambda b=basis, r=reference: r(x, b), repeats=repeats)
                table.add_row(transform, basis, f"{ours:.1f}", f"{theirs:.1f}", f"{theirs / ours:.2f}x")
    return table


# --------------------------------------------------------------------------------------------------------
# data
# --------------------------------------------------------------------------------------------------------


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

    from wdss.data import BATCH_KEYS, Collate, FrameDataset, Preprocessing, SceneDataModule, Sequence
    from wdss.data.pack import pack_sequence
    from wdss.data.synthetic import write_sequence

    height, width = size
    prep = Preprocessing()
    threads = torch.get_num_threads()
    tables = []
    with tempfile.TemporaryDirectory() as tmp:
        root = Path(tmp) / "scenes"
        path = write_sequence(
            root / "seq", frames=range(1, frames + 3), size=size, scales=(round(scale),), compression="zip", half=True
        )
        sources = {"EXR (zip, half)": Sequence(path)}
        for label, codec in (("packed lz4", "lz4"), ("packed zstd", "zstd"), ("packed raw", "none")):
            store = Path(tmp) / f"{codec}.packed"
            sources[label] = pack_sequence(Sequence(path), store / "seq", codec=codec, verify=1)
        datasets = {
            label: FrameDataset([seq], BATCH_KEYS, scale=(scale, scale), patch=patch, preprocessing=prep, flips=False)
            for label, seq in sources.items()
        }
        collate = Collate(BATCH_KEYS, prep, (scale, scale))
        draws = dict.fromkeys(datasets, 0)
        raws: dict = {}

        def read(label: str) -> None:  # a batch of samples, each a fresh random patch, stacked raw
            dataset = datasets[label]
            samples = [dataset[((draws[label] + i) % len(dataset), draws[label] + i)] for i in range(batch)]
            draws[label] += batch
            raws[label] = collate.raw(samples, scale)

        runners = {label: (lambda lb=label: read(lb)) for label in datasets}
        runners["build"] = lambda: raws["packed raw"].build()
        torch.set_num_threads(1)  # one worker, one thread (DataLoader workers run one each)
        try:
            read("packed raw")
            times = interleaved_ms(runners, repeats, warmup=1)
        finally:
            torch.set_num_threads(threads)
        module = _training_module(widths)
        inputs = module.inputs
        step_set = FrameDataset([sources["packed raw"]], inputs, scale=(scale, scale), patch=patch)
        step_batch = Collate(inputs, prep, (scale, scale))([step_set[(i % len(step_set), i)] for i in range(batch)])

        def step(batch_: dict) -> None:
            loss = module._loss(batch_, module(batch_))["total"]
            module.zero_grad(set_to_none=True)
            loss.backward()

        step_ms = statistics.median(interleaved_ms({"step": lambda: step(step_batch)}, step_repeats, warmup=1)["step"])
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
        for label in datasets:
            for placement in ("loader", "device"):
                per = (
                    times[label] if placement == "device" else [r + b for r, b in zip(times[label], build, strict=True)]
                )
                ms = statistics.median(per) / batch
                rate = 1e3 / ms
                table.add_row(
                    label, placement, f"{ms:.1f}", f"{rate:.1f}", f"{paired_ratio(reference, per):.1f}x",
                    f"{rate / consumed:.1f}x",
                )  # fmt: skip
        table.add_row("training step", "-", f"{step_ms / batch:.0f}", f"{consumed:.2f}", "-", "1.0x")
        tables.append(table)

        # Table 2: the step waiting on a DataLoader of `workers` workers.
        per_frame = -(-batch * (fetch_steps + 1) // frames)
        datamodule = SceneDataModule(
            root, {"train": ["seq"]}, inputs, format="packed", packed_root=Path(tmp) / "none.packed",
            preprocess_on="loader", scale=[scale, scale], patch_size=patch, batch_size=batch,
            patches_per_frame=per_frame, num_workers=workers, flips=False,
        )  # fmt: skip
        datamodule.setup("fit")
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
        tables.append(fetch)
    return tables


# --------------------------------------------------------------------------------------------------------
# model
# --------------------------------------------------------------------------------------------------------


def bench_model(size: tuple[int, int], scale: float, repeats: int, device: str, widths: str = "paper") -> Table:
    """Whole-forward time and FLOPs of every transform x basis x head, with ratios to ``none`` (one run, every
    network timed in the same interleaved rounds: :func:`interleaved_ms`)."""
    import inspect

    from wdss.nets.profile import dummy_inputs, flops
    from wdss.nets.wdss.heads import HEADS
    from wdss.nets.wdss.network import WDSSNet

    height, width = size
    kwargs = {} if widths == "paper" else size_widths("small")
    heads = {head.name: head for head in HEADS}
    variants = [("none", "-", "shared_inr")] + [(t, b, h) for t in ("dwt", "swt") for b in BASES for h in heads]
    table = Table(
        title=f"inference at {width}x{height} output, {scale}x, {widths} widths, {device}, {repeats} interleaved rounds"
    )
    for column in ("transform", "basis", "head", "params", "GFLOPs", "synthesis", "ms", "time / none", "FLOPs / none"):
        table.add_column(column, justify="left" if column in ("transform", "basis", "head") else "right")
    others = comparison_models(widths)
    rows = [(t, b, h, None) for t, b, h in variants] + [(name, "-", "-", net) for name, net in others.items()]
    shared: dict[tuple, dict] = {}  # inputs by signature and scale: the networks share them
    runners, counts = {}, {}
    for transform, basis, head, other in rows:
        if other is None:
            net = WDSSNet(transform, basis if basis != "-" else "haar", heads[head](), **kwargs).to(device).eval()
        else:
            net = other.to(device).eval()
        row_scale = float(net.scale) if net.fixed_scale else scale
        key = (tuple(inspect.signature(net.forward).parameters), row_scale)
        inputs = shared.setdefault(key, dummy_inputs(net, height, width, row_scale, device))
        params = sum(p.numel() for p in net.parameters())
        counts[transform, basis, head] = (params, *flops(net, inputs))
        runners[transform, basis, head] = lambda n=net, i=inputs: n(**i)
    with torch.inference_mode():
        times = interleaved_ms(runners, repeats, warmup=2)
    reference = next(iter(runners))
    for (transform, basis, head), (params, total, top) in counts.items():
        ms = times[transform, basis, head]
        synthesis = top.get("wavelet", 0) / total
        table.add_row(
            transform, basis, head, f"{params / 1e6:.3f} M", f"{total / 1e9:.1f}", f"{synthesis:.2%}",
            f"{statistics.median(ms):.0f}", f"{paired_ratio(ms, times[reference]):.3f}",
            f"{total / counts[reference][1]:.3f}",
        )  # fmt: skip
    return table


def dfasr_settings() -> dict:
    """DFASR as a WDSSNet, as conf/model/dfasr.yaml sets it (the full LR grid, its G-buffer subset, its fusion and
    phase); read when a benchmark builds it, not when this module is imported."""
    return model_net_settings("dfasr")


def comparison_models(widths: str) -> dict:
    """DFASR, Real-ESRGAN, NSRR and FuseSR (x2) at the given widths, for the inference table."""
    from wdss.nets.comparison.fusesr import FuseSR
    from wdss.nets.comparison.nsrr import NSRR
    from wdss.nets.comparison.rrdbnet import RRDBNet
    from wdss.nets.wdss.network import WDSSNet

    small = widths != "paper"
    return {
        "DFASR": WDSSNet(**dfasr_settings(), **(size_widths("small") if small else {})),
        "Real-ESRGAN": RRDBNet(scale=2, **(size_widths("small", "real_esrgan") if small else {})),
        "NSRR": NSRR(),
        "FuseSR": FuseSR(scale=2),
    }


# --------------------------------------------------------------------------------------------------------
# inference, as engines run it
# --------------------------------------------------------------------------------------------------------

INFERENCE_CONFIGS = {
    "none": dict(transform="none"),
    "DWT-haar": dict(transform="dwt", basis="haar"),
    "SWT-db4": dict(transform="swt", basis="db4"),
    "DFASR": "dfasr",  # a model config, read when built (inference_settings)
}


def inference_settings(name: str) -> dict:
    """The WDSSNet keyword arguments of an inference-table row: its own, or those of the model config it names."""
    settings = INFERENCE_CONFIGS[name]
    return model_net_settings(settings) if isinstance(settings, str) else settings


BACKENDS = ("eager", "compile", "onnxruntime")
# On a GPU onnxruntime is left out (its CPU provider is what wdss installs) and CUDA graphs come in: torch.compile's
# "reduce-overhead" mode records the compiled graph once and replays it, so no kernel is launched from Python.
GPU_BACKENDS = ("eager", "compile", "cudagraphs")


def ort_session(path: str, profile: bool = False):
    """An onnxruntime CPU session on torch's thread count (the same cores for every backend)."""
    import onnxruntime

    options = onnxruntime.SessionOptions()
    options.intra_op_num_threads = torch.get_num_threads()
    # Idle workers sleep instead of spinning, which would steal a core from the backend timed next.
    options.add_session_config_entry("session.intra_op.allow_spinning", "0")
    if profile:
        options.enable_profiling = True
        options.profile_file_prefix = str(Path(path).with_suffix("")) + "_profile"
    return onnxruntime.InferenceSession(path, options, providers=["CPUExecutionProvider"])


def _check_backends(backends: Sequence[str], device: str, profile: bool, dtype: torch.dtype) -> None:
    if dtype == torch.bfloat16 and "onnxruntime" in backends:
        raise ValueError("onnxruntime's CPU provider has no bfloat16 convolutions: time bfloat16 on the torch backends")
    if profile and device != "cpu":
        raise ValueError("--profile reads CPU profilers: time a GPU without it")
    if device == "cpu" and "cudagraphs" in backends:
        raise ValueError("the cudagraphs backend records CUDA graphs: it needs --device cuda")
    if device != "cpu" and "onnxruntime" in backends:
        raise ValueError(
            "onnxruntime is timed on the CPU only (wdss installs its CPU provider): leave it out of --backends on "
            f"{device}"
        )
    if device != "cpu" and not torch.cuda.is_available():
        raise ValueError(f"--device {device}: torch sees no CUDA device here")


def _inference_runners(
    net: torch.nn.Module,
    height: int,
    width: int,
    scale: float,
    backends: Sequence[str],
    tmp: str,
    device: str = "cpu",
    dtype: torch.dtype = torch.float32,
) -> tuple[dict[str, Callable[[], object]], dict[str, float], dict]:
    """A zero-argument callable per backend, all on the same example inputs and weights, each one's
    max |difference| / max against float32 eager's colour, and the inputs as onnxruntime's feed (the graph is in
    ``tmp``). ``dtype`` float16 or bfloat16 runs the graph and its inputs in that precision (the ONNX graph in float16
    as the fp16 export writes it; onnxruntime's CPU provider has no bfloat16 convolutions)."""
    from wdss.export import export_onnx, relative_error
    from wdss.training.module import SuperResolutionModule

    # The export folds RIR blocks in place and returns the graph every backend runs: network + remodulation.
    graph, inputs, reference = export_onnx(
        SuperResolutionModule(net), f"{tmp}/model.onnx", height=height, width=width, scale=scale,
        fp16=dtype == torch.float16,
    )  # fmt: skip
    feed = {k: v.numpy() for k, v in inputs.items()}
    if dtype == torch.bfloat16:  # a copy in bfloat16, as the fp16 export makes one in float16; the scale stays exact
        graph = copy.deepcopy(graph).to(dtype)
        inputs = {k: v if k == "scale" else v.to(dtype) for k, v in inputs.items()}
    # torch runs the graph channels-last, the layout engines feed: oneDNN's convolutions then skip their reorders,
    # and the SWT head computes its tail on cells (wdss.nets.wdss.polyphase).
    graph = graph.to(device, memory_format=torch.channels_last)
    inputs = {k: v.to(device, memory_format=torch.channels_last) if v.dim() == 4 else v for k, v in inputs.items()}
    runners: dict[str, Callable[[], object]] = {}
    for backend in backends:
        if backend == "onnxruntime":
            session = ort_session(f"{tmp}/model.onnx")
            runners[backend] = lambda s=session, f=feed: torch.from_numpy(s.run(["color"], f)[0])
            continue
        if backend == "compile":
            # Frozen, as inference runs it: the weights become constants, which lets Inductor prepack them for oneDNN.
            module = torch.compile(graph, options={"freezing": True})
        elif backend == "cudagraphs":
            module = torch.compile(graph, mode="reduce-overhead")
        else:
            module = graph
        runners[backend] = lambda m=module: m(inputs)[0]
    if not reference.any():  # a network dead at initialisation: every backend would match it trivially
        raise RuntimeError(f"{net.__class__.__name__}'s colour is zero everywhere: the error column would say nothing")
    with torch.inference_mode():  # the first call also compiles (CUDA graphs: the first calls record)
        errors = {
            backend: relative_error(run().float().cpu().numpy(), reference.numpy()) for backend, run in runners.items()
        }
    return runners, errors, feed


# Where the time of a forward goes, by the name of what ran: torch's operators (eager; the convolutions compiled code
# calls out to), onnxruntime's node types, and the kernels torch.compile generates (elementwise and copies, fused).
CONVOLUTION = frozenset({"aten::mkldnn_convolution", "aten::convolution_overrideable", "aten::slow_conv2d_forward",
                         "aten::_slow_conv2d_forward", "aten::thnn_conv2d", "Conv", "FusedConv", "ConvTranspose",
                         "aten::mkldnn_convolution_transpose", "aten::slow_conv_transpose2d"})  # fmt: skip
DATA_MOVEMENT = frozenset({
    "aten::copy_", "aten::clone", "aten::contiguous", "aten::pixel_shuffle", "aten::pixel_unshuffle", "aten::cat",
    "aten::index_select", "aten::constant_pad_nd", "aten::replication_pad2d", "aten::_pad_circular", "aten::stack",
    "aten::flip", "DepthToSpace", "SpaceToDepth", "Transpose", "Concat", "Slice", "Gather", "Pad", "Split",
    "ReorderInput", "ReorderOutput", "Tile", "Expand",
})  # fmt: skip
PROFILE_BUCKETS = ("convolution", "data movement", "generated", "other")


def profile_buckets(run: Callable[[], object], backend: str, session=None, calls: int = 3) -> dict[str, float]:
    """Milliseconds per call of ``run`` by kind of work (:data:`PROFILE_BUCKETS`), from the backend's profiler: torch's
    for eager and compile (self times, so nothing is counted twice), onnxruntime's per-node times for ``session``.
    "generated" is what torch.compile's own kernels took (elementwise work and copies fused together)."""
    buckets = dict.fromkeys(PROFILE_BUCKETS, 0.0)

    def add(name: str, us: float) -> None:
        if name in CONVOLUTION:
            buckets["convolution"] += us
        elif name in DATA_MOVEMENT:
            buckets["data movement"] += us
        elif name.startswith(("## Call CompiledFxGraph", "graph_")):
            buckets["generated"] += us
        else:
            buckets["other"] += us

    if backend == "onnxruntime":
        import json
        from collections import defaultdict

        # A session profiles from its creation on: ``session`` is a fresh one made with enable_profiling, and its
        # first run (allocations, the arena's growth) is left out as the warm-up of the other backends is.
        for _ in range(calls + 1):
            run()
        with open(session.end_profiling()) as f:
            events = json.load(f)
        per_node: dict = defaultdict(list)
        for event in events:
            if event.get("cat") == "Node" and event["name"].endswith("_kernel_time"):
                per_node[event["name"], event["args"]["op_name"]].append(event["dur"])
        for (_, op), durations in per_node.items():
            add(op, statistics.mean(durations[1:] or durations))
        calls = 1
    else:
        run()  # warm-up (a first compiled call compiles)
        from torch.profiler import ProfilerActivity, profile

        with profile(activities=[ProfilerActivity.CPU]) as prof:
            for _ in range(calls):
                run()
        for event in prof.key_averages():
            add(event.key, event.self_cpu_time_total)
    return {name: us / calls / 1e3 for name, us in buckets.items()}


def bench_inference(
    size: tuple[int, int],
    scale: float,
    repeats: int,
    configs: Sequence[str] = tuple(INFERENCE_CONFIGS),
    backends: Sequence[str] | None = None,
    warmup: int = 1,
    profile: bool = False,
    device: str = "cpu",
    dtype: torch.dtype = torch.float32,
) -> list[Table]:
    """Milliseconds per output frame of every configuration on every backend (paper widths), as an engine
    runs it: the exported graph (network + remodulation, RIR blocks folded), batch of 1, inference mode; torch runs
    it channels-last, and torch.compile freezes the weights (``freezing``), as compiled inference does. ``backends``
    default to :data:`BACKENDS` on the CPU and :data:`GPU_BACKENDS` on a GPU (``device="cuda"``), without onnxruntime in
    bfloat16; ``dtype`` (float16, bfloat16) runs graph and inputs in reduced precision.

    All (configuration, backend) pairs are built first, then timed in the same interleaved rounds
    (:func:`interleaved_ms`); ratios are medians of the per-round ratios (paired), times medians of the rounds.
    ONNX Runtime gets torch's thread count; a ratio's brackets are the 95 % interval of its median over the rounds
    (:func:`median_interval`). With ``profile``, a second table says where each pair's time goes
    (:func:`profile_buckets`, after the timing, so that no profiler slows a timed run), beside none's.
    """
    import tempfile

    from wdss.nets.wdss.network import WDSSNet

    if not backends:
        backends = BACKENDS if device == "cpu" else GPU_BACKENDS
        if dtype == torch.bfloat16:
            backends = tuple(b for b in backends if b != "onnxruntime")
    _check_backends(backends, device, profile, dtype)
    height, width = size
    with tempfile.TemporaryDirectory() as tmp:
        built = {}
        for name in configs:
            torch.manual_seed(0)  # the same weights on every run: a rerun times the same networks
            net = WDSSNet(**inference_settings(name)).eval()
            built[name] = _inference_runners(net, height, width, scale, backends, f"{tmp}/{name}", device, dtype)
        runners = {(name, backend): built[name][0][backend] for name in configs for backend in backends}
        with torch.inference_mode():
            times = interleaved_ms(runners, repeats, warmup)
            spent = {}
            if profile:
                for name, backend in runners:
                    run, session = runners[name, backend], None
                    if backend == "onnxruntime":  # a fresh session that profiles, on the same graph and feed
                        session = ort_session(f"{tmp}/{name}/model.onnx", profile=True)
                        run = lambda s=session, f=built[name][2]: s.run(["color"], f)  # noqa: E731
                    spent[name, backend] = profile_buckets(run, backend, session)

    where_run = f"CPU, {torch.get_num_threads()} threads" if device == "cpu" else torch.cuda.get_device_name(device)
    precision = {torch.float16: ", fp16", torch.bfloat16: ", bf16"}.get(dtype, "")
    table = Table(title=f"ms per {width}x{height} frame at {scale:g}x, {where_run}{precision}, {repeats} rounds")
    for column in ("model", "backend", "ms / frame", "time / eager", "time / none", "max rel. error"):
        table.add_column(column, justify="left" if column in ("model", "backend") else "right")
    for name, backend in runners:
        eager = ratio_cell(times[name, backend], times[name, "eager"]) if "eager" in backends else "-"
        none = ratio_cell(times[name, backend], times["none", backend]) if "none" in configs else "-"
        table.add_row(
            name, backend, f"{statistics.median(times[name, backend]):.1f}", eager, none,
            f"{built[name][1][backend]:.1e}",
        )  # fmt: skip
    if not profile:
        return [table]
    where = Table(title="where the time goes: profiled ms per frame by kind of work (difference to none)")
    for column in ("model", "backend", "profiled", *PROFILE_BUCKETS):
        where.add_column(column, justify="left" if column in ("model", "backend") else "right")
    for (name, backend), buckets in spent.items():
        base = spent.get(("none", backend)) if name != "none" else None

        def cell(ms: float, reference: float | None) -> str:
            return f"{ms:.1f}" if reference is None else f"{ms:.1f} ({ms - reference:+.1f})"

        total = sum(buckets.values())
        cells = [cell(total, None if base is None else sum(base.values()))]
        cells += [cell(buckets[k], None if base is None else base[k]) for k in PROFILE_BUCKETS]
        where.add_row(name, backend, *cells)
    return [table, where]


def bench_stability() -> Table:
    """The stiff and extreme cases of :mod:`wdss.stability`: worst relative error and finiteness."""
    from wdss.stability import run_cases

    table = Table(title="stability: worst relative error against float64 / analytic references")
    for column in ("group", "case", "worst rel. error", "tolerance", "finite"):
        table.add_column(column, justify="right" if "error" in column or column == "tolerance" else "left")
    for case in run_cases():
        ok = case.finite and case.error <= case.tolerance
        table.add_row(
            case.group,
            case.name,
            f"{case.error:.2e}",
            f"{case.tolerance:.0e}",
            ("yes" if case.finite else "[red]NO[/red]") + ("" if ok else " [red](fails)[/red]"),
        )
    return table


def bench_render(
    seeds: Sequence[int], frame: int, size: tuple[int, int], samples: Sequence[int], reference: int
) -> Table:
    """Render quality: colour at each sample count (+ OpenImageDenoise, as datasets are rendered) against a
    ``reference``-sample render of the same frame without denoising, PSNR after the metric's tone map at the
    sequence's auto exposure, and seconds per frame. Needs the ``render`` extra."""
    import numpy as np

    from wdss.ops.tonemap import hable
    from wdss.render.blender import BlenderScene
    from wdss.render.exposure import auto_exposure
    from wdss.render.spec import random_scene

    width, height = size
    table = Table(title=f"render: {width}x{height}, frame {frame}, against {reference} spp without denoising")
    for column in ("seed", "spp", "s/frame", "PSNR (dB)", "high-freq. energy / reference"):
        table.add_column(column, justify="right")
    for seed in seeds:
        scene = BlenderScene(random_scene(seed), samples=reference, denoise=True, filter_width=0.01)
        exposure = auto_exposure(scene.render(0, width, height, samples=8)["Combined"][:3])
        # The reference is not denoised: a denoiser that smears texture would smear the reference alike and hide it.
        scene.denoise = False
        start = time.perf_counter()
        ref = torch.from_numpy(scene.render(frame, width, height)["Combined"][None, :3] * exposure)
        ref_seconds = time.perf_counter() - start
        scene.denoise = True
        ref_ldr = hable(ref)

        def detail(x: torch.Tensor) -> float:  # energy of the Laplacian: texture a denoiser smears is lost here
            lap = x[..., 1:-1, 1:-1] * 4 - x[..., :-2, 1:-1] - x[..., 2:, 1:-1] - x[..., 1:-1, :-2] - x[..., 1:-1, 2:]
            return float((lap**2).mean())

        for spp in samples:
            start = time.perf_counter()
            color = torch.from_numpy(scene.render(frame, width, height, samples=spp)["Combined"][None, :3] * exposure)
            seconds = time.perf_counter() - start
            mse = float(((hable(color) - ref_ldr) ** 2).mean())
            psnr = -10 * np.log10(max(mse, 1e-12))
            ratio = detail(hable(color)) / max(detail(ref_ldr), 1e-12)
            table.add_row(str(seed), str(spp), f"{seconds:.1f}", f"{psnr:.2f}", f"{ratio:.3f}")
        table.add_row(str(seed), f"{reference} (ref)", f"{ref_seconds:.1f}", "-", "1.000")
    return table


def bench_noise(folders: Sequence[str], frames: Sequence[int] | None, noise_seed: int, record: bool) -> Table:
    """The targets' own noise of rendered procedural sequences (:func:`wdss.render.noise.measure_noise`: each HR
    frame rendered again with another Cycles seed; the ceiling every PSNR measured on these targets lies under).
    ``record`` writes it into each sequence's ``sequence.json`` (``noise``). Needs the ``render`` extra."""
    import json

    from wdss.data.layouts import Sequence as Frames
    from wdss.render.blender import BlenderScene
    from wdss.render.noise import measure_noise
    from wdss.render.spec import SceneSpec

    table = Table(title=f"targets' noise: re-rendered with Cycles seed offset {noise_seed}, Hable at exposure 10")
    for column in ("sequence", "frames", "PSNR target vs re-render (dB)", "ceiling (dB)", "s/frame"):
        table.add_column(column, justify="right")
    for folder in map(Path, folders):
        sidecar = folder / "sequence.json"
        meta = json.loads(sidecar.read_text()) if sidecar.exists() else {}
        settings = meta.get("settings", {})
        if "things" not in (meta.get("scene") or {}) or not meta.get("exposure"):
            raise SystemExit(f"bench noise: {sidecar} is not a procedural sequence wdss rendered (no scene spec)")
        scene = BlenderScene(
            SceneSpec.from_dict(meta["scene"]),
            samples=settings["samples"],
            denoise=settings["denoise"],
            filter_width=settings["filter_width"],
        )
        noise = measure_noise(scene, folder, meta["exposure"], frames or Frames(folder).frames, noise_seed)
        ceiling = noise["ceiling_psnr_db"]
        table.add_row(
            folder.name,
            str(len(noise["frames"])),
            f"{ceiling - 10 * math.log10(2.0):.2f}",
            f"{ceiling:.2f}",
            f"{noise['seconds_per_frame']:.1f}",
        )
        if record:
            meta["noise"] = noise
            sidecar.write_text(json.dumps(meta, indent=1))
    return table


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
    from wdss.report import interval

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


# --------------------------------------------------------------------------------------------------------
# bandlimit: what an output without detail above the LR grid's Nyquist frequency can score at best
# --------------------------------------------------------------------------------------------------------


def band_limited(image: torch.Tensor, scale: float) -> torch.Tensor:
    """The orthogonal projection of ``image`` (..., H, W) onto the images the LR grid of ``scale`` can hold
    (:func:`wdss.ops.sampling.lr_size`, ``h x w``): its orthonormal 2-D DCT-II with every coefficient at row index
    >= ``h`` or column index >= ``w`` set to zero. Of all such images it is the nearest in squared error (Parseval),
    so its PSNR against ``image`` bounds any upsampler whose output has no content above the LR grid's frequencies;
    the DCT's even extension keeps the frame's borders from leaking in as a periodic FFT's wrap-around would."""
    from scipy.fft import dctn, idctn

    from wdss.ops.sampling import lr_size

    array = image.detach().double().cpu().numpy()
    coefficients = dctn(array, axes=(-2, -1), norm="ortho")
    height, width = lr_size(*array.shape[-2:], scale)
    coefficients[..., height:, :] = 0.0
    coefficients[..., :, width:] = 0.0
    return torch.from_numpy(idctn(coefficients, axes=(-2, -1), norm="ortho")).to(image)


def bench_bandlimit(
    root: str,
    names: Sequence[str] | None,
    scales: Sequence[float],
    tonemap_name: str = "hable",
    exposure=None,
    skip_first: bool = False,
) -> Table:
    """Per sequence and scale, the mean over frames of the PSNR of the tone-mapped HR target against its
    :func:`band_limited` projection, in the metric's display space: the most a method can score from LR colour alone
    without predicting detail the LR grid cannot hold. Every frame by default, as the data module tests a model that
    reads no previous frame; ``skip_first``: without the first, as it tests one that does."""
    from wdss.data.layouts import discover_sequences
    from wdss.ops.tonemap import ToneMap
    from wdss.training.metrics import psnr

    tone = ToneMap(tonemap_name, exposure)
    table = Table(title=f"bandlimit: PSNR (dB) of the target against its projection on the LR grid, {tonemap_name}")
    table.add_column("sequence")
    table.add_column("frames", justify="right")
    for scale in scales:
        table.add_column(f"{scale:g}x", justify="right")
    for sequence in discover_sequences(root, names):
        frames = sorted(sequence.frames)[1:] if skip_first else sorted(sequence.frames)
        totals = [0.0 for _ in scales]
        for frame in frames:
            target = torch.from_numpy(sequence.read(frame, sequence.hr, ["color"])["color"])[None]
            shown = tone(target, target)
            for i, scale in enumerate(scales):
                totals[i] += float(psnr(band_limited(shown, scale).clamp(0, 1), shown)[0])
        table.add_row(sequence.name, str(len(frames)), *(f"{t / len(frames):.2f}" for t in totals))
    return table


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


def main(argv: Sequence[str] | None = None, *, restart: bool = False) -> None:
    """``restart``: the command line's process, which the timing benchmarks may start again under
    :mod:`wdss.memory`'s malloc tunables."""
    parser = argparse.ArgumentParser(prog="python -m wdss.bench", description=__doc__)
    sub = parser.add_subparsers(dest="what", required=True)
    wav = sub.add_parser("wavelets", help="DWT/SWT analysis+synthesis against ptwt")
    wav.add_argument("--shape", type=int, nargs=4, default=(1, 12, 1080, 1920), metavar=("N", "C", "H", "W"))
    wav.add_argument("--repeats", type=int, default=5)
    wav.add_argument("--device", default="cuda" if torch.cuda.is_available() else "cpu")
    wav.add_argument("--bases", nargs="+", default=list(BASES))
    data = sub.add_parser("data", help="samples/s of a loader worker (EXR, packed; both placements) vs a step's")
    data.add_argument("--size", type=int, nargs=2, default=(1080, 1920), metavar=("H", "W"))
    data.add_argument("--patch", type=int, default=432)
    data.add_argument("--batch", type=int, default=8)
    data.add_argument("--frames", type=int, default=4, help="frames with two previous ones (written, then packed)")
    data.add_argument("--repeats", type=int, default=5)
    data.add_argument("--scale", type=float, default=2.0)
    data.add_argument("--step-repeats", type=int, default=2, help="timed training steps (after one warm-up)")
    data.add_argument("--fetch-steps", type=int, default=3, help="training steps fed by the DataLoader (+ the first)")
    data.add_argument("--workers", type=int, default=2)
    data.add_argument("--widths", choices=("paper", "small"), default="paper")
    model = sub.add_parser("model", help="inference ms and FLOPs of every transform x basis x head")
    model.add_argument("--size", type=int, nargs=2, default=(540, 960), metavar=("H", "W"))
    model.add_argument("--scale", type=float, default=2.0)
    model.add_argument("--repeats", type=int, default=3)
    model.add_argument("--widths", choices=("paper", "small"), default="paper")
    model.add_argument("--device", default="cuda" if torch.cuda.is_available() else "cpu")
    model.add_argument("--system-malloc", action="store_true", help=SYSTEM_MALLOC)
    inf = sub.add_parser(
        "inference", help="ms per frame on torch eager, torch.compile and onnxruntime (CPU) or CUDA graphs (GPU)"
    )
    inf.add_argument("--size", type=int, nargs=2, default=(1080, 1920), metavar=("H", "W"))
    inf.add_argument("--scale", type=float, default=2.0)
    inf.add_argument("--repeats", type=int, default=10)
    inf.add_argument("--configs", nargs="+", choices=list(INFERENCE_CONFIGS), default=list(INFERENCE_CONFIGS))
    inf.add_argument(
        "--backends", nargs="+", choices=list(dict.fromkeys(BACKENDS + GPU_BACKENDS)), default=None,
        help=f"default: {' '.join(BACKENDS)} on the CPU, {' '.join(GPU_BACKENDS)} on a GPU",
    )  # fmt: skip
    inf.add_argument("--device", default="cpu", help="cpu, or cuda (a GPU: eager, compile and CUDA graphs)")
    reduced = inf.add_mutually_exclusive_group()
    reduced.add_argument("--fp16", action="store_true", help="graph and inputs in half precision")
    reduced.add_argument(
        "--bf16", action="store_true", help="graph and inputs in bfloat16 (torch backends; CPUs with AVX512-BF16, AMX)"
    )
    inf.add_argument("--threads", type=int, default=None, help="CPU threads of every backend (default: torch's)")
    inf.add_argument("--profile", action="store_true", help="also where the time goes, by kind of work (profilers)")
    inf.add_argument("--system-malloc", action="store_true", help=SYSTEM_MALLOC)
    sub.add_parser("stability", help="stiff and extreme cases: worst relative error, finiteness")
    ren = sub.add_parser("render", help="rendered colour at a few sample counts against a high-sample reference")
    ren.add_argument("--seeds", type=int, nargs="+", default=[101, 200])  # training and validation scenes of mini
    ren.add_argument("--frame", type=int, default=6)
    ren.add_argument("--size", type=int, nargs=2, default=(384, 216), metavar=("W", "H"))
    ren.add_argument("--samples", type=int, nargs="+", default=[8, 16, 32])
    ren.add_argument("--reference", type=int, default=512)
    noise = sub.add_parser("noise", help="the targets' noise ceiling: HR frames re-rendered with another seed")
    noise.add_argument("folders", nargs="+", help="rendered procedural sequences, e.g. data/mini/test_000")
    noise.add_argument("--frames", type=int, nargs="+", default=None, help="default: every frame")
    noise.add_argument("--noise-seed", type=int, default=1)
    noise.add_argument("--record", action="store_true", help="write the ceiling into each sequence.json (noise)")
    learn = sub.add_parser(
        "learn", help="what a network adds over its own start (kernel), on the validation scenes, over seeds"
    )
    learn.add_argument("overrides", nargs="*", help="train config overrides (default experiment=cpu)")
    learn.add_argument("--steps", type=int, default=300)
    learn.add_argument("--every", type=int, default=100, help="score the arms every this many steps")
    learn.add_argument("--seeds", type=int, nargs="+", default=[0, 1, 2])
    learn.add_argument("--scales", type=float, nargs="+", default=[2.0, 3.0, 4.0])
    band = sub.add_parser("bandlimit", help="the best PSNR of an output without detail above the LR grid's Nyquist")
    band.add_argument("root", help="a dataset folder (its sequences), e.g. data/mini")
    band.add_argument("--sequences", nargs="+", default=None, help="default: every sequence under root")
    band.add_argument("--scales", type=float, nargs="+", default=[2.0, 3.0, 4.0])
    band.add_argument("--tonemap", default="hable")
    band.add_argument("--exposure", default=None, help="the metric's tone-map exposure: a number or auto")
    band.add_argument("--skip-first", action="store_true", help="leave out each sequence's first frame")
    guide = sub.add_parser(
        "guidance", help="bilinear, joint bilateral and checkpoints on frames given each data property"
    )
    guide.add_argument("root", help="a dataset folder (its sequences), e.g. data/mini")
    guide.add_argument("--sequences", nargs="+", default=None, help="default: every sequence under root")
    guide.add_argument("--scales", type=float, nargs="+", default=[2.0, 3.0, 4.0])
    guide.add_argument(
        "--properties", nargs="+", default=["none", "filtered", "all"],
        help="none, all, or names joined by +: filtered no_emission unnormalised_normals gbuffer_noise lr_noise "
        "depth_cm",
    )  # fmt: skip
    guide.add_argument("--checkpoints", nargs="*", default=[], help="name=path of checkpoints to score beside them")
    guide.add_argument("--knee", type=float, default=None, help="data.preprocessing.brdf_knee (default: the current)")
    args = parser.parse_args(argv)

    # Off a terminal (a pipe, a log file) rich would wrap every cell at 80 columns: print tables whole.
    console = Console() if sys.stdout.isatty() else Console(width=TABLE_WIDTH)
    caption = None
    if args.what in ("model", "inference"):
        # The timed networks' tensors reach 133 MB at 1080p: under glibc's default malloc each forward maps them anew
        # and page-faults them in, which engines (and onnxruntime's arena) never do (wdss.memory).
        if restart and not args.system_malloc:
            restart_with_retained_memory()
        caption = "malloc keeps freed memory (wdss.memory)" if memory_retained() else "the C library's default malloc"
    if args.what == "wavelets":
        console.print(bench_wavelets(args.shape, args.repeats, args.device, args.bases))
    elif args.what == "data":
        for table in bench_data(
            tuple(args.size), args.patch, args.batch, args.frames, args.repeats, args.scale, args.step_repeats,
            args.fetch_steps, args.workers, args.widths,
        ):  # fmt: skip
            console.print(table)
    elif args.what == "stability":
        console.print(bench_stability())
    elif args.what == "noise":
        console.print(bench_noise(args.folders, args.frames, args.noise_seed, args.record))
    elif args.what == "render":
        console.print(bench_render(args.seeds, args.frame, tuple(args.size), args.samples, args.reference))
    elif args.what == "model":
        table = bench_model(tuple(args.size), args.scale, args.repeats, args.device, args.widths)
        table.caption = caption
        console.print(table)
    elif args.what == "learn":
        for table in bench_learn(args.overrides, args.steps, args.every, args.seeds, args.scales):
            console.print(table)
    elif args.what == "guidance":
        console.print(
            bench_guidance(args.root, args.sequences, args.scales, args.properties, args.checkpoints, args.knee)
        )
    elif args.what == "bandlimit":
        exposure = None if args.exposure is None else args.exposure if args.exposure == "auto" else float(args.exposure)
        console.print(bench_bandlimit(args.root, args.sequences, args.scales, args.tonemap, exposure, args.skip_first))
    elif args.what == "inference":
        if args.threads:
            torch.set_num_threads(args.threads)
        tables = bench_inference(
            tuple(args.size), args.scale, args.repeats, args.configs, args.backends, profile=args.profile,
            device=args.device, dtype=torch.float16 if args.fp16 else torch.bfloat16 if args.bf16 else torch.float32,
        )  # fmt: skip
        tables[0].caption = caption
        for table in tables:
            console.print(table)


if __name__ == "__main__":
    main(restart=True)
