"""Videos of test sequences (wdss.video): the MP4 decodes back to its frames, a short one loops to last 3 s, the GIF
loops over the crops."""

from __future__ import annotations

import av
import numpy as np
from PIL import Image

from wdss.video import LABELS, MIN_SECONDS, Mp4Writer, labelled, loops, write_gif


def decode(path) -> tuple[list[np.ndarray], float, float]:
    """The frames, frame rate and duration (seconds) of an MP4, as a player reads them."""
    with av.open(str(path)) as container:
        stream = container.streams.video[0]
        frames = [frame.to_ndarray(format="rgb24") for frame in container.decode(stream)]
        return frames, float(stream.average_rate), float(stream.duration * stream.time_base)


def write(path, count: int, fps: float) -> list[np.ndarray]:
    ys, xs = np.mgrid[0:37, 0:61]  # odd sizes: 4:2:0 needs even ones
    frames = [np.stack([xs * 4, ys * 6, np.full_like(xs, (30 * t) % 256)], -1).astype(np.uint8) for t in range(count)]
    writer = Mp4Writer(path, fps=fps)
    for frame in frames:
        writer.write(frame)
    writer.close()
    assert writer.frames == count and writer.loops == loops(count, fps)
    return frames


def test_a_short_mp4_loops_its_frames_at_the_frame_rate_for_three_seconds_padded_to_even_sizes(tmp_path):
    frames = write(tmp_path / "seq.mp4", 7, fps=24)
    decoded, fps, seconds = decode(tmp_path / "seq.mp4")
    assert loops(7, 24) == 11 and MIN_SECONDS == 3  # 7 frames at 24 fps: 0.29 s, played 11 times
    assert len(decoded) == 77 and decoded[0].shape == (38, 62, 3) and fps == 24
    assert seconds == 77 / 24
    for index, back in enumerate(decoded):  # H.264 at CRF 18: close, not exact; each copy the sequence in order
        assert np.abs(back[:37, :61].astype(int) - frames[index % 7]).mean() < 3


def test_a_sequence_of_three_seconds_or_more_plays_once(tmp_path):
    write(tmp_path / "seq.mp4", 31, fps=10)
    decoded, fps, seconds = decode(tmp_path / "seq.mp4")
    assert len(decoded) == 31 and fps == 10 and seconds == 3.1


def test_labels_sit_above_the_tiles_and_the_gif_loops_at_the_frame_rate(tmp_path):
    panel = np.zeros((20, 4 * 30, 3), np.uint8)
    shown = labelled(panel)
    assert shown.shape == (34, 120, 3) and shown[:14].max() == 255 and shown[14:].max() == 0
    assert len(LABELS) == 4
    write_gif([shown, 255 - shown, shown], tmp_path / "crop.gif", fps=10)
    gif = Image.open(tmp_path / "crop.gif")
    assert gif.n_frames == 3 and gif.size == (120, 34) and gif.info["duration"] == 100 and gif.info["loop"] == 0
