"""Jittered LR frames: the sequence, the batch key, and every upsampler placing the LR pixels where they were shaded."""

from __future__ import annotations

import json

import pytest
import torch

from tests.helpers import TINY, head, upsampler
from wdss.data import Collate, FrameDataset, SceneError, Sequence
from wdss.data.synthetic import write_sequence
from wdss.nets.upsamplers.joint_bilateral import joint_bilateral_upsample
from wdss.nets.upsamplers.learned_bilateral import LearnedBilateralUpsample
from wdss.nets.wdss.network import FourierINR, WDSSNet
from wdss.ops.sampling import JITTER_PHASES, halton_jitter, upsample
from wdss.ops.warp import spatial_mask

HR = (24, 36)
JITTER = torch.tensor([[0.3, -0.2], [-0.45, 0.1], [0.0, 0.0]])


def test_the_jitter_sequence_is_halton_2_3_centred_and_cycles():
    assert halton_jitter(0) == pytest.approx((0.0, 1 / 3 - 0.5))  # Halton point 1: (1/2, 1/3)
    assert halton_jitter(1) == pytest.approx((-0.25, 2 / 3 - 0.5))  # point 2: (1/4, 2/3)
    assert halton_jitter(2) == pytest.approx((0.25, 1 / 9 - 0.5))  # point 3: (3/4, 1/9)
    points = [halton_jitter(f) for f in range(JITTER_PHASES)]
    assert len(set(points)) == JITTER_PHASES and all(-0.5 <= c < 0.5 for p in points for c in p)
    assert halton_jitter(JITTER_PHASES + 3) == halton_jitter(3)


def _ramp(jitter: torch.Tensor, scale: int) -> tuple[torch.Tensor, torch.Tensor]:
    """A linear function of the HR position shaded at each jittered LR sample, and on the HR pixel centres."""
    (height, width), n = HR, jitter.shape[0]
    h, w = height // scale, width // scale

    def f(x: torch.Tensor, y: torch.Tensor) -> torch.Tensor:
        return 1.0 + 0.1 * x[None, :] + 0.05 * y[:, None]

    hr = f(torch.arange(width) + 0.5, torch.arange(height) + 0.5).expand(n, 1, height, width)
    lr = torch.stack(
        [f((torch.arange(w) + 0.5 + jx) * scale, (torch.arange(h) + 0.5 + jy) * scale)[None] for jx, jy in jitter]
    )
    return lr, hr


@pytest.mark.parametrize("scale", [2, 3, 4])
def test_bilinear_and_joint_bilateral_interpolate_a_ramp_exactly_from_where_the_lr_was_shaded(scale):
    """Tent and bilinear interpolation reproduce a linear function exactly, away from the borders, when the LR
    samples are placed where they were taken; taken as centred, they miss by the jitter times the ramp's slope."""
    lr, hr = _ramp(JITTER, scale)
    n, (h, w) = JITTER.shape[0], lr.shape[-2:]
    flat = dict(gbuffer=torch.zeros(n, 11, *HR), lr_guide=torch.zeros(n, 7, h, w))  # every guide alike: tent only
    inner = (..., slice(2 * scale, -2 * scale), slice(2 * scale, -2 * scale))
    for result in (
        upsample(lr, HR, "bilinear", JITTER),
        joint_bilateral_upsample(lr, flat["gbuffer"], lr_guide=flat["lr_guide"], lr_jitter=JITTER),
    ):
        torch.testing.assert_close(result[inner], hr[inner], atol=1e-5, rtol=0)
    centred = joint_bilateral_upsample(lr, flat["gbuffer"], lr_guide=flat["lr_guide"])
    assert (centred - hr)[0][inner].abs().max() > 0.01 * scale  # 0.1 * 0.3 * s: the first sample's shift


def test_a_zero_jitter_is_the_centred_path_and_each_sample_keeps_its_own():
    torch.manual_seed(0)
    lr, gbuffer, guide = torch.rand(3, 3, 8, 12), torch.rand(3, 11, 24, 36), torch.rand(3, 7, 8, 12)
    centred = joint_bilateral_upsample(lr, gbuffer, lr_guide=guide)
    assert torch.equal(joint_bilateral_upsample(lr, gbuffer, lr_guide=guide, lr_jitter=torch.zeros(3, 2)), centred)
    assert torch.equal(upsample(lr, (24, 36), "bilinear", torch.zeros(3, 2)), upsample(lr, (24, 36)))
    # A batch of differently jittered samples is each sample upsampled alone with its own jitter.
    batched = joint_bilateral_upsample(lr, gbuffer, lr_guide=guide, lr_jitter=JITTER)
    for i in range(3):
        alone = joint_bilateral_upsample(lr[i : i + 1], gbuffer[i : i + 1], lr_guide=guide[i : i + 1])
        if JITTER[i].any():
            alone = joint_bilateral_upsample(
                lr[i : i + 1], gbuffer[i : i + 1], lr_guide=guide[i : i + 1], lr_jitter=JITTER[i : i + 1]
            )
        torch.testing.assert_close(batched[i : i + 1], alone)
    torch.testing.assert_close(batched[2:], centred[2:])
    with pytest.raises(ValueError, match="lr_jitter"):
        joint_bilateral_upsample(lr, gbuffer, lr_guide=guide, lr_jitter=torch.zeros(3))


def test_the_learned_kernel_starts_as_joint_bilateral_at_the_same_jitter():
    torch.manual_seed(1)
    lr, gbuffer, guide = torch.rand(3, 3, 8, 12), torch.rand(3, 11, 24, 36), torch.rand(3, 7, 8, 12)
    kernel = LearnedBilateralUpsample()
    torch.testing.assert_close(
        kernel.upsample(lr, gbuffer, lr_guide=guide, lr_jitter=JITTER),
        joint_bilateral_upsample(lr, gbuffer, lr_guide=guide, lr_jitter=JITTER, **kernel.ranges),
        atol=1e-5,
        rtol=1e-5,
    )


def test_the_network_reads_the_jitter_per_sample_in_its_inr_offsets_and_its_residual():
    torch.manual_seed(2)
    net = WDSSNet("swt", "haar", head("shared_inr"), False, upsampler=upsampler("joint_bilateral"), **TINY).eval()
    for p in net.parameters():  # a non-zero exit: the INR's output reaches the image
        p.data.normal_(0, 0.1)
    assert "lr_jitter" in net.inputs
    inputs = dict(
        lr=torch.rand(3, 3, 8, 12),
        gbuffer=torch.rand(3, 11, 16, 24),
        spatial_mask=torch.zeros(3, 1, 16, 24),
        scale=torch.full((3,), 2.0),
        lr_guide=torch.rand(3, 7, 8, 12),
    )
    with torch.no_grad():
        centred = net(**inputs)["irradiance"]
        torch.testing.assert_close(net(**inputs, lr_jitter=torch.zeros(3, 2))["irradiance"], centred)
        jittered = net(**inputs, lr_jitter=JITTER)["irradiance"]
    assert not torch.allclose(jittered[:2], centred[:2], atol=1e-4)
    torch.testing.assert_close(jittered[2:], centred[2:])  # the third sample is not jittered


@pytest.mark.parametrize("lr_cell,scale,jitter", [(2, 2, -1.0), (1, 4, -0.5)])
def test_the_inr_offsets_move_by_the_jitter_in_lr_pixels(lr_cell, scale, jitter):
    """With spatially constant features an INR's output varies only with each HR/2 cell's offset from its LR cell.
    Here two HR/2 rows (columns) share an LR cell, one row apart in offset by ``jitter`` LR pixels: jittered by it,
    row r must give what row r + 1 gives centred (a wrong sign, unit or axis does not)."""
    torch.manual_seed(4)
    inr = FourierINR(4, 4, 8, 8, 1, 4)
    inr.exit = torch.nn.Identity()  # the 3x3 exit would mix rows
    hr, lr = 32, 32 // scale
    lr_feature = torch.rand(1, 4, 1, 1).expand(1, 4, lr // lr_cell, lr // lr_cell).contiguous()
    gb_feature = torch.rand(1, 4, 1, 1).expand(1, 4, hr // 2, hr // 2).contiguous()
    args = (lr_feature, gb_feature, torch.full((1,), float(scale)), (hr, hr), (lr, lr), lr_cell)
    with torch.no_grad():
        centred = inr(*args)
        down = inr(*args, torch.tensor([[0.0, jitter]]))
        right = inr(*args, torch.tensor([[jitter, 0.0]]))
    inner = slice(2, hr // 2 - 2)  # away from the convolutions' zero padding
    for r in range(2, hr // 2 - 3, 2):
        torch.testing.assert_close(down[..., r, inner], centred[..., r + 1, inner])
        torch.testing.assert_close(right[..., inner, r], centred[..., inner, r + 1])
    assert not torch.allclose(down[..., 2, inner], centred[..., 2, inner])


def test_the_spatial_mask_compares_the_hr_g_buffer_with_the_lr_one_where_it_was_shaded():
    """A depth step shaded at jittered LR positions agrees with the HR step where the mask places it right."""
    height, width, s = 16, 32, 4
    jitter = torch.tensor([[0.5, 0.0]])
    x_hr = torch.arange(width) + 0.5
    x_lr = (torch.arange(width // s) + 0.5 + 0.5) * s

    def buffers(x: torch.Tensor, h: int) -> dict:
        depth = (0.2 + 0.02 * x).view(1, 1, 1, -1).expand(1, 1, h, -1)  # a ramp: bilinear reproduces it
        return {"depth": depth, "normal": torch.tensor([0.0, 0.0, 1.0]).view(1, 3, 1, 1).expand(1, 3, h, x.numel()),
                "base_color": torch.full((1, 3, h, x.numel()), 0.5)}  # fmt: skip

    hr, lr = buffers(x_hr, height), buffers(x_lr, height // s)
    inner = (..., slice(None), slice(2 * s, -2 * s))
    assert spatial_mask(hr, lr, jitter=jitter)[inner].sum() == 0
    assert spatial_mask(hr, lr)[inner].sum() > 0  # taken as centred, every depth is off by 0.02 * 0.5 * 4


def _jittered_sequence(path, jitter: dict[int, list[float]]):
    folder = write_sequence(path, frames=(1, 2), size=HR, scales=(2,), cameras=True)
    meta = json.loads((folder / "sequence.json").read_text())
    for entry in meta["frames"]:
        if entry["frame"] in jitter:
            entry["lr_jitter"] = jitter[entry["frame"]]
    (folder / "sequence.json").write_text(json.dumps(meta))
    return folder


def test_the_batch_carries_each_frames_recorded_jitter_mirrored_with_the_image(tmp_path):
    folder = _jittered_sequence(tmp_path / "seq", {1: [0.25, -0.125], 2: [-0.375, 0.3]})
    keys = ["lr", "lr_guide", "lr_jitter", "gbuffer", "target"]
    native = FrameDataset([Sequence(folder)], keys, scale=2.0, lr_source="native")
    batch = Collate(native.keys, native.prep, 2.0)([native[0], native[1]])
    torch.testing.assert_close(batch["lr_jitter"], torch.tensor([[0.25, -0.125], [-0.375, 0.3]]))
    # Point samples of the HR frame are taken here, at the LR pixel centres' HR pixels: no jitter.
    point = FrameDataset([Sequence(folder)], keys, scale=2.0, lr_source="point")
    assert torch.equal(Collate(point.keys, point.prep, 2.0)([point[0]])["lr_jitter"], torch.zeros(1, 2))
    # Mirrored frames: the jitter changes sign along each axis the image was mirrored on.
    flipped = FrameDataset([Sequence(folder)], keys, scale=2.0, lr_source="native", flips=True, seed=3)
    unflipped = native[0]["lr"]["color"]
    seen = set()
    for epoch in range(12):
        sample = flipped[(0, epoch, 2.0)]
        color = sample["lr"]["color"]
        horizontal = not torch.equal(color, unflipped) and torch.equal(color, unflipped.flip(-1))
        vertical = not torch.equal(color, unflipped) and torch.equal(color, unflipped.flip(-2))
        both = torch.equal(color, unflipped.flip(-1, -2))
        signs = (-1 if horizontal or both else 1, -1 if vertical or both else 1)
        assert sample["lr_jitter"].tolist() == [0.25 * signs[0], -0.125 * signs[1]]
        seen.add(signs)
    assert len(seen) == 4  # every combination of mirrored axes occurred


def test_a_recorded_jitter_beyond_half_a_pixel_is_refused_naming_the_file_and_frame(tmp_path):
    folder = _jittered_sequence(tmp_path / "seq", {2: [0.7, 0.0]})
    with pytest.raises(SceneError, match=r"sequence\.json.*frame 2.*half a pixel"):
        Sequence(folder)
