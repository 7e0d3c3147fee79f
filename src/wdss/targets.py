"""What configs and checkpoints may build: one explicit allowlist of callables, checked before every instantiate.

Configs and checkpoints are data. A ``_target_`` names a callable by a dotted path, and a name prefix says
nothing about what it names (``torch.save``, ``torch.load`` and ``torch.os.system`` all start with ``torch.``),
so each target is resolved to its object -- walking module namespaces, importing only the modules listed here,
calling nothing -- and compared by identity with the objects of :data:`ALLOWED`. Nested targets (in kwargs,
lists, ``_partial_`` ones) count the same. Hydra 1.3.8's own target policy is a fixed blocklist (``os.system``,
``pickle.load``, ...) with no allowlist hook; it stays active underneath, as a second layer.
"""

from __future__ import annotations

import sys
from collections.abc import Mapping
from functools import cache
from importlib import import_module
from types import ModuleType
from typing import Any

from hydra.utils import instantiate as hydra_instantiate
from omegaconf import OmegaConf

from wdss.errors import UserError

__all__ = ["ALLOWED", "TargetRefused", "check_targets", "instantiate", "resolve"]

# Module -> the names in it that a config or checkpoint may build; a path names them through these modules.
ALLOWED: Mapping[str, tuple[str, ...]] = {
    # wdss's own config groups (conf/**, sweeps/*)
    "wdss.model.module": ("SuperResolutionModule",),
    "wdss.model.network": ("WDSSNet",),
    "wdss.model.baselines": ("Upsample",),
    "wdss.model.joint_bilateral": ("JointBilateralUpsample",),
    "wdss.model.learned_bilateral": ("LearnedBilateralUpsample",),
    "wdss.model.rrdbnet": ("RRDBNet",),
    "wdss.model.nsrr": ("NSRR",),
    "wdss.model.fusesr": ("FuseSR",),
    "wdss.wavelets": ("WaveletTransform",),
    "wdss.data": ("SceneDataModule",),
    "wdss.render": ("RenderOnFirstUse", "render_preset"),
    "wdss.tracking": ("SweepParentRun",),
    "wdss.train": ("ValidateBeforeRun",),
    "wdss.averaging": ("EMAWeightAveraging",),
    # optimisers and learning-rate schedulers (not LambdaLR/MultiplicativeLR: they take a function)
    "torch.optim": ("SGD", "Adam", "AdamW", "Adamax", "Adagrad", "Adadelta", "RMSprop", "NAdam", "RAdam"),
    "torch.optim.lr_scheduler": (
        "StepLR",
        "MultiStepLR",
        "ExponentialLR",
        "CosineAnnealingLR",
        "CosineAnnealingWarmRestarts",
        "LinearLR",
        "ConstantLR",
        "PolynomialLR",
        "OneCycleLR",
        "ReduceLROnPlateau",
    ),
    # the Lightning trainer, callbacks and logger the config groups use
    "lightning.pytorch": ("Trainer",),
    "lightning.pytorch.callbacks": ("ModelCheckpoint", "LearningRateMonitor"),
    "lightning.pytorch.loggers": ("MLFlowLogger",),
}
# The listed modules and their parent packages: the only modules resolving a path may import.
_IMPORTABLE = frozenset(".".join(m.split(".")[:end]) for m in ALLOWED for end in range(1, m.count(".") + 2))


class TargetRefused(UserError):
    """A ``_target_`` that is not on the allowlist."""


@cache
def _allowed() -> dict[int, Any]:
    """The allowlisted objects by ``id`` (held here, so no id is reused)."""
    objects = {}
    for module, names in ALLOWED.items():
        namespace = vars(import_module(module))
        for name in names:
            objects[id(namespace[name])] = namespace[name]
    return objects


def resolve(path: str) -> Any | None:
    """The object a dotted path names, or None: walks module ``__dict__``s (no ``__getattr__``, no descriptors),
    importing only modules of :data:`ALLOWED` (and their packages). Where it finds an object, Hydra's ``_locate``
    finds the same one: it walks the same attributes once those modules are imported."""
    parts = path.split(".")
    obj: Any = sys.modules.get(parts[0])
    if obj is None and parts[0] in _IMPORTABLE:
        obj = import_module(parts[0])
    for end in range(2, len(parts) + 1):
        if not isinstance(obj, ModuleType):
            return None  # attributes of classes or instances are never targets
        namespace, name = vars(obj), parts[end - 1]
        if name in namespace:
            obj = namespace[name]
        elif ".".join(parts[:end]) in _IMPORTABLE:
            obj = import_module(".".join(parts[:end]))
        else:
            return None
    return obj


def _is_allowed(target: Any) -> bool:
    obj = resolve(target) if isinstance(target, str) else target
    return obj is not None and _allowed().get(id(obj)) is obj


def _walk(node: Any, key: str) -> None:
    if isinstance(node, Mapping):
        if "_target_" in node and not _is_allowed(node["_target_"]):
            where = f"{key}._target_" if key else "_target_"
            raise TargetRefused(
                f"{where}={node['_target_']} is not on wdss's allowlist of buildable callables "
                "(wdss.targets.ALLOWED): refused, nothing was built"
            )
        for name, value in node.items():
            _walk(value, f"{key}.{name}" if key else str(name))
    elif isinstance(node, list | tuple):
        for index, value in enumerate(node):
            _walk(value, f"{key}[{index}]")


def check_targets(config: Any, key: str = "") -> None:
    """Raise :class:`TargetRefused`, naming the key and the target, if ``config`` (a mapping, list or OmegaConf
    node; interpolations resolved as instantiate resolves them) names anything outside :data:`ALLOWED`."""
    if OmegaConf.is_config(config):
        config = OmegaConf.to_container(config, resolve=True)
    _walk(config, key)


def instantiate(config: Any, *args: Any, **kwargs: Any) -> Any:
    """``hydra.utils.instantiate`` after :func:`check_targets` of the config and of any mapping in the kwargs."""
    key = config._get_full_key(None) if OmegaConf.is_config(config) else ""
    check_targets(config, key)
    for name, value in kwargs.items():  # a mapping passed here is merged into the config and built too
        check_targets(value, f"{key}.{name}" if key else name)
    return hydra_instantiate(config, *args, **kwargs)
