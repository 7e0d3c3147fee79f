"""The pictures a run logs (wdss.callbacks.images): captioned validation panels, the first test frames per scale."""

from __future__ import annotations

from types import SimpleNamespace

import numpy as np
import torch

import wdss.callbacks.images as images
from tests.helpers import batch
from tests.training.test_module import module
from wdss.callbacks.images import FirstTestFrames, ValidationPanels, comparison_panel, subband_panel
from wdss.ops.tonemap import ToneMap
from wdss.tracking.logged_run import LoggedRun


class Store:
    """What the callbacks call of an MlflowClient, keeping the images by artifact name."""

    def __init__(self) -> None:
        self.images: dict[str, np.ndarray] = {}

    def log_image(self, run_id, image, artifact_file):
        assert run_id == "0" * 32
        self.images[artifact_file] = np.asarray(image)


def logging_to(monkeypatch, store: Store | None) -> None:
    """The callbacks find ``store`` as the trainer's MLflow run (None: no run)."""
    monkeypatch.setattr(images, "logged_run", lambda trainer: store and LoggedRun(store, "0" * 32))


def test_validation_images_are_captioned_with_what_each_tile_shows(monkeypatch):
    """The validation panels logged to MLflow carry the eval videos' captions above the tiles: LR | prediction |
    target | error x4, and the subbands' names with how each is scaled; the pixels below stay the panel's."""
    store = Store()
    logging_to(monkeypatch, store)
    model = module()
    data = batch()
    with torch.no_grad():
        out = model(data)  # what validation_step returns
    ValidationPanels().on_validation_batch_end(SimpleNamespace(current_epoch=0), model, out, data, 0)
    assert set(store.images) == {"images/val_epoch000.png", "images/subbands_epoch000.png"}
    panel, subbands = comparison_panel(data, out, model.tone), subband_panel(out["coefficients"][0])
    for name, plain in (("images/val_epoch000.png", panel), ("images/subbands_epoch000.png", subbands)):
        image = store.images[name]
        plain = plain if plain.ndim == 3 else np.repeat(plain[..., None], 3, -1)  # the subbands are grey
        strip = image.shape[0] - plain.shape[0]
        assert strip > 0 and image.shape[1:] == plain.shape[1:]
        np.testing.assert_array_equal(image[strip:], plain)
        assert image[:strip].any(), f"{name}: the caption strip is blank"


def test_validation_panels_follow_image_every_n_epochs_the_first_batch_only_and_a_run(monkeypatch):
    store = Store()
    logging_to(monkeypatch, store)
    model = module(image_every_n_epochs=2)
    data = batch()
    with torch.no_grad():
        out = model(data)  # what validation_step returns
    callback = ValidationPanels()
    for epoch in range(4):
        for batch_idx in (0, 1):
            callback.on_validation_batch_end(SimpleNamespace(current_epoch=epoch), model, out, data, batch_idx)
    assert sorted(store.images) == [
        "images/subbands_epoch000.png",
        "images/subbands_epoch002.png",
        "images/val_epoch000.png",
        "images/val_epoch002.png",
    ]
    never = module(image_every_n_epochs=0)
    store.images.clear()
    callback.on_validation_batch_end(SimpleNamespace(current_epoch=0), never, out, data, 0)
    logging_to(monkeypatch, None)  # logging off
    callback.on_validation_batch_end(SimpleNamespace(current_epoch=0), model, out, data, 0)
    assert store.images == {}


def test_the_first_three_frames_of_each_scales_first_sequence_are_logged_as_the_metrics_see_them(monkeypatch):
    store = Store()
    logging_to(monkeypatch, store)
    callback = FirstTestFrames()
    tone = ToneMap("hable")

    def test_batch(sequence: str, frames: list[int], scale: float) -> tuple[dict, dict]:
        target = torch.rand(len(frames), 3, 4, 6) * 2
        step = {"sequence": [sequence] * len(frames), "frame": torch.tensor(frames), "scale": torch.full((2,), scale)}
        return step, {"shown": torch.rand(len(frames), 3, 4, 6), "shown_target": tone(target, target)}

    def uint8(image: torch.Tensor) -> np.ndarray:
        return (image.permute(1, 2, 0).numpy() * 255).round().astype(np.uint8)

    callback.on_test_epoch_start(None, None)
    outputs = []
    for sequence, frames, scale in (("a", [0, 1], 2.0), ("a", [2, 3], 2.0), ("b", [0, 1], 2.0), ("b", [0, 1], 3.0)):
        step, output = test_batch(sequence, frames, scale)
        callback.on_test_batch_end(None, None, output, step, 0)
        outputs.append(output)
    names = ("2x", "2x_t1", "2x_t2", "3x", "3x_t1")
    assert sorted(store.images) == sorted(f"test/{kind}_{name}.png" for kind in ("pred", "target") for name in names)
    np.testing.assert_array_equal(store.images["test/pred_2x.png"], uint8(outputs[0]["shown"][0]))
    np.testing.assert_array_equal(store.images["test/target_2x_t1.png"], uint8(outputs[0]["shown_target"][1]))
    np.testing.assert_array_equal(store.images["test/pred_2x_t2.png"], uint8(outputs[1]["shown"][0]))
    np.testing.assert_array_equal(store.images["test/pred_3x_t1.png"], uint8(outputs[3]["shown"][1]))

    store.images.clear()  # a new test starts over; without a run nothing is logged
    callback.on_test_epoch_start(None, None)
    callback.on_test_batch_end(None, None, *reversed(test_batch("c", [5, 6], 2.0)), 0)
    assert sorted(store.images) == [f"test/{k}_2x{t}.png" for k in ("pred", "target") for t in ("", "_t1")]
    logging_to(monkeypatch, None)
    callback.on_test_epoch_start(None, None)
    store.images.clear()
    callback.on_test_batch_end(None, None, *reversed(test_batch("c", [5, 6], 2.0)), 0)
    assert store.images == {}
