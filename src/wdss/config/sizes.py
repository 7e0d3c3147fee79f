"""The widths of the learned models and the settings of a model, read from their configs: the size configs
(``conf/size/<name>.yaml``) and the model configs (``conf/model/<name>.yaml``) are where they are written, and the
benchmarks and checks that build networks outside a Hydra run read them here rather than keeping copies."""

from __future__ import annotations

from typing import Any

from omegaconf import OmegaConf

from wdss.config.targets import instantiate
from wdss.paths import CONF_DIR

__all__ = ["model_net_settings", "size_widths"]


def size_widths(size: str, model: str = "wdss") -> dict[str, Any]:
    """``conf/size/<size>.yaml``'s entry for ``model`` (``wdss``, ``nsrr``, ``fusesr``, ``real_esrgan``) without its
    learning rate: the keyword arguments that size that network."""
    path = CONF_DIR / "size" / f"{size}.yaml"
    if not path.is_file():
        raise ValueError(f"no size {size!r}: {path} does not exist")
    entry = OmegaConf.to_container(OmegaConf.load(path), resolve=False).get(model)
    if not isinstance(entry, dict):
        raise ValueError(f"{path} has no entry {model!r}")
    return {k: v for k, v in entry.items() if k != "lr"}


def model_net_settings(model: str) -> dict[str, Any]:
    """What ``conf/model/<model>.yaml`` itself sets on its network (not what it inherits from its defaults), as
    keyword arguments of :class:`~wdss.nets.wdss.network.WDSSNet`: a ``wavelet`` node becomes its ``transform``, and
    another node with a ``_target_`` (its ``head``) is built, through the allowlist."""
    path = CONF_DIR / "model" / f"{model}.yaml"
    net = dict(OmegaConf.to_container(OmegaConf.load(path), resolve=False).get("net") or {})
    net.pop("_target_", None)
    wavelet = net.pop("wavelet", None)
    if isinstance(wavelet, dict):
        net["transform"] = wavelet["transform"]
    for key, value in net.items():
        if isinstance(value, dict) and "_target_" in value:
            net[key] = instantiate(value, at=f"net.{key}")
    return net
