"""wdss.bench: the inference table (every backend, paired ratios) and tables printed whole off a terminal."""

from __future__ import annotations

import re

import pytest
import torch
from rich.table import Table

from wdss import bench


def table_rows(text: str) -> dict[tuple[str, str], list[str]]:
    """The body rows of a printed rich table by their first two cells (rows wrapped over lines would split)."""
    rows = {}
    for line in text.splitlines():
        cells = [c.strip() for c in re.split(r"[│┃]", line)[1:-1]]
        if len(cells) > 2 and cells[0] and cells[1]:
            rows[cells[0], cells[1]] = cells[2:]
    return rows


def test_tables_print_whole_off_a_terminal(monkeypatch, capsys):
    """Off a terminal rich wraps at 80 columns: a wide table (as bench model's) kept one line per row."""
    table = Table(title="wide")
    for column in ("transform", "basis", "head", "params", "GFLOPs", "synthesis", "ms", "time / none", "FLOPs / none"):
        table.add_column(column)
    table.add_row("swt", "db4", "shared_inr", "0.575 M", "135.7", "0.33%", "3512", "1.135", "1.092")
    monkeypatch.setattr(bench, "bench_model", lambda *args: table)
    monkeypatch.setattr(bench, "memory_retained", lambda: False)
    bench.main(["model"])
    out = capsys.readouterr().out
    assert table_rows(out)["swt", "db4"] == ["shared_inr", "0.575 M", "135.7", "0.33%", "3512", "1.135", "1.092"]
    assert "the C library's default malloc" in out  # the timing tables say how memory was allocated


@pytest.mark.parametrize("argv,restarts", [([], True), (["--system-malloc"], False)])
def test_the_timing_command_starts_again_under_the_malloc_tunables(argv, restarts, monkeypatch, capsys):
    restarted = []
    monkeypatch.setattr(bench, "restart_with_retained_memory", lambda: restarted.append(True))
    table = Table("model", title="timed")
    monkeypatch.setattr(bench, "bench_inference", lambda *args, **kwargs: [table])
    bench.main(["inference", *argv], restart=True)
    bench.main(["inference"])  # called as a function (tests, notebooks): never
    assert restarted == [True] * restarts
    assert "timed" in capsys.readouterr().out


def test_runners_are_timed_in_interleaved_rounds_each_starting_one_later():
    calls = []
    runners = {key: (lambda k=key: calls.append(k)) for key in "abc"}
    times = bench.interleaved_ms(runners, repeats=4, warmup=1)
    assert "".join(calls) == "abc" + "abc" + "bca" + "cab" + "abc"
    assert {k: len(v) for k, v in times.items()} == {"a": 4, "b": 4, "c": 4}
    assert bench.paired_ratio([2.0, 9.0, 4.0], [1.0, 3.0, 4.0]) == 2.0  # per round: 2, 3, 1


def test_the_median_interval_is_the_order_statistics_that_cover_it():
    # n = 10: P(B <= 1) = 11 / 1024, so (2nd, 9th) covers 1 - 22 / 1024 = 97.9 %; (3rd, 8th) only 89.1 %.
    assert bench.median_interval(list(range(10, 0, -1))) == (2, 9)
    assert bench.median_interval(list(range(1, 11)), confidence=0.85) == (3, 8)
    # n = 6: only the extremes, 1 - 2 / 64 = 96.9 %; n = 5 cannot reach 95 % (1 - 2 / 32 = 93.8 %).
    assert bench.median_interval([3, 1, 2, 6, 5, 4]) == (1, 6)
    assert bench.median_interval([1, 2, 3, 4, 5]) is None
    assert bench.ratio_cell([2.0] * 5, [1.0] * 5) == "2.000"
    assert bench.ratio_cell([float(t) for t in range(1, 11)], [1.0] * 10) == "5.500 [2.000, 9.000]"


@pytest.mark.slow  # torch.compile and the ONNX export of every configuration: ~1 min
def test_inference_table_times_every_backend_with_ratios(capsys):
    argv = ["inference", "--size", "16", "32", "--repeats", "2", "--configs", "none", "SWT-db4", "--threads", "1"]
    bench.main([*argv, "--profile"])
    out = capsys.readouterr().out
    assert "ms per 32x16 frame at 2x, CPU, 1 threads, 2 rounds" in out
    timed, profiled = out.split("where the time goes")
    rows = table_rows(timed)
    assert {backend for _, backend in rows} - {"backend"} == {"eager", "compile", "onnxruntime"}
    for name in ("none", "SWT-db4"):
        for backend in bench.BACKENDS:
            ms, to_eager, to_none, error = rows[name, backend]
            to_eager, to_none = float(to_eager.split()[0]), float(to_none.split()[0])  # the ratio before its interval
            assert float(ms) > 0 and to_none > 0
            assert to_eager == 1.0 if backend == "eager" else to_eager > 0
            assert float(error) <= 1e-4  # every backend computes the eager colour
        assert rows["none", backend][2] == "1.000"  # a ratio of 1 in every round: no interval
    # Where the time goes: every pair's profile, its kinds of work adding up to its total, the differences to none's.
    where = table_rows(profiled)
    for backend in bench.BACKENDS:
        none = [float(cell) for cell in where["none", backend]]
        swt = [re.fullmatch(r"(\S+) \((\S+)\)", cell).groups() for cell in where["SWT-db4", backend]]
        for values in (none, [float(ms) for ms, _ in swt]):
            assert values[0] == pytest.approx(sum(values[1:]), abs=0.2) and values[1] > 0  # convolutions ran
        differences = [float(ms) - reference for (ms, _), reference in zip(swt, none, strict=True)]
        assert [float(diff) for _, diff in swt] == pytest.approx(differences, abs=0.2)
    assert float(where["none", "compile"][3]) > 0  # the kernels torch.compile generated
    assert float(where["none", "eager"][3]) == float(where["none", "onnxruntime"][3]) == 0


def test_inference_in_half_precision_stays_close_to_float32(capsys):
    argv = ["inference", "--size", "16", "32", "--repeats", "1", "--configs", "SWT-db4", "--threads", "1"]
    bench.main([*argv, "--backends", "eager", "onnxruntime", "--fp16"])
    rows = table_rows(capsys.readouterr().out)
    assert {backend for name, backend in rows if name == "SWT-db4"} == {"eager", "onnxruntime"}
    for backend in ("eager", "onnxruntime"):
        assert 0 < float(rows["SWT-db4", backend][-1]) <= 1e-2  # half precision: close to float32, not equal


def test_inference_in_bfloat16_runs_the_torch_backends_close_to_float32(capsys):
    argv = ["inference", "--size", "16", "32", "--repeats", "1", "--configs", "SWT-db4", "--threads", "1"]
    bench.main([*argv, "--backends", "eager", "--bf16"])
    out = capsys.readouterr().out
    assert "bf16" in out and 0 < float(table_rows(out)["SWT-db4", "eager"][-1]) <= 2e-2  # 8 bits of mantissa
    with pytest.raises(ValueError, match="onnxruntime's CPU provider has no bfloat16 convolutions"):
        bench.bench_inference((16, 32), 2.0, 1, ["none"], ["onnxruntime"], dtype=torch.bfloat16)


def test_inference_refuses_backends_its_device_cannot_run():
    with pytest.raises(ValueError, match="cudagraphs backend records CUDA graphs: it needs --device cuda"):
        bench.bench_inference((16, 32), 2.0, 1, ["none"], ["eager", "cudagraphs"])
    with pytest.raises(ValueError, match="onnxruntime is timed on the CPU only"):
        bench.bench_inference((16, 32), 2.0, 1, ["none"], ["onnxruntime"], device="cuda")
    if not torch.cuda.is_available():
        with pytest.raises(ValueError, match="--device cuda: torch sees no CUDA device"):
            bench.bench_inference((16, 32), 2.0, 1, ["none"], ["eager", "cudagraphs"], device="cuda")


def test_profile_buckets_sort_work_by_what_ran():
    """Eager and compile: torch's operators by self time (a convolution's dispatch layers are not counted twice)."""
    import torch.nn.functional as F

    x, w = torch.rand(1, 8, 32, 32), torch.rand(8, 8, 3, 3)
    spent = bench.profile_buckets(lambda: F.pixel_shuffle(F.conv2d(x, w, padding=1), 2).sin(), "eager", calls=2)
    assert set(spent) == set(bench.PROFILE_BUCKETS)
    assert spent["convolution"] > 0 and spent["data movement"] > 0 and spent["other"] > 0  # conv, shuffle, sin
    assert spent["generated"] == 0


def _cells(table) -> dict[str, list[str]]:
    return {column.header: list(column._cells) for column in table.columns}


@pytest.mark.parametrize(
    ("residual", "start"),
    [("bilinear", "bilinear"), ("joint_bilateral", "joint bilateral"), ("learned_bilateral", "kernel")],
)
def test_learn_gives_each_arm_its_own_start_and_scores_every_frame_of_the_validation_scenes(
    residual, start, monkeypatch
):
    from wdss.data.datamodule import SceneDataModule

    read, made = [], {}
    dataset = SceneDataModule._dataset

    def spy(self, split, scale, patch):
        read.append((split, scale, patch))
        return dataset(self, split, scale, patch)

    setup = bench._learn_setup

    def keep(overrides, seed):
        made["cfg"], made["module"], made["datamodule"] = setup(overrides, seed)
        return made["cfg"], made["module"], made["datamodule"]

    starts = []

    class Recorded(bench.StartArm):
        def __init__(self, net):
            super().__init__(net)
            self.initial = [p.detach().clone() for p in self.parameters()]
            starts.append(self)

    monkeypatch.setattr(bench, "StartArm", Recorded)
    monkeypatch.setattr(SceneDataModule, "_dataset", spy)
    monkeypatch.setattr(bench, "_learn_setup", keep)
    overrides = ["experiment=smoke", f"residual={residual}", "recipe.output_space=log", "recipe.tap_brdf=true"]
    curve, final = bench.bench_learn(overrides, steps=3, every=3, seeds=[0], scales=[2.0, 4.0])
    # Full frames (no patch) of the validation split, at every scale asked for.
    assert {("val", 2.0, None), ("val", 4.0, None)} <= set(read)
    assert not [r for r in read if r[0] == "test"]
    cells = _cells(curve)
    assert cells["step"] == ["0", "3"]
    # With a zero exit and a zero last layer, both networks start exactly where their starts do.
    for name in ("model", "plain CNN"):
        assert cells[f"{name} - {start} 2x"][0] == "+0.00" and cells[f"{name} - {start} 4x"][0] == "+0.00"
    rows = {row: [c[i] for c in list(_cells(final).values())[1:]] for i, row in enumerate(_cells(final)["arm"])}
    assert list(rows) == [start, "model", "plain CNN", f"model - {start}", f"plain CNN - {start}"]
    if residual == "learned_bilateral":
        # Three copies of the kernel (the model's, the start's, the plain CNN's): no weight shared, each trained
        # by its own arm from the same initial weights.
        kernels = [made["module"].net.upsampler] + [arm.kernel for arm in starts]
        assert len(kernels) == 3
        pointers = [{p.data_ptr() for p in kernel.parameters()} for kernel in kernels]
        assert all(not (pointers[i] & pointers[j]) for i in range(3) for j in range(i + 1, 3))
        for kernel in kernels:
            moved = [not torch.equal(p, q) for p, q in zip(kernel.parameters(), starts[0].initial, strict=True)]
            assert any(moved)
        weights = [torch.cat([p.flatten() for p in kernel.parameters()]) for kernel in kernels]
        assert not torch.equal(weights[0], weights[1]) and not torch.equal(weights[1], weights[2])


def test_learn_states_each_gain_with_its_interval_over_seeds():
    overrides = ["experiment=smoke", "residual=learned_bilateral"]
    curve, final = bench.bench_learn(overrides, steps=2, every=1, seeds=[0, 1], scales=[3.0])
    assert _cells(curve)["step"] == ["0", "1", "2"]
    gain = _cells(final)["PSNR 3x"][3]  # model - kernel: mean +- half-width (seed 0, seed 1)
    mean, rest = gain.split(" +- ")
    half, per_seed = rest.split(" (")
    values = [float(v) for v in per_seed.rstrip(")").split()]
    assert len(values) == 2 and float(mean) == pytest.approx(sum(values) / 2, abs=0.006)
    assert float(half) >= 0


def test_learn_refuses_a_model_without_weights():
    with pytest.raises(SystemExit, match="trainable single-frame model"):
        bench.bench_learn(
            ["experiment=smoke", "variant=bilinear_demodulated"], steps=1, every=1, seeds=[0], scales=[2.0]
        )


def test_learn_refuses_data_without_validation_scenes():
    with pytest.raises(SystemExit, match="data.splits.val names none"):
        bench.bench_learn(["experiment=smoke", "data.splits.val=[]"], steps=1, every=1, seeds=[0], scales=[2.0])


def test_learn_reads_the_reference_buffers_for_a_model_that_does_not():
    # NSRR reads LR G-buffers only: the HR G-buffers the plain CNN and the bilinear start need are read for it.
    curve, _ = bench.bench_learn(["experiment=smoke", "variant=nsrr"], steps=1, every=1, seeds=[0], scales=[2.0])
    assert _cells(curve)["step"] == ["0", "1"]


@pytest.mark.slow  # a DataLoader with two worker processes: ~15 s
def test_data_table_rates_every_source_in_both_placements_against_a_training_step(capsys):
    bench.main(["data", "--size", "48", "64", "--patch", "24", "--batch", "2", "--frames", "2", "--repeats", "1"]
               + ["--step-repeats", "1", "--fetch-steps", "1", "--widths", "small"])  # fmt: skip
    out = capsys.readouterr().out
    rows = table_rows(out)
    for source in ("EXR (zip, half)", "packed zstd", "packed raw"):
        for placement in ("loader", "device"):
            ms, rate, to_exr, to_step = rows[source, placement]
            assert float(ms) > 0 and float(rate) > 0 and float(to_exr.rstrip("x")) > 0 and to_step.endswith("x")
    assert rows["EXR (zip, half)", "loader"][2] == "1.0x" and rows["training step", "-"][3] == "1.0x"
    assert "time each step waits for its batch" in out


def _dct_matrix(n: int):
    """The orthonormal DCT-II matrix from its formula (an oracle independent of scipy.fft)."""
    import numpy as np

    k, i = np.meshgrid(np.arange(n), np.arange(n), indexing="ij")
    matrix = np.sqrt(2.0 / n) * np.cos(np.pi * (2 * i + 1) * k / (2 * n))
    matrix[0] /= np.sqrt(2.0)
    return matrix


@pytest.mark.parametrize("scale", [2.0, 2.5, 3.0, 4.0])
def test_band_limited_is_the_orthogonal_projection_onto_the_lr_grids_cosines(scale):
    import numpy as np
    import torch

    rng = np.random.default_rng(0)
    image = rng.random((2, 3, 18, 24))
    rows, cols = _dct_matrix(18), _dct_matrix(24)
    height, width = {2.0: (9, 12), 2.5: (7, 10), 3.0: (6, 8), 4.0: (4, 6)}[scale]  # round(18 / s), round(24 / s)
    keep_rows = np.diag((np.arange(18) < height).astype(float))
    keep_cols = np.diag((np.arange(24) < width).astype(float))
    expected = rows.T @ keep_rows @ rows @ image @ cols.T @ keep_cols @ cols
    projected = bench.band_limited(torch.from_numpy(image), scale).numpy()
    np.testing.assert_allclose(projected, expected, atol=1e-12)
    np.testing.assert_allclose(bench.band_limited(torch.from_numpy(projected), scale).numpy(), projected, atol=1e-12)
    residual = image - projected  # orthogonal to everything the LR grid holds
    assert abs(float((residual * projected).sum())) < 1e-9
    low = rows.T @ keep_rows @ rng.random((18, 24)) @ keep_cols @ cols  # an image the LR grid holds exactly
    np.testing.assert_allclose(bench.band_limited(torch.from_numpy(low), scale).numpy(), low, atol=1e-12)


def test_bandlimit_bound_falls_with_the_scale_on_the_fixture(capsys):
    from wdss.paths import PROJECT_ROOT

    bench.main(["bandlimit", str(PROJECT_ROOT / "tests" / "fixtures" / "rendered"), "--scales", "2", "3", "4"])
    [row] = [cells for (name, _), cells in table_rows(capsys.readouterr().out).items() if name == "fixture_000"]
    bound_2x, bound_3x, bound_4x = map(float, row)
    assert 10.0 < bound_4x <= bound_3x <= bound_2x < 60.0  # nested subspaces: a coarser grid holds less


def test_guidance_scores_every_method_with_each_property_on_the_fixture(capsys):
    from wdss.paths import PROJECT_ROOT

    fixture = str(PROJECT_ROOT / "tests" / "fixtures" / "rendered")
    bench.main(["guidance", fixture, "--scales", "2", "--properties", "none", "unnormalised_normals", "filtered"])
    rows = table_rows(capsys.readouterr().out)
    plain, short, filtered = rows["2x", "none"], rows["2x", "unnormalised_normals"], rows["2x", "filtered"]
    assert plain == short  # the loader renormalises normals: a property no method can notice
    bilinear, joint = float(plain[0]), float(plain[1].split()[0])
    assert joint > bilinear > 10.0  # guided by the G-buffer, on the data it was made for
    assert float(plain[1].split()[1].strip("()")) == pytest.approx(joint - bilinear, abs=0.011)
    assert filtered != plain
    with pytest.raises(SystemExit, match="unknown properties"):
        bench.main(["guidance", fixture, "--properties", "sharpened"])
