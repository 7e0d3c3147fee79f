"""Data properties (wdss.data.properties): each does what it says to a raw batch, and only that."""

from __future__ import annotations

import pytest
import torch

from wdss.data.dataset import Collate, FrameDataset
from wdss.data.layouts import discover_sequences
from wdss.data.preprocess import Preprocessing
from wdss.data.properties import PROPERTIES, gaussian_blur, with_properties
from wdss.paths import PROJECT_ROOT

KEYS = ("target", "brdf", "emission", "lr", "lr_guide", "gbuffer")


def _raw(scale: float = 2.0):
    sequences = discover_sequences(PROJECT_ROOT / "tests" / "fixtures" / "rendered")
    prep = Preprocessing()
    return Collate(KEYS, prep, scale).raw([FrameDataset(sequences, KEYS, scale=scale, preprocessing=prep)[0]], scale)


def test_gaussian_blur_keeps_constants_and_mass():
    constant = torch.full((1, 2, 9, 11), 0.7)
    torch.testing.assert_close(gaussian_blur(constant), constant)
    impulse = torch.zeros(1, 1, 9, 9, dtype=torch.float64)
    impulse[..., 4, 4] = 1.0
    blurred = gaussian_blur(impulse)
    assert float(blurred.sum()) == pytest.approx(1.0) and float(blurred[..., 4, 4]) < 0.7
    assert blurred.dtype == torch.float64 and torch.equal(blurred, blurred.transpose(-1, -2))


def test_filtered_blurs_colour_and_gbuffer_at_each_resolution_but_not_depth():
    raw, before = _raw(), _raw()
    with_properties(raw, ["filtered"], torch.Generator().manual_seed(0))
    for role in ("hr", "lr"):
        for name, t in raw.roles[role].items():
            if name == "depth":
                assert torch.equal(t, before.roles[role][name]), (role, name)
            elif name in ("color", "base_color", "normal"):
                torch.testing.assert_close(t, gaussian_blur(before.roles[role][name]))


def test_each_property_changes_what_it_names_and_nothing_else():
    changed = {
        "no_emission": {"emission"},
        "unnormalised_normals": {"normal"},
        "gbuffer_noise": {"base_color", "normal"},
        "lr_noise": {"color"},
        "depth_cm": {"depth"},
    }
    for name, buffers in changed.items():
        raw, before = _raw(), _raw()
        with_properties(raw, [name], torch.Generator().manual_seed(0))
        for role, stack in raw.roles.items():
            for buffer, t in stack.items():
                same = torch.equal(t, before.roles[role][buffer])
                if buffer not in buffers or (name == "lr_noise" and role not in ("lr", "prev_lr")):
                    assert same, (name, role, buffer)
                elif name != "no_emission" or before.roles[role][buffer].any():
                    assert not same, (name, role, buffer)
    assert set(changed) | {"filtered"} == set(PROPERTIES)


def test_unnormalised_normals_leave_the_batch_as_it_was_and_unknown_properties_are_refused():
    raw = _raw()
    plain = _raw().build()
    short = with_properties(raw, ["unnormalised_normals"], torch.Generator().manual_seed(0)).build()
    for key in ("gbuffer", "lr_guide", "lr"):
        torch.testing.assert_close(short[key], plain[key])  # the loader renormalises normals
    with pytest.raises(ValueError, match="unknown data properties"):
        with_properties(raw, ["sharpened"], torch.Generator())
