"""A picture of one frame's buffers side by side: ``python -m wdss.render ... preview=true``."""

from __future__ import annotations

from pathlib import Path

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402
import numpy as np  # noqa: E402
import torch  # noqa: E402

from wdss.data.layouts import BUFFERS, Sequence  # noqa: E402
from wdss.ops.tonemap import hable  # noqa: E402


def preview(sequence_dir: str | Path, frame: int | None = None, out: str | Path | None = None) -> Path:
    """Write ``preview_NNNN.png`` beside the sequence: every buffer of one frame, and the LR colour."""
    seq = Sequence(sequence_dir)
    frame = seq.frames[min(1, len(seq.frames) - 1)] if frame is None else frame
    hr = {k: torch.from_numpy(v) for k, v in seq.read(frame, seq.hr, BUFFERS).items()}
    motion = hr["motion"]
    magnitude = motion.norm(dim=0)
    angle = torch.atan2(motion[1], motion[0])
    panels = {
        "colour (Hable)": hable(hr["color"]),
        "base colour": hr["base_color"].clamp(0, 1),
        "depth": hr["depth"] / max(float(hr["depth"].max()), 1e-6),
        "world normal": hr["normal"] * 0.5 + 0.5,
        "roughness": hr["roughness"],
        "metallic": hr["metallic"],
        "NoV": hr["nov"],
        "specular": hr["specular"],
        f"motion (max {float(magnitude.max()):.1f} px)": torch.stack(
            [0.5 + 0.5 * torch.cos(angle), 0.5 + 0.5 * torch.sin(angle), magnitude / max(float(magnitude.max()), 1e-6)]
        ),
    }
    if len(seq.resolutions) > 1:
        low = seq.resolutions[-1]
        panels[f"colour at {low}P"] = hable(torch.from_numpy(seq.read(frame, low, ["color"])["color"]))
    cols = 5
    rows = -(-len(panels) // cols)
    fig, axes = plt.subplots(rows, cols, figsize=(cols * 3.2, rows * 2.2))
    for ax in np.ravel(axes):
        ax.axis("off")
    for ax, (title, image) in zip(np.ravel(axes), panels.items(), strict=False):
        array = image.numpy()
        ax.imshow(
            array[0] if array.shape[0] == 1 else array.transpose(1, 2, 0),
            cmap="gray",
            vmin=0,
            vmax=1,
            interpolation="nearest",
        )
        ax.set_title(title, fontsize=9)
    fig.suptitle(f"{seq.name}, frame {frame}", fontsize=10)
    fig.tight_layout()
    out = Path(out) if out else Path(sequence_dir) / f"preview_{frame:04d}.png"
    fig.savefig(out, dpi=100)
    plt.close(fig)
    return out
