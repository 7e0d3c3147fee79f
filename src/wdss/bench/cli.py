"""``python -m wdss.bench``: the command line of the benchmarks and the probes, its arguments and which function
makes the tables of each subcommand."""

from __future__ import annotations

import argparse
import sys
from collections.abc import Callable, Sequence

import torch
from rich.console import Console
from rich.table import Table

import wdss.bench
from wdss.bench.data import bench_data
from wdss.bench.inference import BACKENDS, GPU_BACKENDS, INFERENCE_CONFIGS, bench_inference
from wdss.bench.model import bench_model
from wdss.bench.probes.bandlimit import bench_bandlimit
from wdss.bench.probes.guidance import bench_guidance
from wdss.bench.probes.learn import bench_learn
from wdss.bench.render import bench_noise, bench_render
from wdss.bench.stability import bench_stability
from wdss.bench.wavelets import BASES, bench_wavelets
from wdss.memory import memory_retained, restart_with_retained_memory

TABLE_WIDTH = 160  # columns of a table printed off a terminal
SYSTEM_MALLOC = "time under glibc's default malloc, which unmaps large blocks when freed (see wdss.memory)"
TIMED = ("model", "inference")  # may start again under wdss.memory's malloc tunables; their table names the malloc


def _add_benchmarks(sub) -> None:
    """The timings (wavelets, data, model, inference) and the numerical check (stability)."""
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


def _add_render_checks(sub) -> None:
    """The quality of rendered frames: sample counts (render) and the targets' own noise (noise)."""
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


def _add_probes(sub) -> None:
    """The research probes: learn, bandlimit, guidance."""
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


def parser() -> argparse.ArgumentParser:
    """``python -m wdss.bench``'s arguments: a subcommand per benchmark or probe."""
    parser = argparse.ArgumentParser(prog="python -m wdss.bench", description=wdss.bench.__doc__)
    sub = parser.add_subparsers(dest="what", required=True)
    _add_benchmarks(sub)
    _add_render_checks(sub)
    _add_probes(sub)
    return parser


def _wavelets(args: argparse.Namespace) -> list[Table]:
    return [bench_wavelets(args.shape, args.repeats, args.device, args.bases)]


def _data(args: argparse.Namespace) -> list[Table]:
    return bench_data(
        tuple(args.size), args.patch, args.batch, args.frames, args.repeats, args.scale, args.step_repeats,
        args.fetch_steps, args.workers, args.widths,
    )  # fmt: skip


def _model(args: argparse.Namespace) -> list[Table]:
    return [bench_model(tuple(args.size), args.scale, args.repeats, args.device, args.widths)]


def _inference(args: argparse.Namespace) -> list[Table]:
    if args.threads:
        torch.set_num_threads(args.threads)
    return bench_inference(
        tuple(args.size), args.scale, args.repeats, args.configs, args.backends, profile=args.profile,
        device=args.device, dtype=torch.float16 if args.fp16 else torch.bfloat16 if args.bf16 else torch.float32,
    )  # fmt: skip


def _stability(args: argparse.Namespace) -> list[Table]:
    return [bench_stability()]


def _render(args: argparse.Namespace) -> list[Table]:
    return [bench_render(args.seeds, args.frame, tuple(args.size), args.samples, args.reference)]


def _noise(args: argparse.Namespace) -> list[Table]:
    return [bench_noise(args.folders, args.frames, args.noise_seed, args.record)]


def _learn(args: argparse.Namespace) -> list[Table]:
    return bench_learn(args.overrides, args.steps, args.every, args.seeds, args.scales)


def _bandlimit(args: argparse.Namespace) -> list[Table]:
    exposure = None if args.exposure is None else args.exposure if args.exposure == "auto" else float(args.exposure)
    return [bench_bandlimit(args.root, args.sequences, args.scales, args.tonemap, exposure, args.skip_first)]


def _guidance(args: argparse.Namespace) -> list[Table]:
    return [bench_guidance(args.root, args.sequences, args.scales, args.properties, args.checkpoints, args.knee)]


# Each subcommand's tables; its function looks the benchmark up when it runs (tests replace them in this module).
COMMANDS: dict[str, Callable[[argparse.Namespace], list[Table]]] = {
    "wavelets": _wavelets,
    "data": _data,
    "model": _model,
    "inference": _inference,
    "stability": _stability,
    "render": _render,
    "noise": _noise,
    "learn": _learn,
    "bandlimit": _bandlimit,
    "guidance": _guidance,
}


def _malloc_caption(system_malloc: bool, restart: bool) -> str:
    """Start again under the malloc tunables where asked to (``restart``, not ``--system-malloc``), and say which
    malloc the timing runs under."""
    # The timed networks' tensors reach 133 MB at 1080p: under glibc's default malloc each forward maps them anew
    # and page-faults them in, which engines (and onnxruntime's arena) never do (wdss.memory).
    if restart and not system_malloc:
        restart_with_retained_memory()
    return "malloc keeps freed memory (wdss.memory)" if memory_retained() else "the C library's default malloc"


def main(argv: Sequence[str] | None = None, *, restart: bool = False) -> None:
    """``restart``: the command line's process, which the timing benchmarks may start again under
    :mod:`wdss.memory`'s malloc tunables."""
    args = parser().parse_args(argv)
    # Off a terminal (a pipe, a log file) rich would wrap every cell at 80 columns: print tables whole.
    console = Console() if sys.stdout.isatty() else Console(width=TABLE_WIDTH)
    caption = _malloc_caption(args.system_malloc, restart) if args.what in TIMED else None
    tables = COMMANDS[args.what](args)
    if caption is not None:
        tables[0].caption = caption
    for table in tables:
        console.print(table)
