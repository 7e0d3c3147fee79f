"""wdss.bench.probes.learn: what a network adds over its own start, on the validation scenes, over seeds."""

from __future__ import annotations

import pytest
import torch

from wdss.bench.probes import learn


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

    setup = learn._learn_setup

    def keep(overrides, seed):
        made["cfg"], made["module"], made["datamodule"] = setup(overrides, seed)
        return made["cfg"], made["module"], made["datamodule"]

    starts = []

    class Recorded(learn.StartArm):
        def __init__(self, net):
            super().__init__(net)
            self.initial = [p.detach().clone() for p in self.parameters()]
            starts.append(self)

    monkeypatch.setattr(learn, "StartArm", Recorded)
    monkeypatch.setattr(SceneDataModule, "_dataset", spy)
    monkeypatch.setattr(learn, "_learn_setup", keep)
    overrides = ["experiment=smoke", f"residual={residual}", "recipe.output_space=log", "recipe.tap_brdf=true"]
    curve, final = learn.bench_learn(overrides, steps=3, every=3, seeds=[0], scales=[2.0, 4.0])
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
    curve, final = learn.bench_learn(overrides, steps=2, every=1, seeds=[0, 1], scales=[3.0])
    assert _cells(curve)["step"] == ["0", "1", "2"]
    gain = _cells(final)["PSNR 3x"][3]  # model - kernel: mean +- half-width (seed 0, seed 1)
    mean, rest = gain.split(" +- ")
    half, per_seed = rest.split(" (")
    values = [float(v) for v in per_seed.rstrip(")").split()]
    assert len(values) == 2 and float(mean) == pytest.approx(sum(values) / 2, abs=0.006)
    assert float(half) >= 0


def test_learn_refuses_a_model_without_weights():
    with pytest.raises(SystemExit, match="trainable single-frame model"):
        learn.bench_learn(
            ["experiment=smoke", "variant=bilinear_demodulated"], steps=1, every=1, seeds=[0], scales=[2.0]
        )


def test_learn_refuses_data_without_validation_scenes():
    with pytest.raises(SystemExit, match="data.splits.val names none"):
        learn.bench_learn(["experiment=smoke", "data.splits.val=[]"], steps=1, every=1, seeds=[0], scales=[2.0])


def test_learn_reads_the_reference_buffers_for_a_model_that_does_not():
    # NSRR reads LR G-buffers only: the HR G-buffers the plain CNN and the bilinear start need are read for it.
    curve, _ = learn.bench_learn(["experiment=smoke", "variant=nsrr"], steps=1, every=1, seeds=[0], scales=[2.0])
    assert _cells(curve)["step"] == ["0", "1"]
