"""The LightningDataModule: scenes on disk -> batches of named float32 tensors.

Batches are dicts of named tensors: :mod:`wdss.data.batch` defines every key (shape, dtype, space, meaning); only
those the model asks for are built, and only the files they need are opened. The first batch of each loader is held
to that definition (:func:`wdss.data.batch.check_batch`); later ones are not checked.

With ``sequence_length = T > 1`` a training batch is ``{"steps": [batch_1, ..., batch_T]}``: T consecutive
frames, the same patch and mirroring in each, one scale; validation and test batches stay single frames, in
order.

Sources (``format``): ``exr`` reads the scenes' EXR files; ``packed`` a packed store (``packed_root``, default
``<root>.packed``, written by ``python -m wdss.data.pack``), which reads a patch's tiles instead of whole frames;
``auto`` the packed copy of every sequence that has an up-to-date one holding the buffers needed, the EXR files of
the others. Where the per-pixel preprocessing runs (``preprocess_on``): ``loader`` in the loader's workers,
``device`` on the model's device after the transfer (:meth:`SceneDataModule.on_after_batch_transfer`); ``auto``
picks ``device`` when the trainer runs on an accelerator, ``loader`` on a CPU. Both give the same batch. Decoded
EXR frames are kept in a per-process LRU of ``cache_mb`` MB (:class:`wdss.data.cache.FrameCache`; 0: none), so a
frame is decoded once per loader worker rather than once per patch.
"""

from __future__ import annotations

import json
import logging
import multiprocessing
from collections.abc import Callable, Iterable, Mapping
from pathlib import Path
from typing import Any

import lightning as L
import torch
from torch.utils.data import DataLoader

from wdss.data.batch import check_batch
from wdss.data.buffers import OPTIONAL_BUFFERS
from wdss.data.cache import FrameCache
from wdss.data.dataset import Collate, EpochSampler, FrameDataset, Preprocessing, ScaleSpec, parse_scale, requirements
from wdss.data.layouts import SceneError, discover_sequences
from wdss.data.packed import PackedSequence, discover_packed, is_packed
from wdss.data.prepare import Preparer, as_preparer
from wdss.data.preprocess import RawBatch
from wdss.data.source import FrameSource
from wdss.errors import ConfigError

__all__ = ["SceneDataModule"]

log = logging.getLogger(__name__)

SPLITS = ("train", "val", "test")
FORMATS = ("auto", "exr", "packed")
PLACEMENTS = ("auto", "loader", "device")


def _parse_split(entries: Iterable[Any]) -> tuple[list[str], dict[str, tuple[int, int]]]:
    """``["seq", {"name": "seq2", "frames": [start, stop]}]`` -> names and frame ranges (stop exclusive)."""
    names, ranges = [], {}
    for entry in entries:
        if isinstance(entry, str):
            names.append(entry)
        elif isinstance(entry, Mapping) and "name" in entry:
            names.append(str(entry["name"]))
            if entry.get("frames") is not None:
                start, stop = entry["frames"]
                ranges[str(entry["name"])] = (int(start), int(stop))
        else:
            raise ConfigError(f"data.splits entries are names or {{name, frames: [start, stop]}}, got {entry!r}")
    return names, ranges


def worker_context() -> str | None:
    """The start method for loader workers: the process's own, unless a launcher replaced it.

    A job that joblib's loky backend runs (``hydra/launcher=parallel``) has ``loky`` as its default start method, and
    loky's ``Popen`` cannot start a plain ``multiprocessing.Process``: the DataLoader's workers would fail to start.
    There the platform's default (fork on Linux, spawn on macOS) is used, as in a job that runs in the main process.
    """
    method = multiprocessing.get_start_method(allow_none=True)
    if method is None or method in multiprocessing.get_all_start_methods():
        return None
    return multiprocessing.get_all_start_methods()[0]


class SceneDataModule(L.LightningDataModule):
    """Train/val/test splits of rendered sequences, by sequence name (see the module docstring for keys).

    ``inputs`` are the batch keys the model consumes (the model config declares them); ``test_inputs`` those of
    the test split, when it needs more (the temporal metrics: motion and G-buffer). ``scale`` is a fixed
    training scale, a ``[low, high]`` range or a ``{choices: [...]}`` set drawn from per batch; validation runs
    full frames at ``val_scale`` and testing at every scale of ``test_scales`` (one dataloader each).
    ``lr_source`` is the LR sampling convention read: ``auto`` (a native ``<H>P`` folder where one matches the
    scale, else the HR frame point-sampled), ``native`` (required) or ``point`` (always point-sampled);
    ``test_lr_source`` the test split's (``None``: the same), so that a model trained on one convention is tested
    on another; ``test_root`` a folder the test split's sequences are read from instead of ``root`` (the same scenes
    rendered under another convention: jittered LR, filtered G-buffers), EXR files only.
    ``patches_per_frame`` random patches of every training frame make one epoch. ``prepare`` (a
    :class:`wdss.data.prepare.Preparer`, or a plain callable) is called with ``root`` by :meth:`prepare_data`
    when ``root`` does not exist yet (e.g. to render a dataset), or when it holds a render of its own
    (``sequence.json`` files) that was stopped before every sequence of the splits was finished; what it made
    earlier and now judges stale or outdated is refused by name.
    """

    def __init__(
        self,
        root: str | Path,
        splits: Mapping[str, Iterable[Any]],
        inputs: Iterable[str],
        *,
        layout: str = "auto",
        scale: float | Iterable[float] | Mapping[str, Any] = 2.0,
        val_scale: float | None = None,
        test_scales: Iterable[float] = (2.0, 3.0, 4.0),
        patch_size: int | None = 96,
        patches_per_frame: int = 1,
        batch_size: int = 8,
        eval_batch_size: int = 1,
        num_workers: int = 0,
        pin_memory: bool = True,
        preprocessing: Preprocessing | Mapping[str, Any] | None = None,
        flips: bool = False,
        first_frame: str = "skip",
        sequence_length: int = 1,
        seed: int = 0,
        prepare: Preparer | Callable[[Path], object] | None = None,
        test_inputs: Iterable[str] | None = None,
        format: str = "auto",  # noqa: A002 (the config key's name)
        packed_root: str | Path | None = None,
        preprocess_on: str = "auto",
        cache_mb: int = 1024,
        lr_source: str = "auto",
        test_lr_source: str | None = None,
        test_root: str | Path | None = None,
    ) -> None:
        super().__init__()
        if format not in FORMATS:
            raise ConfigError(f"data.format must be one of {', '.join(FORMATS)}, got {format!r}")
        if preprocess_on not in PLACEMENTS:
            raise ConfigError(f"data.preprocess_on must be one of {', '.join(PLACEMENTS)}, got {preprocess_on!r}")
        self.root = Path(root)
        self.format = format
        self.packed_root = Path(packed_root) if packed_root else self.root.with_name(f"{self.root.name}.packed")
        self.preprocess_on = preprocess_on
        unknown = set(splits) - set(SPLITS)
        if unknown:
            raise ConfigError(f"data.splits has unknown split(s) {sorted(unknown)}: expected train, val, test")
        self.splits = {name: _parse_split(entries) for name, entries in splits.items()}
        self.inputs = tuple(inputs)
        self.test_inputs = self.inputs if test_inputs is None else tuple(test_inputs)
        self.layout = layout
        self.scale = parse_scale(scale)
        self.lr_source = lr_source
        self.test_lr_source = lr_source if test_lr_source is None else test_lr_source
        self.test_root = Path(test_root) if test_root is not None else None
        self.val_scale = float(val_scale) if val_scale is not None else self._middle(self.scale)
        self.test_scales = tuple(float(s) for s in test_scales)
        self.patch_size = patch_size
        self.patches_per_frame = int(patches_per_frame)
        self.batch_size = batch_size
        self.eval_batch_size = eval_batch_size
        self.num_workers = num_workers
        self.pin_memory = pin_memory and torch.cuda.is_available()
        if isinstance(preprocessing, Preprocessing):
            self.prep = preprocessing
        else:
            self.prep = Preprocessing(**dict(preprocessing or {}))
        self.flips = flips
        self.first_frame = first_frame
        self.sequence_length = sequence_length
        self.seed = seed
        self.prepare = as_preparer(prepare)
        if isinstance(cache_mb, bool) or not isinstance(cache_mb, int) or cache_mb < 0:
            raise ConfigError(f"data.cache_mb must be an integer >= 0 (0: no cache), got {cache_mb!r}")
        # EXR sequences share one budget per process (each loader worker holds its own cache).
        self.cache = FrameCache(cache_mb * 2**20) if cache_mb else None
        self.datasets: dict[str, Any] = {}
        self._checked: set[tuple[Any, int]] = set()  # (trainer stage, dataloader) whose first batch was checked

    @staticmethod
    def _middle(scale: ScaleSpec) -> float:
        if isinstance(scale, dict):  # the middle choice: a scale the data has natively
            choices = sorted(scale["choices"])
            return choices[len(choices) // 2]
        return float(scale) if not isinstance(scale, tuple) else round(sum(scale) / 2, 3)

    def check(self, splits: Iterable[str] = SPLITS) -> None:
        """Refuse, before anything is created, a ``root`` that does not exist and that ``prepare`` will not make
        (none given, or one that refuses this folder: :meth:`wdss.render.RenderOnFirstUse.refusal`), and one of
        ``splits`` that names a sequence the data does not hold (unless a render here will make it)."""
        if self.format != "packed" and not self.root.exists():
            if self.prepare is None:
                raise SceneError(f"data root {self.root} does not exist")
            why = self.prepare.refusal(self.root)
            if why:
                raise SceneError(why)
            return  # rendered on first use
        resumable = (
            self.prepare is not None and self.prepare.resumes(self.root) and any(self.root.glob("*/sequence.json"))
        )
        for split, (names, _) in self.splits.items():
            if split not in splits:
                continue
            root = self.test_root if split == "test" and self.test_root is not None else self.root
            if self.format == "packed" and not (split == "test" and self.test_root is not None):
                root = self.packed_root
            elif root == self.root and resumable:
                continue  # a render of this dataset that stopped part-way resumes (prepare_data)
            if not root.is_dir():
                key = "data.test_root" if root == self.test_root else "data.packed_root"
                raise SceneError(f"{key} {root} is not a folder")
            missing = [n for n in names if not (root / n).exists() and not (root / f"{n}.zip").exists()]
            if missing:
                held = sorted(p.name for p in root.iterdir() if p.is_dir() or p.suffix == ".zip")
                shown = ", ".join(held[:10]) + (f", ... ({len(held)} in all)" if len(held) > 10 else "")
                raise SceneError(
                    f"data.splits.{split}: {', '.join(map(repr, missing))} not under {root} (it holds: "
                    f"{shown or 'no sequence folders'}); name the sequences as data.splits.{split}=[name,...] "
                    f"(or [{{name: a, frames: [start, stop]}}])"
                )

    def prepare_data(self) -> None:
        # A packed store is read without its EXR source: nothing to render for it.
        if self.prepare is None or self.format == "packed":
            return
        if not self.root.exists():
            self.prepare(self.root)
            return
        if not self.prepare.resumes(self.root):
            return  # a folder of other frames (one's own, foreign): never rendered into, nor judged as a preset's
        rendered = {}
        for sidecar in sorted(self.root.glob("*/sequence.json")):  # rendered on first use by an older wdss?
            meta = json.loads(sidecar.read_text())
            why = self.prepare.stale(meta)
            if why:
                raise SceneError(
                    f"{sidecar.parent} was rendered by an earlier wdss: {why}. Remove {self.root} and it is "
                    "rendered again on first use (or: make data)"
                )
            rendered[sidecar.parent.name] = meta
        why = self.prepare.outdated(rendered) if rendered else None
        if why:
            raise SceneError(
                f"{self.root}: {why}. Remove {self.root} and it is rendered again on first use (or: make data)"
            )
        # A render of this dataset that was stopped part-way (wdss renders here, and a sequence of the splits is
        # missing or unfinished) resumes; a folder of other frames is never rendered into.
        names = {name for names, _ in self.splits.values() for name in names}
        unfinished = sorted(
            name
            for name in names
            if name not in rendered
            or len(rendered[name].get("render_seconds") or {})
            < int((rendered[name].get("settings") or {}).get("frames", -1)) + 1
        )
        if rendered and unfinished:
            print(f"wdss: {self.root}: resuming the render of {', '.join(unfinished)}", flush=True)
            self.prepare(self.root)

    def noise_ceilings(self, split: str = "test") -> dict[str, tuple[float, int]]:
        """The targets' noise ceiling each sequence of ``split`` records (``sequence.json`` ``noise``, measured by
        :mod:`wdss.render.noise`: the PSNR a perfect method would score against them, Hable at exposure 10) and
        over how many frames; sequences without one are left out."""
        names, _ = self.splits.get(split, ([], {}))
        root = self.test_root if split == "test" and self.test_root is not None else self.root
        ceilings = {}
        for name in names:
            sidecar = root / name / "sequence.json"
            noise = json.loads(sidecar.read_text()).get("noise") if sidecar.is_file() else None
            if noise and "ceiling_psnr_db" in noise:
                ceilings[name] = (float(noise["ceiling_psnr_db"]), len(noise.get("frames") or [1]))
        return ceilings

    def _sequences(self, split: str, keys: Iterable[str]) -> tuple[list[FrameSource], dict[str, tuple[int, int]]]:
        if split not in self.splits:
            raise SceneError(f"data.splits has no {split!r} split")
        names, ranges = self.splits[split]
        if split == "test" and self.test_root is not None:
            if not self.test_root.is_dir():
                raise SceneError(f"data.test_root {self.test_root} is not a folder (render it first)")
            return self._cached(discover_sequences(self.test_root, names, self.layout)), ranges
        if self.format == "exr":
            return self._cached(discover_sequences(self.root, names, self.layout)), ranges
        if self.format == "packed":
            sequences = discover_packed(self.packed_root, names)
            for seq in sequences:
                changed = seq.stale()
                if changed:
                    raise SceneError(
                        f"packed sequence {seq.name!r} ({seq.folder}) is out of date: {changed}; pack it again "
                        f"(python -m wdss.data.pack root={self.root} out={self.packed_root}) or set data.format=exr"
                    )
            return sequences, ranges
        need = set().union(*requirements(keys, self.prep).values())
        return self._cached([self._auto(name, need) for name in names]), ranges

    def _cached(self, sequences: list[FrameSource]) -> list[FrameSource]:
        """Sequences keep their decoded frames in the data module's cache (EXR ones do; packed ones read patches)."""
        for seq in sequences:
            seq.use_cache(self.cache)
        return sequences

    def _auto(self, name: str, need: set[str]) -> FrameSource:
        """The packed copy of a sequence where it is complete, up to date and holds ``need``; else its EXR files."""
        folder = self.packed_root / name
        if is_packed(folder):
            try:
                packed = PackedSequence(folder)
            except SceneError as err:
                log.warning("data.format=auto: reading %s from EXR files: %s", name, err)
            else:
                missing = sorted(b for b in need if not packed.has(b, packed.hr))
                if set(missing) <= set(OPTIONAL_BUFFERS):  # absent from the EXR files too: the copy holds all there is
                    source = discover_sequences(self.root, [name], self.layout)[0]
                    missing = [b for b in missing if source.has(b, source.hr)]
                changed = packed.stale()
                if not missing and not changed:
                    return packed
                why = changed or f"it lacks {', '.join(missing)}"
                log.warning("data.format=auto: reading %s from EXR files, not its packed copy: %s", name, why)
        return discover_sequences(self.root, [name], self.layout)[0]

    def _dataset(self, split: str, scale: ScaleSpec, patch: int | None) -> FrameDataset:
        keys = self.test_inputs if split == "test" else self.inputs
        sequences, ranges = self._sequences(split, keys)
        return FrameDataset(
            sequences,
            keys,
            scale=scale,
            patch=patch,
            preprocessing=self.prep,
            flips=self.flips and split == "train",
            first_frame=self.first_frame,
            frame_ranges=ranges,
            sequence_length=self.sequence_length if split == "train" else 1,
            seed=self.seed,
            lr_source=self.test_lr_source if split == "test" else self.lr_source,
        )

    def setup(self, stage: str | None = None) -> None:
        if stage in ("fit", None) and "train" not in self.datasets:
            self.datasets["train"] = self._dataset("train", self.scale, self.patch_size)
        if stage in ("fit", "validate", None) and "val" not in self.datasets and "val" in self.splits:
            self.datasets["val"] = self._dataset("val", self.val_scale, None)
        if stage in ("test", None) and "test" not in self.datasets:
            self.datasets["test"] = [self._dataset("test", s, None) for s in self.test_scales]

    def _loader(self, dataset: FrameDataset, batch_size: int, *, train: bool) -> DataLoader:
        # Evaluation keeps frames in order, so a recurrent model can feed back its previous output.
        generator = torch.Generator().manual_seed(self.seed) if train else None
        # Under DDP each rank loads its own share (EpochSampler); the trainer config turns Lightning's sampler off.
        trainer = self.trainer
        rank, world_size = (trainer.global_rank, trainer.world_size) if trainer is not None else (0, 1)
        sampler = EpochSampler(
            len(dataset),
            self.seed,
            shuffle=train,
            repeats=self.patches_per_frame if train else 1,
            rank=rank,
            world_size=world_size,
            scale=dataset.scale,
            batch_size=batch_size,
        )
        return DataLoader(
            dataset,
            batch_size=batch_size,
            sampler=sampler,
            drop_last=train and len(sampler) >= batch_size,
            num_workers=self.num_workers,
            pin_memory=self.pin_memory,
            persistent_workers=self.num_workers > 0,
            multiprocessing_context=worker_context() if self.num_workers > 0 else None,
            collate_fn=Collate(dataset.keys, self.prep, dataset.scale, on_device=self._on_device()),
            generator=generator,
        )

    def _on_device(self) -> bool:
        """Whether the per-pixel preprocessing runs on the trainer's device (in on_after_batch_transfer)."""
        if self.preprocess_on != "auto":
            return self.preprocess_on == "device"
        trainer = self.trainer
        return trainer is not None and trainer.strategy.root_device.type != "cpu"

    def on_after_batch_transfer(self, batch: Any, dataloader_idx: int) -> Any:
        """Build a raw batch on the device it was moved to (``preprocess_on: device``); other batches pass. The
        first batch of each loader is checked against :mod:`wdss.data.batch` (once: no cost per step)."""
        if isinstance(batch, RawBatch):
            batch = batch.build()
        elif isinstance(batch, dict) and "steps" in batch and any(isinstance(s, RawBatch) for s in batch["steps"]):
            batch = {**batch, "steps": [s.build() if isinstance(s, RawBatch) else s for s in batch["steps"]]}
        trainer = self.trainer
        loader = (trainer.state.stage if trainer is not None else None, dataloader_idx)
        if loader not in self._checked and isinstance(batch, dict):
            self._checked.add(loader)
            check_batch(batch, self.test_inputs if trainer is not None and trainer.testing else self.inputs)
        return batch

    def train_dataloader(self) -> DataLoader:
        return self._loader(self.datasets["train"], self.batch_size, train=True)

    def val_dataloader(self) -> DataLoader:
        return self._loader(self.datasets["val"], self.eval_batch_size, train=False)

    def test_dataloader(self) -> list[DataLoader]:
        return [self._loader(ds, self.eval_batch_size, train=False) for ds in self.datasets["test"]]
