"""Where the time of a forward goes, by kind of work, from the profiler of the backend that ran it."""

from __future__ import annotations

import statistics
from collections.abc import Callable

from rich.table import Table

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


def where_table(spent: dict[tuple[str, str], dict[str, float]]) -> Table:
    """Where the time goes: the profiled milliseconds of each (configuration, backend) by kind of work
    (:func:`profile_buckets`), each with its difference to ``none``'s on the same backend."""
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
    return where
