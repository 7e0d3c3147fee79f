"""``bench inference``: milliseconds per frame of the exported graph as engines run it, on every backend."""

from __future__ import annotations

import copy
import statistics
from collections.abc import Callable, Sequence
from pathlib import Path

import torch
from rich.table import Table

from wdss.bench.profiling import profile_buckets, where_table
from wdss.bench.timing import interleaved_ms, ratio_cell
from wdss.config.sizes import model_net_settings

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
    return [table, where_table(spent)]
