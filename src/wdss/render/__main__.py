"""``python -m wdss.render``: render sequences with Blender Cycles (config: ``conf/render/``).

Examples::

    python -m wdss.render                                   # conf/render/default.yaml
    python -m wdss.render -cn mini                          # the default training dataset (data/mini)
    python -m wdss.render out_dir=data/city 'sequences=[{name: a, seed: 7}]' frames=60 preview=true
    python -m wdss.render out_dir=data/house scene=assets/house.glb camera=fly 'sequences=[{name: a, seed: 1}]'
"""

from __future__ import annotations

from pathlib import Path

from omegaconf import DictConfig, OmegaConf

from wdss.errors import entry_point
from wdss.paths import CONF_DIR


@entry_point("wdss.render", CONF_DIR / "render", "default")
def main(cfg: DictConfig) -> None:
    from wdss.render.preview import preview
    from wdss.render.sequence import render_sequences

    settings = OmegaConf.to_container(cfg, resolve=True)
    out_dir = Path(settings.pop("out_dir"))
    sequences = settings.pop("sequences")
    show = settings.pop("preview")
    frame = settings.pop("preview_frame")
    folders = render_sequences(out_dir, sequences, **settings)
    for folder in folders:
        print(f"{folder}")
        if show:
            print(f"  preview: {preview(folder, frame)}")


if __name__ == "__main__":
    main()
