"""Reports of any runs (by id, by experiment and filter), and a parent whose children read other data."""

from __future__ import annotations

import pytest

from tests.report.sweeps import body
from wdss.report.write import report


def _adhoc_runs(root):
    """A training run of the default model with two evaluations nested under it (its own test scene and held-out
    scenes), and a baseline run on each of those data roots, logged as wdss.train and wdss.eval tag them."""
    from mlflow import MlflowClient

    uri = f"sqlite:///{root}/mlflow.db"
    client = MlflowClient(uri)
    experiment = client.create_experiment("wdss", artifact_location=(root / "artifacts").as_uri())

    def run(name, tags, psnr, parent=None, start=0):
        tags = {**tags, **({"mlflow.parentRunId": parent} if parent else {})}
        created = client.create_run(experiment, run_name=name, tags=tags, start_time=start)
        for k, scale in enumerate(("2x", "3x", "4x")):
            client.log_metric(created.info.run_id, f"test/psnr_{scale}", psnr - k)
        client.set_terminated(created.info.run_id, "FINISHED")
        return created.info.run_id

    trained = {"model": "wdss", "transform": "swt", "basis": "db4", "seed": "0"}
    training = run("experiment=cpu", {**trained, "data_root": "data/mini"}, 32.0, start=1)
    trained["overrides"] = "experiment=cpu"  # wdss.eval copies its training's
    own = run("eval epoch015.ckpt · data/mini", {**trained, "data_root": "data/mini"}, 32.1, training, 2)
    held = run("eval epoch015.ckpt · data/heldout", {**trained, "data_root": "data/heldout"}, 27.0, training, 3)
    baseline = {"model": "joint_bilateral", "transform": "n/a (baseline)", "basis": "n/a (baseline)", "seed": "0"}
    jb_mini = run("experiment=cpu,model=joint_bilateral", {**baseline, "data_root": "data/mini"}, 31.5, start=4)
    jb_held = run("experiment=cpu,model=joint_bilateral", {**baseline, "data_root": "data/heldout"}, 26.7, start=5)
    parent = client.create_run(experiment, run_name="sweep x", tags={"sweep": "x"}, start_time=6).info.run_id
    return uri, training, own, held, jb_mini, jb_held, parent


def test_any_runs_make_one_table_a_row_per_configuration_and_data(tmp_path):
    uri, training, own, held, jb_mini, jb_held, _ = _adhoc_runs(tmp_path)
    out = report(runs=[held, jb_held, jb_mini, own], tracking_uri=uri, out_dir=tmp_path / "reports")
    assert out == tmp_path / "reports" / "runs"
    _, rows = body((out / "table.md").read_text())
    assert list(rows) == [
        "SWT-db4, model=default · data/heldout",
        "Joint bilateral · data/heldout",
        "SWT-db4, model=default · data/mini",
        "Joint bilateral · data/mini",
    ]
    assert [cells[0] for cells in rows.values()] == ["**27.00 ± n/a**", "26.70 ± n/a", "**32.10 ± n/a**", "31.50 ± n/a"]
    # An experiment's runs with test metrics (the sweep parent has none), narrowed by a filter.
    out = report(experiment="wdss", filter_string="tags.data_root = 'data/heldout'", tracking_uri=uri, out_dir=tmp_path)
    _, rows = body((out / "table.md").read_text())
    assert set(rows) == {"SWT-db4, model=default", "Joint bilateral"} and out.name == "wdss"


def test_a_parent_whose_children_read_other_data_is_not_averaged_as_seeds(tmp_path):
    uri, training, own, held, *_ = _adhoc_runs(tmp_path)
    listed = r"data/heldout \(1 run\), data/mini \(1 run\)"
    with pytest.raises(SystemExit, match=rf"read different data \({listed}\).*--runs"):
        report(parent=training, tracking_uri=uri, out_dir=tmp_path)
    with pytest.raises(SystemExit, match="no run nope"):
        report(runs=["nope"], tracking_uri=uri, out_dir=tmp_path)
