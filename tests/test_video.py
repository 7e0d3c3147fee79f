"""Videos of test sequences (wdss.video): the MP4 decodes back to its frames, the GIF loops over the crops."""

from __future__ import annotations

import av
import numpy as np
from PIL import Image

from wdss.video import LABELS, Mp4Writer, labelled, write_gif


def decode(path) -> tuple[list[np.ndarray], float]:
    with av.open(str(path)) as container:
        stream = container.streams.video[0]
        frames = [frame.to_ndarray(format="rgb24") for frame in container.decode(stream)]
        return frames, float(stream.average_rate)


def test_the_mp4_decodes_to_every_frame_at_the_frame_rate_padded_to_even_sizes(tmp_path):
    ys, xs = np.mgrid[0:37, 0:61]  # odd sizes: 4:2:0 needs even ones
    frames = [np.stack([xs * 4, ys * 6, np.full_like(xs, 30 * t)], -1).astype(np.uint8) for t in range(7)]
    writer = Mp4Writer(tmp_path / "seq.mp4", fps=24)
    for frame in frames:
        writer.write(frame)
    writer.close()
    decoded, fps = decode(tmp_path / "seq.mp4")
    assert len(decoded) == 7 and decoded[0].shape == (38, 62, 3) and fps == 24
    for original, back in zip(frames, decoded, strict=True):  # H.264 at CRF 18: close, not exact
        assert np.abs(back[:37, :61].astype(int) - original).mean() < 3


def test_labels_sit_above_the_tiles_and_the_gif_loops_at_the_frame_rate(tmp_path):
    panel = np.zeros((20, 4 * 30, 3), np.uint8)
    shown = labelled(panel)
    assert shown.shape == (34, 120, 3) and shown[:14].max() == 255 and shown[14:].max() == 0
    assert len(LABELS) == 4
    write_gif([shown, 255 - shown, shown], tmp_path / "crop.gif", fps=10)
    gif = Image.open(tmp_path / "crop.gif")
    assert gif.n_frames == 3 and gif.size == (120, 34) and gif.info["duration"] == 100 and gif.info["loop"] == 0
