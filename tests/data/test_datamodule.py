"""Batches from scenes: need-driven opens, alignment of LR and HR, history, scales and determinism."""

from __future__ import annotations

import json
import re
from pathlib import Path

import pytest
import torch
from hydra import compose, initialize_config_dir

from wdss.data import (
    BATCH_KEYS,
    Collate,
    FrameDataset,
    Preprocessing,
    SceneDataModule,
    SceneError,
    Sequence,
    point_sample,
)
from wdss.data.synthetic import write_sequence
from wdss.ops.brdf import demodulate, extranet_brdf, safe_brdf

HR = (24, 36)


@pytest.fixture(scope="module")
def root(tmp_path_factory) -> Path:
    root = tmp_path_factory.mktemp("scenes")
    write_sequence(root / "seq_a", layout="unreal", frames=(1, 2, 3, 4), size=HR, scales=(2, 3), cameras=True)
    write_sequence(root / "seq_b", layout="dfasr", frames=(1, 2, 3), size=HR, scales=(2, 3), seed=1)
    return root


def frames_of(names: list[str]) -> set[int]:
    return {int(re.search(r"\.(\d+)\.exr$", n).group(1)) for n in names}


def test_a_model_without_temporal_branch_opens_no_previous_frame(root, opened):
    keys = ["lr", "gbuffer", "spatial_mask", "brdf", "target"]
    dataset = FrameDataset([Sequence(root / "seq_a")], keys, scale=2.0)
    assert len(dataset) == 4  # no history needed: the first frame is a sample too
    for index in range(len(dataset)):
        opened.clear()
        frame = dataset[index]["frame"]
        assert frames_of(opened) == {frame}, opened
        # HR: all four packed files; native 12P: colour, base colour/depth, normal/specular (metallic rides with
        # colour) for demodulation and the spatial mask -- no motion vectors anywhere.
        assert sorted(opened) == sorted(
            [
                f"24P/{s}.{frame:04d}.exr"
                for s in ("BaseColorDepth", "NormalSpecular", "PretonemapMetallic", "MV_Roughness_NOV")
            ]
            + [f"12P/{s}.{frame:04d}.exr" for s in ("BaseColorDepth", "NormalSpecular", "PretonemapMetallic")]
        )


def test_a_bare_model_reads_one_file_per_resolution(root, opened):
    prep = Preprocessing(demodulate=False)
    dataset = FrameDataset([Sequence(root / "seq_a")], ["lr", "target"], scale=3.0, preprocessing=prep)
    sample = dataset[0]
    assert sorted(opened) == ["24P/PretonemapMetallic.0001.exr", "8P/PretonemapMetallic.0001.exr"]
    assert sample["lr"]["color"].shape == (3, 8, 12)


def test_history_reads_the_previous_frame_and_skips_first_frames(root, opened):
    dataset = FrameDataset([Sequence(root / "seq_a")], ["history", "temporal_mask", "target"], scale=2.0)
    assert [frame for _, frame in dataset.items] == [2, 3, 4]
    dataset[0]
    assert frames_of(opened) == {1, 2}
    keep = FrameDataset([Sequence(root / "seq_a")], ["history"], scale=2.0, first_frame="zeros")
    assert [frame for _, frame in keep.items] == [1, 2, 3, 4]
    assert keep[0]["prev"]["color"].abs().sum() == 0


@pytest.mark.parametrize("sequence", ["seq_a", "seq_b"])
def test_full_frame_batch_values(root, sequence):
    dm = SceneDataModule(root, {"train": [sequence], "test": [sequence]}, BATCH_KEYS, test_scales=[2.0])
    dm.setup("test")
    batch = next(iter(dm.test_dataloader()[0]))
    assert set(BATCH_KEYS) | {"scale", "sequence", "frame"} == set(batch)
    for key in BATCH_KEYS:
        assert batch[key].dtype == torch.float32 and torch.isfinite(batch[key]).all(), key
    assert batch["target"].shape == (1, 3, *HR) and batch["lr"].shape == (1, 3, 12, 18)
    assert batch["gbuffer"].shape == (1, 11, *HR) and batch["temporal_mask"].shape == (1, 5, *HR)
    # The native 12P folder holds point samples of the HR frame, so lr is the demodulated point sample.
    seq = Sequence(root / sequence)
    frame = int(batch["frame"][0])
    hr = {
        k: torch.from_numpy(v)[None]
        for k, v in seq.read(frame, 24, ["color", "base_color", "metallic", "specular"]).items()
    }
    lr = {k: point_sample(v, (12, 18)) for k, v in hr.items()}
    expected = demodulate(lr["color"], safe_brdf(extranet_brdf(lr["base_color"], lr["metallic"], lr["specular"])))
    torch.testing.assert_close(batch["lr"], expected)
    # The emitter (black albedo, colour 5) passes through demodulation and remodulates to itself.
    assert (batch["brdf"] == 1).any() and torch.allclose(
        batch["target"] / batch["brdf"] * batch["brdf"], batch["target"]
    )
    # The synthetic content translates by the motion vectors, so the warped previous irradiance is the current
    # irradiance wherever the history came from inside the frame.
    current = batch["target"] / batch["brdf"]
    inside = batch["history"].abs().sum(1) > 1e-3  # outside: 0 up to grid_sample rounding (~1e-7)
    torch.testing.assert_close(batch["history"][:, :, inside[0]], current[:, :, inside[0]], rtol=1e-5, atol=1e-5)
    assert inside.float().mean() > 0.9


@pytest.mark.parametrize("scale, size", [(2.0, (12, 18)), (3.0, (8, 12)), (2.5, (10, 14)), (4.0, (6, 9))])
def test_any_scale_gives_the_rounded_grid(root, scale, size):
    dm = SceneDataModule(root, {"test": ["seq_a"]}, ["lr", "target"], test_scales=[scale])
    dm.setup("test")
    batch = next(iter(dm.test_dataloader()[0]))
    assert batch["lr"].shape[-2:] == size and batch["scale"].tolist() == [scale]


def test_patches_align_native_lr_with_hr(root):
    dataset = FrameDataset([Sequence(root / "seq_a")], ["lr_color", "target"], scale=3.0, patch=12)
    torch.manual_seed(0)
    for index in range(len(dataset)):
        sample = dataset[index]
        assert sample["hr"]["color"].shape == (3, 12, 12) and sample["lr"]["color"].shape == (3, 4, 4)
        torch.testing.assert_close(sample["lr"]["color"], point_sample(sample["hr"]["color"][None], (4, 4))[0])


def test_arbitrary_scale_is_one_per_batch_and_varies(root):
    dm = SceneDataModule(
        root, {"train": ["seq_a", "seq_b"]}, ["lr", "target"], scale=[2, 4], patch_size=12, batch_size=2
    )
    dm.setup("fit")
    torch.manual_seed(0)
    scales = []
    for _ in range(4):
        for batch in dm.train_dataloader():
            assert len(set(batch["scale"].tolist())) == 1
            s = float(batch["scale"][0])
            assert 2 <= s <= 4 and batch["lr"].shape[-1] == round(12 / s)
            scales.append(s)
    assert len(set(scales)) > 1


def test_same_seed_same_batches(root):
    def first_batch():
        torch.manual_seed(123)
        dm = SceneDataModule(root, {"train": ["seq_a"]}, ["target", "gbuffer"], patch_size=12, batch_size=2, seed=7)
        dm.setup("fit")
        return next(iter(dm.train_dataloader()))

    a, b = first_batch(), first_batch()
    assert a["frame"].tolist() == b["frame"].tolist()
    torch.testing.assert_close(a["target"], b["target"])


def test_another_seed_draws_other_batches_and_the_data_group_follows_the_runs_seed(root):
    def first_batch(seed):
        dm = SceneDataModule(root, {"train": ["seq_a"]}, ["target", "gbuffer"], patch_size=12, batch_size=2, seed=seed)
        dm.setup("fit")
        return next(iter(dm.train_dataloader()))

    assert not torch.equal(first_batch(7)["target"], first_batch(8)["target"])
    # seed=S varies the data's draws too, not only the weights: an interval over seeds holds both
    conf = Path(__file__).resolve().parents[2] / "conf"
    with initialize_config_dir(config_dir=str(conf), version_base="1.3"):
        for experiment in ("cpu", "bench"):
            cfg = compose("train", overrides=[f"experiment={experiment}", "seed=3"])
            assert cfg.data.seed == 3, experiment
        assert compose("eval", overrides=["ckpt_path=x"]).data.seed == 0


def test_flips_mirror_only_sequences_with_camera_rotations(root, caplog):
    """Mirroring world-space normals needs each frame's camera: frames without one are read unmirrored, said once."""
    dm = SceneDataModule(root, {"train": ["seq_a"]}, ["gbuffer", "motion"], patch_size=12, batch_size=2, flips=True)
    dm.setup("fit")
    assert next(iter(dm.train_dataloader()))["gbuffer"].shape == (2, 11, 12, 12)
    assert not dm.datasets["train"].unmirrored
    with caplog.at_level("WARNING", logger="wdss.data.dataset"):
        dm = SceneDataModule(root, {"train": ["seq_b"]}, ["gbuffer"], patch_size=None, batch_size=1, flips=True)
        dm.setup("fit")
    assert "seq_b has no camera rotation per frame in sequence.json" in caplog.text
    plain = SceneDataModule(root, {"train": ["seq_b"]}, ["gbuffer"], patch_size=None, batch_size=1, flips=False)
    plain.setup("fit")
    drawn, read = dm.datasets["train"], plain.datasets["train"]
    for epoch in range(4):  # every draw of four epochs: no sample of seq_b is mirrored
        for i in range(len(drawn)):
            a, b = drawn[(i, epoch)]["hr"], read[(i, epoch)]["hr"]
            assert all(torch.equal(torch.as_tensor(a[k]), torch.as_tensor(b[k])) for k in b)
    # With the cameras it has, seq_a is mirrored: some sample differs from its unflipped read.
    flipped = FrameDataset([Sequence(root / "seq_a")], ["gbuffer"], patch=None, flips=True, seed=3)
    unflipped = FrameDataset([Sequence(root / "seq_a")], ["gbuffer"], patch=None, flips=False, seed=3)
    assert any(
        not torch.equal(
            torch.as_tensor(flipped[(i, e)]["hr"]["normal"]), torch.as_tensor(unflipped[(i, e)]["hr"]["normal"])
        )
        for e in range(4)
        for i in range(len(flipped))
    )


def test_configuration_errors_are_clear(root):
    with pytest.raises(ValueError, match=r"unknown batch keys \['albedo'\]"):
        FrameDataset([Sequence(root / "seq_a")], ["albedo"])
    with pytest.raises(ValueError, match="unknown split"):
        SceneDataModule(root, {"training": ["seq_a"]}, ["target"])
    with pytest.raises(ValueError, match="brdf must be 'extranet' or 'split_sum'"):
        Preprocessing(brdf="lambert")
    with pytest.raises(SceneError, match="patch size 48 is larger than the frame"):
        FrameDataset([Sequence(root / "seq_a")], ["target"], patch=48)[0]
    dm = SceneDataModule(root, {"train": ["seq_zzz"]}, ["target"])
    with pytest.raises(SceneError, match="sequence 'seq_zzz' not found"):
        dm.setup("fit")


def test_the_test_split_reads_its_own_keys_and_keeps_every_frame(root):
    """The temporal metrics need motion and G-buffer at test time only; current-frame keys drop no frame."""
    splits = {"train": ["seq_a"], "test": ["seq_a"]}
    dm = SceneDataModule(
        root,
        splits,
        ["lr", "target"],
        test_inputs=["lr", "target", "motion", "gbuffer"],
        test_scales=[2.0],
        patch_size=16,
    )
    dm.setup(None)
    train = next(iter(dm.train_dataloader()))
    test = next(iter(dm.test_dataloader()[0]))
    assert {"motion", "gbuffer"} & set(train) == set() and {"motion", "gbuffer", "lr", "target"} <= set(test)
    assert [frame for _, frame in dm.datasets["test"][0].items] == [1, 2, 3, 4]


def test_frame_ranges_and_split_entries(root):
    dm = SceneDataModule(
        root, {"train": [{"name": "seq_a", "frames": [2, 4]}]}, ["target"], patch_size=None, batch_size=1
    )
    dm.setup("fit")
    assert [frame for _, frame in dm.datasets["train"].items] == [2, 3]


def test_split_sum_preprocessing_reads_roughness_and_nov(root, opened):
    prep = Preprocessing(brdf="split_sum")
    dataset = FrameDataset([Sequence(root / "seq_a")], ["brdf"], preprocessing=prep)
    dataset[0]
    assert any("MV_Roughness_NOV" in n for n in opened)


def test_native_lr_of_the_wrong_width_is_a_clear_error(tmp_path):
    seq_dir = write_sequence(tmp_path / "seq", frames=(1,), size=(8, 8), scales=(2,))
    from wdss.data import write_exr

    write_exr(seq_dir / "4P" / "PretonemapMetallic.0001.exr", {c: torch.zeros(4, 5).numpy() for c in "RGBA"})
    dataset = FrameDataset([Sequence(seq_dir)], ["lr_color", "target"], scale=2.0)
    with pytest.raises(SceneError, match=r"frame 1: the 4P frame is 5x4, but 8x8 at scale 2 needs 4x4"):
        dataset[0]


def test_worker_processes_read_zipped_sequences(root, tmp_path):
    import shutil

    shutil.make_archive(str(tmp_path / "seq_a"), "zip", root / "seq_a")
    dm = SceneDataModule(
        tmp_path, {"train": ["seq_a"]}, ["lr", "history", "target"], patch_size=12, batch_size=2, num_workers=2
    )
    dm.setup("fit")
    batches = list(dm.train_dataloader())
    assert len(batches) == 1 and batches[0]["history"].shape == (2, 3, 12, 12)


def _first_batch_shape(root: Path) -> tuple[int, ...]:
    dm = SceneDataModule(root, {"train": ["seq_a"]}, ["target"], patch_size=12, batch_size=2, num_workers=1)
    dm.setup("fit")
    return tuple(next(iter(dm.train_dataloader()))["target"].shape)


@pytest.mark.slow
def test_loader_workers_start_inside_a_parallel_launcher_job(root):
    # hydra/launcher=parallel runs each job in a joblib (loky) worker, whose default start method is "loky".
    from joblib import Parallel, delayed

    shapes = Parallel(n_jobs=2, backend="loky")([delayed(_first_batch_shape)(root)] * 2)
    assert shapes == [(2, 3, 12, 12)] * 2


def test_prepare_data_makes_a_missing_root_once(tmp_path):
    calls = []

    def prepare(root):
        calls.append(root)
        write_sequence(root / "seq_a", frames=(1, 2), size=(8, 8), scales=())

    dm = SceneDataModule(tmp_path / "made", {"train": ["seq_a"]}, ["target"], patch_size=None, prepare=prepare)
    dm.prepare_data()
    dm.prepare_data()  # the root exists now: nothing to do
    assert calls == [tmp_path / "made"]
    dm.setup("fit")
    assert len(dm.datasets["train"]) == 2


EMITS = {"passes": ["emission"]}


@pytest.mark.parametrize(
    ("settings", "stale"),
    [
        ({"denoise": True, "resolution": [384, 216], **EMITS}, "prefilter"),  # denoised with OIDN's prefilter
        ({"denoise": True, "denoise_prefilter": "none", "resolution": [384, 216], **EMITS}, None),
        ({"denoise": True, "resolution": [96, 48], **EMITS}, None),  # under 200 pixels: never prefiltered
        ({"denoise": False, "resolution": [384, 216], **EMITS}, None),
        ({"denoise": False, "resolution": [384, 216]}, "no emission pass"),  # rendered before the emission pass
        ({"denoise": False, "resolution": [384, 216], **EMITS, "unsampled": True}, "no LR sampling convention"),
    ],
)
def test_a_dataset_rendered_by_an_earlier_wdss_is_refused_by_name(tmp_path, settings, stale):
    from wdss.render import RenderOnFirstUse

    calls = []

    class Recording(RenderOnFirstUse):  # the renderer the config injects, its render recorded instead of run
        def __call__(self, root):
            calls.append(root)

    write_sequence(tmp_path / "made" / "seq_a", frames=(1, 2), size=(8, 8), scales=())
    sampling = {} if settings.pop("unsampled", False) else {"sampling": {"gbuffer": "point-sampled"}}
    (tmp_path / "made" / "seq_a" / "sequence.json").write_text(json.dumps({"settings": settings, **sampling}))
    prepare = Recording("mini", home=tmp_path / "made")
    dm = SceneDataModule(tmp_path / "made", {"train": ["seq_a"]}, ["target"], patch_size=None, prepare=prepare)
    if stale:
        with pytest.raises(SceneError, match=rf"made/seq_a was rendered by an earlier wdss: .*{stale}.* Remove "):
            dm.prepare_data()
    else:
        dm.prepare_data()
    assert calls == []  # never rendered over


def test_the_default_data_config_instantiates():
    from hydra import compose, initialize_config_dir
    from hydra.utils import instantiate

    from wdss.paths import CONF_DIR
    from wdss.render import RenderOnFirstUse

    with initialize_config_dir(config_dir=str(CONF_DIR), version_base="1.3"):
        cfg = compose("train", overrides=["data=mini", "paths.root_dir=/project"])
    dm = instantiate(cfg.data, inputs=["lr", "target"])
    assert isinstance(dm, SceneDataModule) and dm.inputs == ("lr", "target") and dm.scale == (2.0, 4.0)
    assert str(dm.root) == "/project/data/mini"
    assert isinstance(dm.prepare, RenderOnFirstUse) and dm.prepare.name == "mini"
    assert dm.prepare.home == Path("/project/data/mini") and not dm.prepare.anywhere


@pytest.mark.parametrize("preset", ["mini", "tiny", "bench", "bench_jittered"])
def test_a_typo_in_data_root_renders_nothing_and_names_the_root(tmp_path, monkeypatch, preset):
    from hydra import compose, initialize_config_dir
    from hydra.utils import instantiate

    from wdss.paths import CONF_DIR
    from wdss.render import sequence

    rendered = []
    monkeypatch.setattr(sequence, "render_preset", lambda root, name: rendered.append((root, name)))
    with initialize_config_dir(config_dir=str(CONF_DIR), version_base="1.3"):
        home = compose("train", overrides=[f"data={preset}", f"paths.root_dir={tmp_path}"])
        typo = compose("train", overrides=[f"data={preset}", f"paths.root_dir={tmp_path}", "data.root=data/mnii"])
        anywhere = compose(
            "train",
            overrides=[f"data={preset}", f"paths.root_dir={tmp_path}", "data.root=data/mnii"]
            + ["data.prepare.anywhere=true"],
        )
    dm = instantiate(typo.data, inputs=["lr", "target"])
    with pytest.raises(SceneError, match=rf"^data root data/mnii does not exist \(the '{preset}' dataset renders on "):
        dm.check()
    with pytest.raises(SceneError, match="data.prepare.anywhere=true"):
        dm.prepare_data()
    assert rendered == [] and not (tmp_path / "data").exists()
    instantiate(anywhere.data, inputs=["lr", "target"]).check()  # asked for: rendered there
    dm = instantiate(home.data, inputs=["lr", "target"])
    dm.check()
    dm.prepare_data()  # its own folder renders on first use
    assert rendered == [(tmp_path / "data" / preset, preset)]


def test_a_missing_root_with_nothing_to_make_it_is_refused_by_name(tmp_path):
    dm = SceneDataModule(tmp_path / "nowhere", {"train": ["seq_a"]}, ["target"], patch_size=None)
    with pytest.raises(SceneError, match=r"^data root .*nowhere does not exist$"):
        dm.check()


def test_sequences_share_one_patch_and_scale_across_steps(root):
    keys = ["lr", "motion", "temporal_mask", "target", "brdf"]
    dm = SceneDataModule(
        root, {"train": ["seq_a"], "val": ["seq_a"]}, keys, scale=[2, 4], patch_size=12, batch_size=1, sequence_length=3
    )
    dm.setup("fit")
    assert [frame for _, frame in dm.datasets["train"].items] == [4]  # frames 2-4, and 1 as history
    assert [frame for _, frame in dm.datasets["val"].items] == [2, 3, 4]  # evaluation stays frame by frame
    torch.manual_seed(0)
    batch = next(iter(dm.train_dataloader()))
    steps = batch["steps"]
    assert [int(s["frame"][0]) for s in steps] == [2, 3, 4]
    assert len({float(s["scale"][0]) for s in steps}) == 1
    # The same window in consecutive frames: the content moved by the motion vectors (1, -1) in between.
    from wdss.data import warp_backward

    for previous, current in zip(steps, steps[1:], strict=False):
        warped = warp_backward(previous["target"], current["motion"])
        inside = warped.abs().sum(1) > 1e-3
        torch.testing.assert_close(warped[:, :, inside[0]], current["target"][:, :, inside[0]], rtol=1e-5, atol=1e-5)


def test_rendering_methods_read_only_their_history(root, opened):
    """NSRR reads the previous frame at low resolution only; FuseSR two previous frames at high resolution."""
    nsrr = FrameDataset(
        [Sequence(root / "seq_a")],
        ["lr_color", "lr_gbuffer", "prev_lr_color", "prev_lr_gbuffer", "motion", "brdf", "target"],
        scale=3.0,
    )
    sample = nsrr[0]  # frame 2: its previous frame from the native 8P folder
    previous = [n for n in opened if ".0001." in n]
    # ... and of the HR frame, only the depth plane: the range that normalises the LR depth
    assert previous and {n for n in previous if not n.startswith("8P/")} == {"24P/BaseColorDepth.0001.exr"}
    assert sample["prev"] == {}
    assert sample["prev_lr"]["color"].shape == (3, 8, 12)
    opened.clear()
    fusesr = FrameDataset(
        [Sequence(root / "seq_a")], ["lr", "lr_gbuffer", "gbuffer", "history", "history2", "brdf", "target"], scale=3.0
    )
    assert [frame for _, frame in fusesr.items] == [3, 4]  # two previous frames needed
    fusesr[0]
    assert {int(n.split(".")[-2]) for n in opened} == {1, 2, 3}
    batch = Collate(fusesr.keys, fusesr.prep, 3.0)([fusesr[0], fusesr[1]])
    assert batch["history2"].shape == (2, 3, 24, 36) and batch["lr_gbuffer"].shape == (2, 4, 8, 12)
    # The synthetic content moves by the motion vectors: frame t-2 warped twice is frame t where it was seen.
    current = batch["target"] / batch["brdf"]
    inside = batch["history2"].abs().sum(1) > 1e-3
    torch.testing.assert_close(batch["history2"][:, :, inside[0]][0], current[0][:, inside[0]], rtol=1e-5, atol=1e-5)


def test_patches_round_down_to_a_multiple_of_a_native_scale(root):
    dataset = FrameDataset([Sequence(root / "seq_a")], ["lr_color", "target"], scale=3.0, patch=14)
    sample = dataset[0]
    assert sample["hr"]["color"].shape[-2:] == (12, 12) and sample["lr"]["color"].shape[-2:] == (4, 4)


def test_patches_per_frame_draws_every_frame_that_often_with_distinct_randomness():
    from wdss.data.dataset import EpochSampler

    sampler = EpochSampler(5, seed=3, repeats=3)
    sampler.set_epoch(2)
    draws = list(sampler)
    assert len(draws) == len(sampler) == 15
    assert sorted(i for i, _ in draws) == sorted(list(range(5)) * 3)
    assert len(set(draws)) == 15  # the same frame is drawn with three different (index, draw) seeds
    assert {d for _, d in draws} == {6, 7, 8}  # draws of epoch 2 never reuse those of another epoch
    again = EpochSampler(5, seed=3, repeats=3)
    again.set_epoch(2)
    assert list(again) == draws  # a function of (seed, epoch) alone: resume replays it
    with pytest.raises(ValueError, match="patches_per_frame"):
        EpochSampler(5, repeats=0)


def test_two_ddp_ranks_share_every_epoch_disjointly_as_a_function_of_seed_and_epoch_alone():
    from wdss.data.dataset import EpochSampler

    def shares(epoch: int, shuffle: bool = True, size: int = 7, repeats: int = 3) -> list[list[tuple[int, int]]]:
        out = []
        for rank in (0, 1):
            sampler = EpochSampler(size, seed=3, shuffle=shuffle, repeats=repeats, rank=rank, world_size=2)
            sampler.set_epoch(epoch)
            out.append(list(sampler))
            assert len(out[-1]) == len(sampler)
        return out

    one = EpochSampler(7, seed=3, repeats=3)
    one.set_epoch(4)
    first, second = shares(4)
    assert len(first) == len(second) == 10  # 21 draws: one left out, so both ranks step the same batches
    assert not set(first) & set(second)
    assert set(first) | set(second) < set(one)  # one process's epoch, less the remainder
    assert [d for pair in zip(first, second, strict=True) for d in pair] == list(one)[:20]  # alternate draws
    assert shares(4) == [first, second]  # a function of (seed, epoch): a resumed DDP run replays its shares
    assert shares(5) != [first, second]
    # Evaluation: contiguous blocks in order, together every frame once (a mean over ranks is one process's).
    assert shares(0, shuffle=False, size=5, repeats=1) == [[(0, 0), (1, 0)], [(2, 0), (3, 0), (4, 0)]]
    with pytest.raises(ValueError, match="1 samples cannot be shared among 2 processes"):
        EpochSampler(1, world_size=2, rank=0)


# ---------------------------------------------------------------------------------------------- emission


def _irradiance(frame: int, height: int, width: int) -> torch.Tensor:
    """The synthetic scene's analytic irradiance (wdss.data.synthetic), motion (1, -1): the oracle."""
    v, u = torch.meshgrid(
        torch.arange(height, dtype=torch.float64), torch.arange(width, dtype=torch.float64), indexing="ij"
    )
    tu, tv = u - frame, v - frame
    return torch.stack([0.2 + 1.5 * (0.5 + 0.5 * torch.sin(0.11 * tu + 0.07 * tv + c)) for c in range(3)])[None]


@pytest.mark.parametrize("layout", ["unreal", "dfasr"])
def test_emission_is_taken_out_before_demodulation_and_comes_back_at_high_resolution(tmp_path, layout):
    from wdss.data.preprocess import prediction_color, target_irradiance

    write_sequence(tmp_path / "glow", layout=layout, frames=(1, 2), size=HR, scales=(2,), emission=True)
    keys = ["lr", "brdf", "target", "emission", "history"]
    # The hard switch: demodulation is exact wherever F is not replaced by 1 (the knee blends dark pixels).
    prep = Preprocessing(brdf_knee=0.0)
    dataset = FrameDataset([Sequence(tmp_path / "glow")], keys, scale=2.0, first_frame="zeros", preprocessing=prep)
    batch = Collate(dataset.keys, dataset.prep, 2.0)([dataset[1]])  # frame 2
    emission = batch["emission"]
    glow = (emission[0, 0] == 2.0) & (batch["brdf"][0, 0] != 1.0)  # the textured emitter (F is not replaced by 1)
    assert glow.sum() > 10 and emission.abs().sum() > 0
    truth = _irradiance(2, *HR).float()
    # At HR: what the data says the target's irradiance is, is the analytic one, on the emitter too.
    surface = batch["brdf"][0, 0] != 1.0
    torch.testing.assert_close(target_irradiance(batch)[..., surface], truth[..., surface], rtol=1e-4, atol=1e-5)
    # At LR (the native 12P folder, point samples of HR): the irradiance of the LR pixels, emitters included.
    lr_truth = point_sample(truth, batch["lr"].shape[-2:])
    lr_surface = point_sample(surface[None, None].float(), batch["lr"].shape[-2:])[0, 0] > 0
    torch.testing.assert_close(batch["lr"][..., lr_surface], lr_truth[..., lr_surface], rtol=1e-4, atol=1e-5)
    # The history of frame 1, warped, is its irradiance without emission too (no 2 / F on the emitter).
    assert float(batch["history"][..., glow].max()) < 2.0
    # Remodulating the true irradiance gives the target back, emission included.
    torch.testing.assert_close(prediction_color(target_irradiance(batch), batch), batch["target"], rtol=1e-5, atol=1e-5)
    # Without separation the emitter's irradiance holds 2 / F: far from the truth.
    whole = FrameDataset([Sequence(tmp_path / "glow")], keys, scale=2.0, preprocessing=Preprocessing(emission=False))
    plain = Collate(whole.keys, whole.prep, 2.0)([whole[0]])
    assert "emission" not in plain and float((plain["lr"] - batch["lr"]).abs().max()) > 1.0


def test_a_sequence_without_emission_emits_nothing_unless_emission_is_required(root):
    keys = ["lr", "brdf", "target", "emission"]
    dataset = FrameDataset([Sequence(root / "seq_a")], keys, scale=2.0)  # written without the buffer
    assert dataset.no_emission == {"seq_a"}
    batch = Collate(dataset.keys, dataset.prep, 2.0)([dataset[0]])
    assert batch["emission"].shape == batch["target"].shape and batch["emission"].abs().sum() == 0
    whole = FrameDataset([Sequence(root / "seq_a")], keys, scale=2.0, preprocessing=Preprocessing(emission=False))
    torch.testing.assert_close(Collate(whole.keys, whole.prep, 2.0)([whole[0]])["lr"], batch["lr"])
    with pytest.raises(SceneError, match=r"seq_a have no emission buffer .*emission=true"):
        FrameDataset([Sequence(root / "seq_a")], keys, scale=2.0, preprocessing=Preprocessing(emission=True))
    with pytest.raises(ValueError, match="emission must be true, false or auto"):
        Preprocessing(emission="yes")


def test_the_test_splits_noise_ceilings_are_read_from_the_records_and_logged_only_when_they_apply(tmp_path):
    from types import SimpleNamespace

    from wdss.ops.tonemap import ToneMap
    from wdss.train import log_noise_ceilings

    for name, noise in (
        ("a", {"ceiling_psnr_db": 40.0, "frames": [1, 2, 3]}),
        ("b", {"ceiling_psnr_db": 44.0, "frames": [1]}),
    ):
        (tmp_path / name).mkdir()
        (tmp_path / name / "sequence.json").write_text(json.dumps({"name": name, "noise": noise}))
    (tmp_path / "c").mkdir()
    (tmp_path / "c" / "sequence.json").write_text(json.dumps({"name": "c"}))
    dm = SceneDataModule(tmp_path, {"test": ["a", "b"], "val": ["c"]}, ["lr", "target"])
    assert dm.noise_ceilings("test") == {"a": (40.0, 3), "b": (44.0, 1)} and dm.noise_ceilings("val") == {}
    module = SimpleNamespace(tone=ToneMap("hable"))
    # weighted by the frames each ceiling was measured on: (3 x 40 + 44) / 4
    logged = []
    logger = SimpleNamespace(log_metrics=logged.append)
    assert (
        log_noise_ceilings(module, dm, logger)
        == logged[0]
        == {
            "test/noise_ceiling_a": 40.0,
            "test/noise_ceiling_b": 44.0,
            "test/noise_ceiling": 41.0,
        }
    )
    partial = SceneDataModule(tmp_path, {"test": ["a", "c"]}, ["lr", "target"])
    assert log_noise_ceilings(module, partial, None) == {"test/noise_ceiling_a": 40.0}  # no mean over part of the split
    assert log_noise_ceilings(SimpleNamespace(tone=ToneMap("hable", "auto")), dm, None) == {}  # measured at exposure 10


def test_prepare_data_resumes_a_render_stopped_part_way_and_never_renders_into_other_frames(tmp_path):
    calls = []
    root = tmp_path / "made"
    write_sequence(root / "seq_a", frames=(0, 1, 2), size=(8, 8), scales=())
    meta = {"settings": {"frames": 2, "passes": ["emission"]}, "sampling": {}, "render_seconds": {"0": 1, "1": 1}}
    (root / "seq_a" / "sequence.json").write_text(json.dumps(meta))
    dm = SceneDataModule(
        root, {"train": ["seq_a"], "val": ["seq_b"]}, ["target"], patch_size=None, prepare=calls.append
    )
    dm.prepare_data()  # seq_a lacks frame 2's render, seq_b was never reached
    assert calls == [root]
    meta["render_seconds"]["2"] = 1
    (root / "seq_a" / "sequence.json").write_text(json.dumps(meta))
    SceneDataModule(root, {"train": ["seq_a"]}, ["target"], patch_size=None, prepare=calls.append).prepare_data()
    assert calls == [root]  # finished: nothing to do
    write_sequence(tmp_path / "mine" / "seq_a", frames=(1, 2), size=(8, 8), scales=())  # no wdss render record
    SceneDataModule(tmp_path / "mine", {"train": ["seq_a", "typo"]}, ["target"], prepare=calls.append).prepare_data()
    assert calls == [root]


def test_a_split_naming_a_missing_sequence_is_refused_with_the_syntax(root):
    dm = SceneDataModule(root, {"train": ["seq_a"], "test": ["seq_b", "nope"]}, ["target"], patch_size=None)
    dm.check(["train"])  # only the splits asked about
    with pytest.raises(SceneError, match=r"^data.splits.test: 'nope' not under .* \(it holds: .*seq_a.*\); name "):
        dm.check()
    with pytest.raises(SceneError, match=r"data.test_root .*elsewhere is not a folder"):
        SceneDataModule(root, {"test": ["seq_b"]}, ["target"], patch_size=None, test_root=root / "elsewhere").check(
            ["test"]
        )


def test_a_folder_of_other_wdss_renders_is_never_resumed_as_the_preset(tmp_path, monkeypatch):
    """data.root=<held-out scenes rendered by wdss> with the preset's train split: nothing is rendered into it."""
    from wdss.render import RenderOnFirstUse, sequence

    rendered = []
    monkeypatch.setattr(sequence, "render_preset", lambda root, name: rendered.append(root))
    other = tmp_path / "heldout"
    write_sequence(other / "heldout_400", frames=(0, 1, 2), size=(8, 8), scales=())
    meta = {
        "settings": {"frames": 2, "passes": ["emission"]},
        "sampling": {},
        "render_seconds": {"0": 1, "1": 1, "2": 1},
    }
    (other / "heldout_400" / "sequence.json").write_text(json.dumps(meta))
    prepare = RenderOnFirstUse("mini", home=tmp_path / "mini")
    dm = SceneDataModule(other, {"train": ["train_000"], "test": ["heldout_400"]}, ["target"], prepare=prepare)
    dm.prepare_data()
    dm.check(["test"])
    with pytest.raises(SceneError, match="data.splits.train: 'train_000' not under"):
        dm.check()
    assert rendered == [] and sorted(p.name for p in other.iterdir()) == ["heldout_400"]
    # Frames another tool wrote, with a sequence.json of its own: read as they are, never judged as a stale preset.
    foreign = tmp_path / "unreal"
    write_sequence(foreign / "shot_a", frames=(0, 1), size=(8, 8), scales=())
    (foreign / "shot_a" / "sequence.json").write_text(json.dumps({"fps": 24}))
    SceneDataModule(foreign, {"train": ["shot_a"]}, ["target"], prepare=prepare).prepare_data()
    assert rendered == []
    # Its own folder, stopped part-way, resumes.
    own = tmp_path / "mini"
    write_sequence(own / "train_000", frames=(0, 1), size=(8, 8), scales=())
    stopped = {**meta, "seed": 100, "settings": {**meta["settings"], "frames": 3}, "render_seconds": {"0": 1}}
    (own / "train_000" / "sequence.json").write_text(json.dumps(stopped))
    SceneDataModule(own, {"train": ["train_000"]}, ["target"], prepare=prepare).prepare_data()
    assert rendered == [own]
    # Rendered from an earlier version of the preset (train_000 had 24 frames): refused, not resumed into a mix.
    (own / "train_000" / "sequence.json").write_text(
        json.dumps({**stopped, "settings": {**meta["settings"], "frames": 24}})
    )
    with pytest.raises(
        SceneError,
        match=r"train_000 was rendered from an earlier version of the 'mini' preset "
        r"\(seed 100, 24 frames; now seed 100, 3 frames\)\. Remove .*mini and it is rendered again",
    ):
        SceneDataModule(own, {"train": ["train_000"]}, ["target"], prepare=prepare).prepare_data()
    assert rendered == [own]
