"""Where a report is written: under --out, whatever the sweep's tag says."""

from __future__ import annotations

from tests.report.sweeps import fake_sweep
from wdss.report.write import report


def test_a_sweep_tag_that_names_a_path_writes_only_under_out(tmp_path):
    """The report's folder comes from the parent run's ``sweep`` tag, which anyone who logs to the store sets."""
    from wdss.report.write import path_component

    jobs = [({"variant": "swt_db4", "seed": "0"}, {"test/psnr_3x": 30.0}, "FINISHED")]
    uri = fake_sweep(tmp_path, "../../escaped", jobs)
    out = report("../../escaped", tracking_uri=uri, out_dir=tmp_path / "reports")
    assert out.parent == tmp_path / "reports" and out.name == "escaped"
    assert not (tmp_path.parent / "escaped").exists()
    assert [path_component(n) for n in ("/etc/x", "..", "ablation_wavelet", "a b")] == ["etc_x", "report"] + [
        "ablation_wavelet",
        "a_b",
    ]


def test_a_report_named_otherwise_keeps_its_sweeps_facts(tmp_path):
    """``--name`` names the folder; the scale and orderings stay those of the sweep the parent is tagged with."""
    jobs = [
        ({"variant": v, "seed": "0"}, {"test/psnr_2x": 30.0 + i, "test/psnr_3x": 28.0 + i}, "FINISHED")
        for i, v in enumerate(("bicubic", "swt_db4"))
    ]
    uri = fake_sweep(tmp_path, "methods", jobs)
    out = report("methods", name="mine", tracking_uri=uri, out_dir=tmp_path / "reports")
    text = (out / "table.md").read_text()
    assert out.name == "mine" and "Test metrics at 3x" in text and "The paper's orderings at 3x" in text


def test_runs_by_id_take_the_facts_of_the_sweep_file_they_are_named_for(tmp_path):
    """``--runs`` of a table that two sweeps ran (a sweep's jobs and rows another sweep ran) with ``--facts methods``:
    that file's scale and orderings; without it, none; an unknown name is refused before anything is written."""
    import pytest
    from mlflow import MlflowClient

    jobs = [
        (
            {"variant": v, "seed": str(seed)},
            {"test/psnr_2x": 30.0 + i + 0.1 * seed, "test/psnr_3x": 28.0 + i},
            "FINISHED",
        )
        for i, v in enumerate(("bicubic", "real_esrgan"))
        for seed in (0, 1)
    ]
    uri = fake_sweep(tmp_path, "other", jobs)
    client = MlflowClient(uri)
    runs = client.search_runs([client.get_experiment_by_name("other").experiment_id])
    ids = [r.info.run_id for r in runs if "mlflow.parentRunId" in r.data.tags]  # the jobs, not the parent
    text = (report(runs=ids, facts="methods", tracking_uri=uri, out_dir=tmp_path / "a") / "table.md").read_text()
    assert "Test metrics at 3x" in text and "- Bicubic < Real-ESRGAN: holds, +1.00 ± 0.00 dB, n=2" in text
    plain = (report(runs=ids, tracking_uri=uri, out_dir=tmp_path / "b") / "table.md").read_text()
    assert "The paper's orderings" not in plain
    with pytest.raises(SystemExit, match=r"--facts 'nope' is not a sweep file .*methods"):
        report(runs=ids, facts="nope", tracking_uri=uri, out_dir=tmp_path / "c")
    assert not (tmp_path / "c").exists()
