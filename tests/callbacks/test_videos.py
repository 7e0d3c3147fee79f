"""The test videos' callback (wdss.callbacks.videos): written per sequence and scale, logged to the trainer's MLflow
run when it has one."""

from pathlib import Path


def test_the_videos_of_a_test_are_logged_to_the_trainers_mlflow_run_and_written_without_one(tmp_path, monkeypatch):
    from types import SimpleNamespace

    import torch

    import wdss.callbacks.videos as video
    from wdss.callbacks.videos import SequenceVideos
    from wdss.ops.tonemap import ToneMap
    from wdss.tracking.logged_run import LoggedRun

    logged = []
    client = SimpleNamespace(log_artifact=lambda run_id, path, folder: logged.append((run_id, Path(path).name, folder)))
    trainer, module = SimpleNamespace(datamodule=None), SimpleNamespace(tone=ToneMap("hable"))
    for run in (LoggedRun(client, "run"), None):
        monkeypatch.setattr(video, "logged_run", lambda trainer, run=run: run)
        videos = SequenceVideos(tmp_path / ("logged" if run else "unlogged"))
        for first in (0, 2):
            step = {"target": torch.rand(2, 3, 8, 12), "sequence": ["seq", "seq"], "scale": torch.full((2,), 2.0)}
            videos.on_test_batch_end(trainer, module, {"shown": torch.rand(2, 3, 8, 12)}, step, first)
        videos.on_test_epoch_end(trainer, module)
        assert sorted(p.name for p in videos.out_dir.iterdir()) == ["seq_2x.mp4", "seq_2x_crop.gif"]
    assert logged == [("run", "seq_2x.mp4", "videos"), ("run", "seq_2x_crop.gif", "videos")]
