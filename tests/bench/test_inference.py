"""wdss.bench.inference: the inference table (every backend, paired ratios, reduced precision, where the time goes)."""

from __future__ import annotations

import re

import pytest
import torch

from tests.bench.tables import table_rows
from wdss.bench import inference
from wdss.bench.cli import main


@pytest.mark.slow  # torch.compile and the ONNX export of every configuration: ~1 min
def test_inference_table_times_every_backend_with_ratios(capsys):
    argv = ["inference", "--size", "16", "32", "--repeats", "2", "--configs", "none", "SWT-db4", "--threads", "1"]
    main([*argv, "--profile"])
    out = capsys.readouterr().out
    assert "ms per 32x16 frame at 2x, CPU, 1 threads, 2 rounds" in out
    timed, profiled = out.split("where the time goes")
    rows = table_rows(timed)
    assert {backend for _, backend in rows} - {"backend"} == {"eager", "compile", "onnxruntime"}
    for name in ("none", "SWT-db4"):
        for backend in inference.BACKENDS:
            ms, to_eager, to_none, error = rows[name, backend]
            to_eager, to_none = float(to_eager.split()[0]), float(to_none.split()[0])  # the ratio before its interval
            assert float(ms) > 0 and to_none > 0
            assert to_eager == 1.0 if backend == "eager" else to_eager > 0
            assert float(error) <= 1e-4  # every backend computes the eager colour
        assert rows["none", backend][2] == "1.000"  # a ratio of 1 in every round: no interval
    # Where the time goes: every pair's profile, its kinds of work adding up to its total, the differences to none's.
    where = table_rows(profiled)
    for backend in inference.BACKENDS:
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
    main([*argv, "--backends", "eager", "onnxruntime", "--fp16"])
    rows = table_rows(capsys.readouterr().out)
    assert {backend for name, backend in rows if name == "SWT-db4"} == {"eager", "onnxruntime"}
    for backend in ("eager", "onnxruntime"):
        assert 0 < float(rows["SWT-db4", backend][-1]) <= 1e-2  # half precision: close to float32, not equal


def test_inference_in_bfloat16_runs_the_torch_backends_close_to_float32(capsys):
    argv = ["inference", "--size", "16", "32", "--repeats", "1", "--configs", "SWT-db4", "--threads", "1"]
    main([*argv, "--backends", "eager", "--bf16"])
    out = capsys.readouterr().out
    assert "bf16" in out and 0 < float(table_rows(out)["SWT-db4", "eager"][-1]) <= 2e-2  # 8 bits of mantissa
    with pytest.raises(ValueError, match="onnxruntime's CPU provider has no bfloat16 convolutions"):
        inference.bench_inference((16, 32), 2.0, 1, ["none"], ["onnxruntime"], dtype=torch.bfloat16)


def test_inference_refuses_backends_its_device_cannot_run():
    with pytest.raises(ValueError, match="cudagraphs backend records CUDA graphs: it needs --device cuda"):
        inference.bench_inference((16, 32), 2.0, 1, ["none"], ["eager", "cudagraphs"])
    with pytest.raises(ValueError, match="onnxruntime is timed on the CPU only"):
        inference.bench_inference((16, 32), 2.0, 1, ["none"], ["onnxruntime"], device="cuda")
    if not torch.cuda.is_available():
        with pytest.raises(ValueError, match="--device cuda: torch sees no CUDA device"):
            inference.bench_inference((16, 32), 2.0, 1, ["none"], ["eager", "cudagraphs"], device="cuda")
