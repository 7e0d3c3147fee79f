"""An independent reprojection of planar depth with the sidecar cameras (the oracle for motion vectors)."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np


def load_sidecar(folder: Path) -> tuple[dict, dict[int, np.ndarray]]:
    meta = json.loads((folder / "sequence.json").read_text())
    return meta, {f["frame"]: np.array(f["camera_to_world"]) for f in meta["frames"]}


def reproject(depth: np.ndarray, current: np.ndarray, previous: np.ndarray, fx_fy_cx_cy) -> tuple[np.ndarray, ...]:
    """World points of planar ``depth`` (H, W) and their motion (current - previous, pixels, y up)."""
    fx, fy, cx, cy = fx_fy_cx_cy
    height, width = depth.shape
    x = np.arange(width)[None, :] + 0.5
    y_up = height - (np.arange(height)[:, None] + 0.5)
    cam = np.stack([(x - cx) / fx * depth, (y_up - cy) / fy * depth, -depth, np.ones_like(depth)], axis=-1)
    world = cam @ current.T
    prev = world @ np.linalg.inv(previous).T
    x_prev = cx + fx * prev[..., 0] / -prev[..., 2]
    y_prev = cy + fy * prev[..., 1] / -prev[..., 2]
    return world[..., :3], np.stack([x - x_prev, y_up - y_prev])
