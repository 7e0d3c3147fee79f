"""The rows of a report: a row per configuration and other axis, named from the runs' overrides."""

from __future__ import annotations

from tests.report.sweeps import body, fake_sweep, t_half_width
from wdss.report.rows import overrides
from wdss.report.write import report


def test_other_axes_than_the_seed_split_rows_and_runs_names_parse_with_lists(tmp_path):
    jobs = [
        ({"variant": "swt_haar", "data.patch_size": str(p), "seed": str(s)}, {"test/psnr_2x": 30.0 + p / 100 + s}, "")
        for p in (24, 48)
        for s in (0, 1)
    ]
    uri = fake_sweep(tmp_path, "ablation_arch", [(job, metrics, "FINISHED") for job, metrics, _ in jobs])
    _, rows = body((report("ablation_arch", tracking_uri=uri, out_dir=tmp_path / "reports") / "table.md").read_text())
    assert list(rows) == ["SWT-haar, data.patch_size=24", "SWT-haar, data.patch_size=48"]
    assert rows["SWT-haar, data.patch_size=48"][0] == f"**{30.98:.2f} ± {t_half_width([30.48, 31.48]):.2f}**"

    class Run:  # only what overrides() reads
        class data:
            tags = {"mlflow.runName": "data.test_scales=[2.0,3.0],seed=1,variant=none"}

    assert overrides(Run) == {"data.test_scales": "[2.0,3.0]", "seed": "1", "variant": "none"}


def test_runs_named_variant_first_are_read_by_their_overrides_tag(tmp_path):
    jobs = [
        ({"variant": "swt_haar", "data.patch_size": str(p), "seed": str(s)}, {"test/psnr_2x": 30.0 + p / 100 + s}, "")
        for p in (24, 48)
        for s in (0, 1)
    ]
    uri = fake_sweep(tmp_path, "ablation_arch", [(j, m, "FINISHED") for j, m, _ in jobs], old=False)
    out = report("ablation_arch", tracking_uri=uri, out_dir=tmp_path / "reports")
    _, rows = body((out / "table.md").read_text())
    assert list(rows) == ["SWT-haar, data.patch_size=24", "SWT-haar, data.patch_size=48"]

    class Run:  # a name that leads with the variant is never parsed as overrides
        class data:
            tags = {"mlflow.runName": "swt_haar · patch_size=48 · seed0 · mini"}

    assert overrides(Run) == {}
    Run.data.tags = {**Run.data.tags, "overrides": "data.patch_size=48,seed=0,variant=swt_haar"}
    assert overrides(Run) == {"data.patch_size": "48", "seed": "0", "variant": "swt_haar"}
    Run.data.tags["overrides"] = ""  # a run of the defaults
    assert overrides(Run) == {}


def test_where_a_run_is_tracked_and_the_scales_it_was_tested_at_split_no_rows(tmp_path):
    """Runs of one configuration tracked in another experiment or tested at more scales (a baseline run again with
    ``data.test_scales=[2.0,3.0,4.0]``) are seeds of one row, named without those keys."""
    jobs = [
        ({"variant": "bicubic", "seed": "0"}, {"test/psnr_3x": 20.0}, "FINISHED"),
        (
            {
                "variant": "bicubic",
                "seed": "1",
                "experiment_name": "m",
                "data.test_scales": "[2.0,3.0]",
                "video": "true",
            },
            {"test/psnr_3x": 20.0},
            "FINISHED",
        ),
        ({"variant": "swt_db4", "seed": "0", "data.patch_size": "48"}, {"test/psnr_3x": 24.0}, "FINISHED"),
    ]
    uri = fake_sweep(tmp_path, "methods", jobs, old=False)
    _, rows = body((report("methods", tracking_uri=uri, out_dir=tmp_path / "reports") / "table.md").read_text())
    assert list(rows) == ["Bicubic, data.patch_size=default", "SWT-db4, data.patch_size=48"]
    assert rows["Bicubic, data.patch_size=default"][-1] == "2"
