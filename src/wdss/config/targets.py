"""What configs and checkpoints may build: an allowlist of callables per slot, checked before every instantiate.

Configs and checkpoints are data. A ``_target_`` names a callable by a dotted path, and a name prefix says
nothing about what it names (``torch.save``, ``torch.load`` and ``torch.os.system`` all start with ``torch.``),
so each target is resolved to its object -- walking module namespaces, importing only the modules listed here,
calling nothing -- and compared by identity with the objects its slot may build: a network where a network is
built (``model.net``), an optimiser where an optimiser is (:data:`SLOTS`, :data:`KINDS`). Nested targets (in
kwargs, lists, ``_partial_`` ones) count the same; a target where nothing of any kind is built is refused.

Interpolations are resolved before the check, as Hydra resolves them before it builds, and a resolved string that
still holds ``${`` is refused (Hydra would resolve it again, past the check). Data that wdss reads rather than
composes (a checkpoint's hyper-parameters, a run's saved preprocessing) holds no interpolation at all
(:func:`refuse_interpolation`). :func:`check_config` covers what Hydra itself builds from the ``hydra`` node
(callbacks, launcher, sweeper, logging handlers), before it builds anything. Hydra 1.3.8's own target policy is
a fixed blocklist (``os.system``, ``pickle.load``, ...) with no allowlist hook; it stays active underneath.
"""

from __future__ import annotations

import re
import sys
from collections.abc import Mapping
from functools import cache
from importlib import import_module
from types import ModuleType
from typing import Any

from hydra.utils import instantiate as hydra_instantiate
from omegaconf import DictConfig, ListConfig, OmegaConf

from wdss.errors import UserError

__all__ = [
    "ALLOWED",
    "KINDS",
    "LOGGING",
    "MOVED",
    "SLOTS",
    "InterpolationRefused",
    "TargetRefused",
    "check_config",
    "check_targets",
    "composed_wdss_net",
    "instantiate",
    "moved",
    "refuse_interpolation",
    "resolve",
    "slot_kind",
]

# Kind -> module -> the names in it that a slot of that kind may build.
KINDS: Mapping[str, Mapping[str, tuple[str, ...]]] = {
    "model": {"wdss.training.module": ("SuperResolutionModule",)},
    "network": {
        "wdss.nets.wdss.network": ("WDSSNet",),
        "wdss.nets.upsamplers.baselines": ("Upsample",),
        "wdss.nets.upsamplers.joint_bilateral": ("JointBilateralUpsample",),
        "wdss.nets.upsamplers.learned_bilateral": ("LearnedBilateralUpsample",),
        "wdss.nets.comparison.rrdbnet": ("RRDBNet",),
        "wdss.nets.comparison.nsrr": ("NSRR",),
        "wdss.nets.comparison.fusesr": ("FuseSR",),
    },
    "wavelet transform": {"wdss.wavelets": ("WaveletTransform",)},
    "network head": {"wdss.nets.wdss.heads": ("SharedINR", "MultiINR", "FusionLL")},
    "residual upsampler": {
        "wdss.nets.upsamplers.baselines": ("Upsample",),
        "wdss.nets.upsamplers.joint_bilateral": ("JointBilateralUpsample",),
        "wdss.nets.upsamplers.learned_bilateral": ("LearnedBilateralUpsample",),
    },
    # not LambdaLR/MultiplicativeLR: they take a function
    "optimizer": {
        "torch.optim": ("SGD", "Adam", "AdamW", "Adamax", "Adagrad", "Adadelta", "RMSprop", "NAdam", "RAdam"),
    },
    "scheduler": {
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
    },
    "data module": {"wdss.data": ("SceneDataModule",)},
    "data preparer": {"wdss.render": ("RenderOnFirstUse", "render_preset")},
    "trainer": {"lightning.pytorch": ("Trainer",)},
    "callback": {
        "lightning.pytorch.callbacks": ("ModelCheckpoint", "LearningRateMonitor"),
        "wdss.callbacks.averaging": ("EMAWeightAveraging",),
    },
    "logger": {"lightning.pytorch.loggers": ("MLFlowLogger",)},
    "Hydra callback": {"wdss.tracking": ("SweepParentRun",), "wdss.train": ("ValidateBeforeRun",)},
    # Hydra also requires a registered plugin class here; nothing nested in their configs is buildable.
    "Hydra launcher": {
        "hydra._internal.core_plugins.basic_launcher": ("BasicLauncher",),
        "hydra_plugins.hydra_joblib_launcher.joblib_launcher": ("JoblibLauncher",),
        "hydra_plugins.hydra_submitit_launcher.submitit_launcher": ("LocalLauncher", "SlurmLauncher"),
    },
    "Hydra sweeper": {"hydra._internal.core_plugins.basic_sweeper": ("BasicSweeper",)},
}
# Dotted paths of the layout before issue 39's move (``wdss.model.*``) -> where those callables live now. Checkpoints
# written before the move store the old paths: :func:`moved` renames them in a checkpoint's hyper-parameters before
# they are checked and built. A path not listed here is checked as it stands.
MOVED: Mapping[str, str] = {
    "wdss.model.module.SuperResolutionModule": "wdss.training.module.SuperResolutionModule",
    "wdss.model.network.WDSSNet": "wdss.nets.wdss.network.WDSSNet",
    "wdss.model.baselines.Upsample": "wdss.nets.upsamplers.baselines.Upsample",
    "wdss.model.joint_bilateral.JointBilateralUpsample": "wdss.nets.upsamplers.joint_bilateral.JointBilateralUpsample",
    "wdss.model.learned_bilateral.LearnedBilateralUpsample": (
        "wdss.nets.upsamplers.learned_bilateral.LearnedBilateralUpsample"
    ),
    "wdss.model.rrdbnet.RRDBNet": "wdss.nets.comparison.rrdbnet.RRDBNet",
    "wdss.model.nsrr.NSRR": "wdss.nets.comparison.nsrr.NSRR",
    "wdss.model.fusesr.FuseSR": "wdss.nets.comparison.fusesr.FuseSR",
    "wdss.averaging.EMAWeightAveraging": "wdss.callbacks.averaging.EMAWeightAveraging",
}
WDSS_NET = "wdss.nets.wdss.network.WDSSNet"
# Before issue 39 composed WDSSNet, it took its head and its residual upsampler by name (``head: shared_inr``,
# ``residual: learned_bilateral``) and the learned kernel's options beside them; checkpoints of then store that shape.
# :func:`composed_wdss_net` rewrites it into today's with these: each old name -> the config that builds it now
# (conf/head, conf/residual), and each kernel option -> its name on the kernel.
OLD_HEADS: Mapping[str, str] = {
    "shared_inr": "wdss.nets.wdss.heads.SharedINR",
    "multi_inr": "wdss.nets.wdss.heads.MultiINR",
    "fusion_ll": "wdss.nets.wdss.heads.FusionLL",
}
OLD_RESIDUALS: Mapping[str, Mapping[str, Any] | None] = {
    "none": None,
    "bilinear": {"_target_": "wdss.nets.upsamplers.baselines.Upsample", "mode": "bilinear", "demodulated": True},
    "joint_bilateral": {"_target_": "wdss.nets.upsamplers.joint_bilateral.JointBilateralUpsample"},
    "learned_bilateral": {"_target_": "wdss.nets.upsamplers.learned_bilateral.LearnedBilateralUpsample"},
}
OLD_KERNEL_OPTIONS: Mapping[str, str] = {
    "tap_brdf": "tap_brdf",
    "kernel_never_raise": "never_raise",
    "kernel_raise_within_albedo": "raise_within_albedo",
}
# The classes and factories (``class:``, ``()``) that Hydra's logging configs may name (logging.config.dictConfig
# builds them with their keys as arguments: any class would do, subprocess.Popen included).
LOGGING: Mapping[str, tuple[str, ...]] = {
    "logging": ("StreamHandler", "FileHandler", "NullHandler", "Formatter", "Filter"),
    "logging.handlers": ("RotatingFileHandler", "TimedRotatingFileHandler", "WatchedFileHandler"),
    "colorlog": ("ColoredFormatter",),  # hydra/job_logging=colorlog (the hydra_colorlog plugin)
}
_STREAMS = ("ext://sys.stdout", "ext://sys.stderr")  # dictConfig's ext:// imports what it names

# What each slot builds: a key path (``*``: any one key or list index) -> its kind. The module's own slots appear
# bare (its arguments), under ``model`` (a config) and under ``hyper_parameters`` (a checkpoint).
_MODULE_SLOTS = {
    ("net",): "network",
    ("net", "wavelet"): "wavelet transform",
    ("net", "head"): "network head",
    ("net", "upsampler"): "residual upsampler",
    ("optimizer",): "optimizer",
    ("scheduler",): "scheduler",
}
SLOTS: Mapping[tuple[str, ...], str] = {
    ("model",): "model",
    **_MODULE_SLOTS,
    **{("model", *path): kind for path, kind in _MODULE_SLOTS.items()},
    **{("hyper_parameters", *path): kind for path, kind in _MODULE_SLOTS.items()},
    ("transform",): "wavelet transform",  # the transform group, which model.net.wavelet interpolates
    ("head",): "network head",  # the head group, which model.net.head interpolates
    ("residual", "upsampler"): "residual upsampler",  # the residual group, which model.net.upsampler interpolates
    ("data",): "data module",
    ("data", "prepare"): "data preparer",
    ("trainer",): "trainer",
    ("callbacks", "*"): "callback",
    ("logger",): "logger",
    ("hydra", "callbacks", "*"): "Hydra callback",
    ("hydra", "launcher"): "Hydra launcher",
    ("hydra", "sweeper"): "Hydra sweeper",
}

# The union of the kinds: every callable any slot may build.
ALLOWED: Mapping[str, tuple[str, ...]] = {}
for _modules in KINDS.values():
    for _module, _names in _modules.items():
        ALLOWED[_module] = tuple(dict.fromkeys((*ALLOWED.get(_module, ()), *_names)))  # type: ignore[index]
# The listed modules and their parent packages: the only modules resolving a path may import.
_IMPORTABLE = frozenset(
    ".".join(m.split(".")[:end]) for m in (*ALLOWED, *LOGGING) for end in range(1, m.count(".") + 2)
)


class TargetRefused(UserError):
    """A ``_target_`` (or logging class) that its slot may not build."""


class InterpolationRefused(TargetRefused):
    """An interpolation in data that wdss reads and never resolves, or one that resolving would leave behind."""


@cache
def _allowed(kind: str) -> dict[int, Any]:
    """The objects of one kind (:data:`KINDS`, or ``"logging"``) by ``id`` (held here, so no id is reused); a
    module that is not installed (an optional Hydra plugin) contributes nothing."""
    objects = {}
    for module, names in (LOGGING if kind == "logging" else KINDS[kind]).items():
        try:
            namespace = vars(import_module(module))
        except ImportError:
            continue
        for name in names:
            objects[id(namespace[name])] = namespace[name]
    return objects


def resolve(path: str) -> Any | None:
    """The object a dotted path names, or None: walks module ``__dict__``s (no ``__getattr__``, no descriptors),
    importing only modules of :data:`ALLOWED` (and their packages). Where it finds an object, Hydra's ``_locate``
    finds the same one: it walks the same attributes once those modules are imported."""
    parts = path.split(".")
    try:
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
    except ImportError:  # an optional plugin that is not installed
        return None
    return obj


def _is(kind: str, target: Any) -> bool:
    if isinstance(target, _Unresolved):
        return False
    obj = resolve(target) if isinstance(target, str) else target
    return obj is not None and _allowed(kind).get(id(obj)) is obj


def slot_kind(key: str) -> str | None:
    """The kind of callable built at a dotted ``key`` (``model.net``, ``callbacks.checkpoint``,
    ``hyper_parameters.optimizer``), or None where nothing is built (:data:`SLOTS`)."""
    parts = tuple(p for p in re.split(r"[.\[\]]", key) if p)
    for pattern, kind in SLOTS.items():
        if len(pattern) == len(parts) and all(p in ("*", q) for p, q in zip(pattern, parts, strict=True)):
            return kind
    return None


def _names(kind: str) -> str:
    return ", ".join(f"{m}.{n}" for m, names in KINDS[kind].items() for n in names)


class _Unresolved(str):
    """An interpolation that resolves only while Hydra runs (``${hydra:runtime.output_dir}``, a missing value)."""


def _refused_target(key: str, target: Any) -> TargetRefused:
    where = f"{key}._target_" if key else "_target_"
    kind = slot_kind(key)
    if isinstance(target, _Unresolved):
        return TargetRefused(f"{where}={target} cannot be resolved before the run: refused, nothing was built")
    if kind is None:
        return TargetRefused(
            f"{where}={target} is not on wdss's allowlist: nothing is built at {key or 'the top level'} "
            "(wdss.config.targets.SLOTS): refused, nothing was built"
        )
    return TargetRefused(
        f"{where}={target} is not on wdss's allowlist for {key}, which builds a {kind} ({_names(kind)}; "
        "wdss.config.targets.KINDS): refused, nothing was built"
    )


def _walk(node: Any, key: str) -> None:
    if isinstance(node, Mapping):
        if "_target_" in node:
            kind = slot_kind(key)
            if kind is None or not _is(kind, node["_target_"]):
                raise _refused_target(key, node["_target_"])
        for name, value in node.items():
            _walk(value, f"{key}.{name}" if key else str(name))
    elif isinstance(node, list | tuple):
        for index, value in enumerate(node):
            _walk(value, f"{key}[{index}]")
    elif isinstance(node, str) and "${" in node and not isinstance(node, _Unresolved):
        raise InterpolationRefused(
            f"{key}={_short(node)} still holds an interpolation once resolved (an escaped \\${{...}}), which "
            "instantiate would resolve again: refused, nothing was built"
        )


def _short(value: str) -> str:
    return value if len(value) <= 80 else value[:77] + "..."


def _has_interpolation(node: Any) -> bool:
    if isinstance(node, str):
        return "${" in node
    if isinstance(node, Mapping):
        return any(_has_interpolation(k) or _has_interpolation(v) for k, v in node.items())
    if isinstance(node, list | tuple):
        return any(_has_interpolation(v) for v in node)
    return False


def composed_wdss_net(net: Mapping[str, Any]) -> dict[str, Any]:
    """A WDSSNet config (plain containers) of the shape before issue 39 composed the network -- ``head`` and
    ``residual`` by name, the learned kernel's ``tap_brdf``, ``kernel_never_raise`` and ``kernel_raise_within_albedo``
    beside them -- in today's shape: ``head`` the node that builds that head, ``upsampler`` the node that builds that
    residual upsampler (None for ``none``), the kernel's options on the kernel (without it they did nothing, and are
    dropped). A name it does not know is kept, for the network to refuse; a config of today's shape is returned as
    it is."""
    head, old = net.get("head"), [key for key in ("residual", *OLD_KERNEL_OPTIONS) if key in net]
    if not isinstance(head, str) and not old:
        return dict(net)
    new: dict[str, Any] = {}
    for key, value in net.items():
        if key == "head" and isinstance(value, str):
            new[key] = {"_target_": OLD_HEADS[value]} if value in OLD_HEADS else value
        elif key not in old:
            new[key] = value
        elif key == "residual" and "upsampler" not in net:
            upsampler = OLD_RESIDUALS.get(value, value) if isinstance(value, str) else value
            if value == "learned_bilateral":
                options = {OLD_KERNEL_OPTIONS[option]: net[option] for option in OLD_KERNEL_OPTIONS if option in net}
                upsampler = {**upsampler, **options}
            new["upsampler"] = dict(upsampler) if isinstance(upsampler, Mapping) else upsampler
    return new


def moved(node: Any) -> Any:
    """``node`` (plain containers, as a checkpoint stores them) with every ``_target_`` that :data:`MOVED` lists
    renamed to where it lives now, and every WDSSNet config of the shape before the network was composed rewritten
    into today's (:func:`composed_wdss_net`); everything else as it was."""
    if isinstance(node, Mapping):
        renamed = {
            name: MOVED.get(value, value) if name == "_target_" and isinstance(value, str) else moved(value)
            for name, value in node.items()
        }
        return composed_wdss_net(renamed) if renamed.get("_target_") == WDSS_NET else renamed
    if isinstance(node, list | tuple):
        return type(node)(moved(value) for value in node)
    return node


def refuse_interpolation(node: Any, key: str = "") -> None:
    """Raise :class:`InterpolationRefused`, naming the key, where data that wdss reads and never resolves (a
    checkpoint's hyper-parameters, a run's saved preprocessing) holds an interpolation: resolving one can build
    anything (``${oc.create:{_target_: ...}}``), read the environment, or hide a value from the allowlist."""
    if OmegaConf.is_config(node):
        node = OmegaConf.to_container(node, resolve=False)
    if isinstance(node, str) and "${" in node:
        raise InterpolationRefused(
            f"{key or 'the value'}={_short(node)} is an interpolation, and wdss resolves none in data it reads "
            "(checkpoints, a run's saved config): refused, nothing was built"
        )
    if isinstance(node, Mapping):
        for name, value in node.items():
            here = f"{key}.{name}" if key else str(name)
            if isinstance(name, str) and "${" in name:
                raise InterpolationRefused(f"{here}: a key with an interpolation, in data wdss reads: refused")
            refuse_interpolation(value, here)
    elif isinstance(node, list | tuple):
        for index, value in enumerate(node):
            refuse_interpolation(value, f"{key}[{index}]")


def check_targets(config: Any, key: str = "") -> None:
    """Raise :class:`TargetRefused`, naming the key and the target, if ``config`` (a mapping, list or OmegaConf
    node at ``key``; interpolations resolved as instantiate resolves them) builds anything its slots may not."""
    if not OmegaConf.is_config(config) and _has_interpolation(config):  # instantiate resolves these too
        config = OmegaConf.create(config, flags={"allow_objects": True})
    if OmegaConf.is_config(config):
        config = OmegaConf.to_container(config, resolve=True)
    _walk(config, key)


def _tolerant(node: Any) -> Any:
    """A composed config as plain containers, its interpolations resolved where they resolve before the run;
    the rest (Hydra's runtime values, missing values) kept as :class:`_Unresolved` text."""
    if isinstance(node, DictConfig):
        return {key: _child(node, key) for key in node}
    if isinstance(node, ListConfig):
        return [_child(node, index) for index in range(len(node))]
    return node


def _child(parent: DictConfig | ListConfig, key: Any) -> Any:
    try:
        value = parent[key]
    except Exception:  # noqa: BLE001 - unresolvable now (Hydra fills it in as it runs)
        return _Unresolved(str(parent._get_node(key)._value()))
    return _tolerant(value) if OmegaConf.is_config(value) else value


def _check_logging(node: Any, key: str) -> None:
    if isinstance(node, Mapping):
        for name, value in node.items():
            here = f"{key}.{name}"
            if name in ("class", "()") and not _is("logging", value):
                raise TargetRefused(
                    f"{here}={value} is not on wdss's allowlist of logging classes (wdss.config.targets.LOGGING): "
                    "refused, nothing was built"
                )
            _check_logging(value, here)
    elif isinstance(node, list | tuple):
        for index, value in enumerate(node):
            _check_logging(value, f"{key}[{index}]")
    elif isinstance(node, str) and node.startswith("ext://") and node not in _STREAMS:
        raise TargetRefused(f"{key}={node}: logging configs may name only {' or '.join(_STREAMS)}: refused")


def check_config(cfg: DictConfig) -> None:
    """Raise :class:`TargetRefused`, naming the key, if a composed config (with its ``hydra`` node, before Hydra
    runs) has Hydra or wdss build anything its slot may not: the task's nodes, ``hydra.callbacks``,
    ``hydra.launcher`` and ``hydra.sweeper`` (:data:`SLOTS`), and the classes of Hydra's logging configs
    (:data:`LOGGING`)."""
    plain = _tolerant(cfg)
    _walk(plain, "")
    for name in ("job_logging", "hydra_logging"):
        _check_logging((plain.get("hydra") or {}).get(name), f"hydra.{name}")


def instantiate(config: Any, *args: Any, at: str | None = None, **kwargs: Any) -> Any:
    """``hydra.utils.instantiate`` after :func:`check_targets` of the config and of any mapping in the kwargs.
    ``at``: the slot a plain mapping fills (``net``, ``optimizer``); an OmegaConf node's own key says it."""
    key = config._get_full_key(None) if OmegaConf.is_config(config) else ""
    key = at if at is not None else key
    check_targets(config, key)
    for name, value in kwargs.items():  # a mapping passed here is merged into the config and built too
        check_targets(value, f"{key}.{name}" if key else name)
    return hydra_instantiate(config, *args, **kwargs)
