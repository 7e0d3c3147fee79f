"""``bench model``: the forward time and FLOPs of every transform x basis x head and of the comparison models."""

from __future__ import annotations

import statistics

import torch
from rich.table import Table

from wdss.bench.timing import interleaved_ms, paired_ratio
from wdss.bench.wavelets import BASES
from wdss.config.sizes import model_net_settings, size_widths


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
