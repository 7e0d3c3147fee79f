"""Checkpoints are data: :func:`read_checkpoint` opens one weights-only and checks it before anything uses it.

A file that is not a checkpoint gets one sentence naming it, never torch's hint to retry with
``weights_only=False`` (which would run whatever the file holds); a checkpoint whose stored model config holds an
interpolation (``${oc.create:{_target_: ...}}`` builds whatever it names once resolved), or names a callable
outside its slot's allowlist (:mod:`wdss.config.targets`), is refused before any of it is built. The same holds for what
is read from the run folder beside it (``.hydra/config.yaml``'s ``data.preprocessing``).
"""

from __future__ import annotations

import zipfile
from pathlib import Path
from typing import Any

import torch
from omegaconf import OmegaConf

from wdss.config.targets import TargetRefused, check_targets, moved, refuse_interpolation
from wdss.errors import UserError

__all__ = ["CheckpointError", "load_weights", "read_checkpoint", "training_preprocessing"]


class CheckpointError(UserError):
    """A file that is not a usable wdss checkpoint."""


def _nearby(path: Path) -> str:
    """The checkpoints beside a missing one (its folder, or the ``checkpoints/`` of a run folder): what was meant."""
    for folder in (path.parent, path, path / "checkpoints", path.parent / "checkpoints"):
        if folder.is_dir():
            found = sorted(p.name for p in folder.glob("*.ckpt"))
            if found:
                shown = ", ".join(found[:8]) + (f", ... ({len(found)} in all)" if len(found) > 8 else "")
                return f"; {folder} holds {shown}"
    return ""


def _load_archive(path: Path, named: str, kind: str, hint: str, **load: Any) -> Any:
    """What the torch archive at ``path`` holds, loaded weights-only; a file that is not one, or holds more than
    tensors and plain values, is one sentence naming it (``named``) as a ``kind``, never torch's advice to retry
    with ``weights_only=False``."""
    if not zipfile.is_zipfile(path):  # torch.save (since 1.6) and Lightning write zip archives
        raise CheckpointError(f"{named} is not a {kind}: not a torch archive ({hint})")
    try:
        return torch.load(path, map_location="cpu", weights_only=True, **load)
    except Exception as err:
        raise CheckpointError(
            f"{named} cannot be read as a {kind} ({type(err).__name__}): it is damaged or holds objects other than "
            "tensors and plain values, which wdss never loads"
        ) from None


def load_weights(path: str | Path, what: str) -> dict[str, Any]:
    """A state dict file named by the config key ``what`` (published or local weights: LPIPS, Real-ESRGAN), opened
    weights-only; anything else gets one sentence naming the key and the file, never torch's advice to retry with
    ``weights_only=False``."""
    path = Path(path)
    if not path.is_file():
        raise CheckpointError(f"{what}={path} is not a file")
    state = _load_archive(path, f"{what}={path}", "torch weight file", "torch.save writes one")
    if not isinstance(state, dict):
        raise CheckpointError(f"{what}={path} holds a {type(state).__name__}, not a state dict")
    return state


def read_checkpoint(path: str | Path) -> dict[str, Any]:
    """The checkpoint at ``path`` (tensors memory-mapped), once it is known to be a wdss.train checkpoint whose
    hyper-parameters build only allowlisted callables."""
    path = Path(path)
    if not path.is_file():
        raise CheckpointError(f"checkpoint {path} is not a file{_nearby(path)}")
    checkpoint = _load_archive(path, str(path), "checkpoint", "a .ckpt that wdss.train writes", mmap=True)
    hparams = checkpoint.get("hyper_parameters") if isinstance(checkpoint, dict) else None
    if not isinstance(hparams, dict) or "state_dict" not in checkpoint or "net" not in hparams:
        raise CheckpointError(f"{path} is not a checkpoint written by wdss.train (no state_dict and model config)")
    # Lightning passes these to the model too (arguments of old checkpoints, or all of them under one name).
    for key in ("hparams", "module_arguments", "hparams_name"):
        if checkpoint.get(key) is not None:
            raise CheckpointError(f"checkpoint {path} holds {key!r}, which wdss.train never writes: refused")
    try:
        refuse_interpolation(hparams, "hyper_parameters")  # nothing in a checkpoint is resolved
        check_targets(moved(hparams), "hyper_parameters")  # a checkpoint of the layout before the move too
    except TargetRefused as err:
        raise CheckpointError(f"checkpoint {path}: {err}") from err
    return checkpoint


def training_preprocessing(path: str | Path) -> dict[str, Any]:
    """``data.preprocessing`` of the run that wrote the checkpoint at ``path`` (``<run>/checkpoints/x.ckpt``
    beside ``<run>/.hydra/config.yaml``), or ``{}`` when it is not in a run folder: a model sees its inputs
    demodulated, clamped and normalised as in training, whatever the defaults are now."""
    config = Path(path).resolve().parent.parent / ".hydra" / "config.yaml"
    if not config.is_file():
        return {}
    data = OmegaConf.to_container(OmegaConf.load(config), resolve=False).get("data")  # nothing resolved yet
    prep = data.get("preprocessing") if isinstance(data, dict) else data
    if prep is None:
        return {}
    try:  # wdss writes plain values here: an interpolation would resolve (and build) whatever it says
        refuse_interpolation(prep, "data.preprocessing" if isinstance(data, dict) else "data")
    except TargetRefused as err:
        raise CheckpointError(f"{config} (the run of checkpoint {path}): {err}") from err
    if not isinstance(prep, dict) or not all(v is None or isinstance(v, str | int | float) for v in prep.values()):
        raise CheckpointError(f"{config}: data.preprocessing is not a mapping of plain values: refused")
    # Runs from before the knee existed demodulated with the hard switch: their models expect exactly that.
    prep.setdefault("brdf_knee", 0.0)
    return prep
