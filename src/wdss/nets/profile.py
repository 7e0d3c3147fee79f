"""Inference cost of a network: whole-forward median milliseconds and FLOPs (``torch.utils.flop_counter``).

The authors timed modules with CUDA events in FP16; wdss times the whole forward (synchronised before and
after on a GPU) and counts FLOPs, which do not depend on the machine.
"""

from __future__ import annotations

import inspect
import os
import platform
import socket
import statistics
import time
import uuid

import torch
from torch import nn
from torch.utils.flop_counter import FlopCounterMode

from wdss.data.batch import KEYS
from wdss.ops.sampling import lr_size

__all__ = ["PROCESS", "device_name", "dummy_inputs", "flops", "forward_ms"]

# This process, as timings record it: runs timed by one process (a sweep's jobs run one after another) compare
# fairly; runs timed by different processes ran under other loads, clocks and thread counts.
PROCESS = f"{socket.gethostname()}:{os.getpid()}:{uuid.uuid4().hex[:8]}"


def device_name(device: str | torch.device) -> str:
    """The device a timing ran on, as a reader compares timings: the GPU's name, or the CPU's and its threads."""
    device = torch.device(device)
    if device.type == "cuda":
        return f"cuda: {torch.cuda.get_device_name(device)}"
    cpu = platform.processor() or platform.machine()
    try:
        with open("/proc/cpuinfo") as info:
            cpu = next((line.split(":", 1)[1].strip() for line in info if line.startswith("model name")), cpu)
    except OSError:
        pass
    return f"{device.type}: {cpu} ({torch.get_num_threads()} threads)"


def dummy_inputs(net: nn.Module, height: int, width: int, scale: float, device: str = "cpu") -> dict:
    """Random inputs for every image argument of ``net.forward`` (shapes of :mod:`wdss.data.batch`) at an
    ``height x width`` output and ``scale``."""
    grids = {"hr": (height, width), "lr": lr_size(height, width, scale)}
    inputs = {}
    for name in inspect.signature(net.forward).parameters:
        if name == "scale":
            inputs["scale"] = torch.full((1,), float(scale), device=device)
        elif name in KEYS and KEYS[name].grid in grids:  # the image keys (lr_jitter is left to its default)
            inputs[name] = torch.rand(1, KEYS[name].channels, *grids[KEYS[name].grid], device=device)
    return inputs


def flops(net: nn.Module, inputs: dict) -> tuple[int, dict[str, int]]:
    """Total FLOPs of one forward and the FLOPs per top-level submodule."""
    counter = FlopCounterMode(display=False)
    with torch.no_grad(), counter:
        net(**inputs)
    per_module = counter.get_flop_counts()
    top = {}
    for name, counts in per_module.items():
        parts = name.split(".")
        if len(parts) == 2:  # "<Net>.<child>"
            top[parts[1]] = sum(counts.values())
    return counter.get_total_flops(), top


def forward_ms(net: nn.Module, inputs: dict, repeats: int = 5, warmup: int = 2) -> float:
    """Median wall-clock milliseconds of one forward (synchronised on CUDA)."""
    sync = torch.cuda.synchronize if next(iter(inputs.values())).is_cuda else (lambda: None)
    times = []
    with torch.inference_mode():
        for i in range(warmup + repeats):
            sync()
            start = time.perf_counter()
            net(**inputs)
            sync()
            if i >= warmup:
                times.append((time.perf_counter() - start) * 1e3)
    return statistics.median(times)
