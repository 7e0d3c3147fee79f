"""Composing the network (its head and residual upsampler built from config groups, issue 39) changed no network:
every config choice builds the same state_dict (keys, shapes, order) with the same seeded values, asks for the same
inputs and computes the same output as the network that took them by name did. The expected values were recorded
from that network (commit 1cea5ed) with the overrides of its day, which :data:`CASES` lists beside today's."""

from __future__ import annotations

import hashlib
from typing import NamedTuple

import pytest
import torch

from tests.test_train import compose_train
from wdss.config.targets import instantiate
from wdss.nets.upsamplers.learned_bilateral import LearnedBilateralUpsample

HEADS = ("shared_inr", "multi_inr", "fusion_ll")
RESIDUALS = ("none", "bilinear", "joint_bilateral", "learned_bilateral")
# name -> (the overrides before the composition, which recorded the expected values; today's)
CASES: dict[str, tuple[list[str], list[str]]] = {
    f"cpu-{h}-{r}": (
        ["experiment=cpu", f"head={h}", f"recipe.residual={r}"],
        ["experiment=cpu", f"head={h}", f"residual={r}"],
    )
    for h in HEADS
    for r in RESIDUALS
}
CASES.update(
    {
        "experiment-cpu": (["experiment=cpu"], ["experiment=cpu"]),
        "paper-default": ([], []),
        "paper-learned_bilateral": (["recipe.residual=learned_bilateral"], ["residual=learned_bilateral"]),
        "experiment-paper": (["experiment=paper"], ["experiment=paper"]),
        "cpu-no-wavelet": (["experiment=cpu", "variant=none"], ["experiment=cpu", "variant=none"]),
        "cpu-multi_inr-variant": (["experiment=cpu", "variant=multi_inr"], ["experiment=cpu", "variant=multi_inr"]),
        "cpu-fusion_ll-variant": (["experiment=cpu", "variant=fusion_ll"], ["experiment=cpu", "variant=fusion_ll"]),
        "cpu-dfasr": (["experiment=cpu", "variant=dfasr"], ["experiment=cpu", "variant=dfasr"]),
        "dfasr": (["variant=dfasr"], ["variant=dfasr"]),
        "cpu-residual-input-refine": (
            [
                "experiment=cpu",
                "recipe.residual=joint_bilateral",
                "recipe.residual_input=true",
                "recipe.refine_width=8",
            ],
            ["experiment=cpu", "residual=joint_bilateral", "recipe.residual_input=true", "recipe.refine_width=8"],
        ),
        "cpu-kernel-never-raise": (
            [
                "experiment=cpu",
                "recipe.kernel_never_raise=true",
                "recipe.kernel_raise_within_albedo=false",
                "recipe.tap_brdf=false",
            ],
            [
                "experiment=cpu",
                "recipe.kernel_never_raise=true",
                "recipe.kernel_raise_within_albedo=false",
                "recipe.tap_brdf=false",
            ],
        ),
    }
)
PLAIN = ("lr", "gbuffer", "spatial_mask", "history", "temporal_mask", "lr_jitter")
GUIDED = ("lr", "gbuffer", "spatial_mask", "history", "temporal_mask", "lr_guide", "lr_jitter")
TAP_BRDF = (*GUIDED, "brdf", "lr_brdf")


class Built(NamedTuple):
    """What a seeded build gives: the state_dict's tensor count and layout (sha256 of its ``key shape`` lines, in
    order), the float64 sum of every value and of each tensor's absolute values weighted by its position, the inputs,
    the learned kernel's (tap_brdf, never_raise, raise_within_albedo), and the sum of a forward's irradiance."""

    tensors: int
    layout: str
    sum: float
    weighted: float
    inputs: tuple[str, ...]
    kernel: tuple[bool, bool, bool] | None
    output: float


EXPECTED = {
    "cpu-shared_inr-none": Built(
        60, "33ded4ec26ad0e9a", 19.504645174257405, 158326.87141870332, PLAIN, None, 129.98259942795994
    ),
    "cpu-shared_inr-bilinear": Built(
        60, "33ded4ec26ad0e9a", 19.45707265302923, 154629.1902135433, PLAIN, None, 2438.8179894327186
    ),
    "cpu-shared_inr-joint_bilateral": Built(
        60, "33ded4ec26ad0e9a", 19.45707265302923, 154629.1902135433, GUIDED, None, 2435.0739757250994
    ),
    "cpu-shared_inr-learned_bilateral": Built(
        66, "34e5ade0888a647c", 17.68247514953788, 188008.25201085224, TAP_BRDF, (True, False, True), 2276.4129888266907
    ),
    "cpu-multi_inr-none": Built(
        78, "9e10df4260c33234", 21.150663981305172, 177204.66314737452, PLAIN, None, 76.05485654846416
    ),
    "cpu-multi_inr-bilinear": Built(
        78, "9e10df4260c33234", 19.469036158064284, 172379.65965471993, PLAIN, None, 2357.9100546240807
    ),
    "cpu-multi_inr-joint_bilateral": Built(
        78, "9e10df4260c33234", 19.469036158064284, 172379.65965471993, GUIDED, None, 2354.4345921422355
    ),
    "cpu-multi_inr-learned_bilateral": Built(
        84, "3e0bcffdd6f36a81", 15.588468707181221, 206336.570024594, TAP_BRDF, (True, False, True), 2245.3884124830365
    ),
    "cpu-fusion_ll-none": Built(
        60, "19375566df681079", 4.833840690769421, 135118.495976106, PLAIN, None, 94.47609492909396
    ),
    "cpu-fusion_ll-bilinear": Built(
        60, "19375566df681079", 5.489826259623214, 131406.09286172665, PLAIN, None, 2413.727868683636
    ),
    "cpu-fusion_ll-joint_bilateral": Built(
        60, "19375566df681079", 5.489826259623214, 131406.09286172665, GUIDED, None, 2410.30264077615
    ),
    "cpu-fusion_ll-learned_bilateral": Built(
        66,
        "257abf228abaa356",
        3.4126149418214027,
        162124.27853678804,
        TAP_BRDF,
        (True, False, True),
        2465.4837316051126,
    ),
    "experiment-cpu": Built(
        66, "34e5ade0888a647c", 17.68247514953788, 188008.25201085224, TAP_BRDF, (True, False, True), 2276.4129888266907
    ),
    "paper-default": Built(
        62, "f48e49b016f8cdf9", 28.148825959651237, 362763.5939238268, PLAIN, None, 317.7159005981521
    ),
    "paper-learned_bilateral": Built(
        68, "24643e65d84d166e", 20.934309979672395, 441771.98482120736, GUIDED, (False, False, True), 2312.6045777760446
    ),
    "experiment-paper": Built(
        62, "f48e49b016f8cdf9", 28.148825959651237, 362763.5939238268, PLAIN, None, 317.7159005981521
    ),
    "cpu-no-wavelet": Built(
        66, "26a492581fbb4039", 1.8217271863841233, 141212.7308561588, TAP_BRDF, (True, False, True), 2265.911430203356
    ),
    "cpu-multi_inr-variant": Built(
        84, "7fc930e25c67dbb4", 3.735878267015323, 153013.33385116464, TAP_BRDF, (True, False, True), 2496.9920691307634
    ),
    "cpu-fusion_ll-variant": Built(
        66,
        "257abf228abaa356",
        3.4126149418214027,
        162124.27853678804,
        TAP_BRDF,
        (True, False, True),
        2465.0101088136435,
    ),
    "cpu-dfasr": Built(
        65, "a7fdc5580acada93", 10.057249347917036, 138796.6858361613, TAP_BRDF, (True, False, True), 2365.1605871412903
    ),
    "dfasr": Built(61, "5d8c223917e67047", 28.030187659984538, 306537.15230027965, PLAIN, None, 573.2516637444496),
    "cpu-residual-input-refine": Built(
        66, "812b7f4245ef1a5b", 23.981248086163475, 160102.03980127943, GUIDED, None, 2252.8176331128925
    ),
    "cpu-kernel-never-raise": Built(
        66, "82abf720516e5bd8", 21.61082899467243, 188083.11807756205, GUIDED, (False, True, False), 2352.7247848026454
    ),
}


def _output(net: torch.nn.Module) -> float:
    """The sum of the irradiance of one forward on fixed random inputs, after a fixed random change of every weight
    (so that the zero exits and kernel layers of the start do not hide a path)."""
    g = torch.Generator().manual_seed(1)
    h, w, lh, lw = 18, 22, 9, 11
    data = {
        "lr": torch.rand(2, 3, lh, lw, generator=g) * 2,
        "gbuffer": torch.rand(2, 11, h, w, generator=g),
        "spatial_mask": torch.rand(2, 1, h, w, generator=g),
        "history": torch.rand(2, 3, h, w, generator=g),
        "temporal_mask": torch.rand(2, 5, h, w, generator=g),
        "brdf": torch.rand(2, 3, h, w, generator=g) + 0.1,
        "lr_brdf": torch.rand(2, 3, lh, lw, generator=g) + 0.1,
        "lr_guide": torch.rand(2, 7, lh, lw, generator=g),
        "lr_jitter": torch.rand(2, 2, generator=g) - 0.5,
    }
    with torch.no_grad():
        for p in net.parameters():
            p.add_(0.05 * torch.randn(p.shape, generator=g))
        out = net(**{k: data[k] for k in net.inputs}, scale=torch.tensor([2.0, 2.0]))
    return float(out["irradiance"].double().sum())


def built(overrides: list[str]) -> Built:
    torch.manual_seed(0)
    net = instantiate(compose_train(overrides).model.net, at="net")
    state = net.state_dict()
    layout = "\n".join(f"{key} {tuple(value.shape)}" for key, value in state.items())
    values = [value.double() for value in state.values()]
    kernel = net.upsampler
    return Built(
        len(state),
        hashlib.sha256(layout.encode()).hexdigest()[:16],
        float(sum(v.sum() for v in values)),
        float(sum((k + 1) * v.abs().sum() for k, v in enumerate(values))),
        tuple(net.inputs),
        (kernel.tap_brdf, kernel.never_raise, kernel.raise_within_albedo)
        if isinstance(kernel, LearnedBilateralUpsample)
        else None,
        _output(net),
    )


def test_every_head_and_residual_is_a_case():
    assert {f"cpu-{h}-{r}" for h in HEADS for r in RESIDUALS} <= set(CASES) and set(CASES) == set(EXPECTED)


# Recorded when experiment=cpu's recipe started the exit at zero (recipe.exit_init=0.3 since): set as it was then.
THEN = ["recipe.exit_init=0.0"]


@pytest.mark.parametrize("name", list(CASES))
def test_the_composed_network_is_the_one_built_by_name(name):
    expected, got = EXPECTED[name], built([*CASES[name][1], *THEN])
    assert (got.tensors, got.layout) == (expected.tensors, expected.layout)  # keys, shapes and their order
    assert got.sum == pytest.approx(expected.sum, rel=1e-9, abs=1e-9)  # the same random numbers...
    assert got.weighted == pytest.approx(expected.weighted, rel=1e-9)  # ...in the same tensors
    assert got.inputs == expected.inputs and got.kernel == expected.kernel
    assert got.output == pytest.approx(expected.output, rel=1e-5)
