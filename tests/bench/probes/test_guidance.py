"""wdss.bench.probes.guidance: every method scored with each data property on the fixture."""

from __future__ import annotations

import pytest

from tests.bench.tables import table_rows
from wdss.bench.cli import main


def test_guidance_scores_every_method_with_each_property_on_the_fixture(capsys):
    from wdss.paths import PROJECT_ROOT

    fixture = str(PROJECT_ROOT / "tests" / "fixtures" / "rendered")
    main(["guidance", fixture, "--scales", "2", "--properties", "none", "unnormalised_normals", "filtered"])
    rows = table_rows(capsys.readouterr().out)
    plain, short, filtered = rows["2x", "none"], rows["2x", "unnormalised_normals"], rows["2x", "filtered"]
    assert plain == short  # the loader renormalises normals: a property no method can notice
    bilinear, joint = float(plain[0]), float(plain[1].split()[0])
    assert joint > bilinear > 10.0  # guided by the G-buffer, on the data it was made for
    assert float(plain[1].split()[1].strip("()")) == pytest.approx(joint - bilinear, abs=0.011)
    assert filtered != plain
    with pytest.raises(SystemExit, match="unknown properties"):
        main(["guidance", fixture, "--properties", "sharpened"])
