"""wdss.bench.data: what a loader worker delivers against what a training step consumes."""

from __future__ import annotations

import pytest

from tests.bench.tables import table_rows
from wdss.bench.cli import main


@pytest.mark.slow  # a DataLoader with two worker processes: ~15 s
def test_data_table_rates_every_source_in_both_placements_against_a_training_step(capsys):
    main(["data", "--size", "48", "64", "--patch", "24", "--batch", "2", "--frames", "2", "--repeats", "1"]
               + ["--step-repeats", "1", "--fetch-steps", "1", "--widths", "small"])  # fmt: skip
    out = capsys.readouterr().out
    rows = table_rows(out)
    for source in ("EXR (zip, half)", "packed zstd", "packed raw"):
        for placement in ("loader", "device"):
            ms, rate, to_exr, to_step = rows[source, placement]
            assert float(ms) > 0 and float(rate) > 0 and float(to_exr.rstrip("x")) > 0 and to_step.endswith("x")
    assert rows["EXR (zip, half)", "loader"][2] == "1.0x" and rows["training step", "-"][3] == "1.0x"
    assert "time each step waits for its batch" in out
