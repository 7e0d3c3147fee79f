"""The rendered conventions, checked against independent oracles: motion vectors against a reprojection of
planar depth with the sidecar cameras, the sky's against directions at infinity, normals of unit length."""

from __future__ import annotations

import json
from collections.abc import Callable
from pathlib import Path

import numpy as np

from wdss.data import Sequence

G_BUFFERS = ["color", "depth", "motion", "normal", "roughness", "metallic", "base_color"]


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


def project(points: np.ndarray, camera_to_world: np.ndarray, fx_fy_cx_cy) -> np.ndarray:
    """Pixel positions ``(2, N)`` (x right, y up from the bottom) of world ``points`` ``(N, 3)``."""
    fx, fy, cx, cy = fx_fy_cx_cy
    local = np.concatenate([points, np.ones((len(points), 1))], axis=1) @ np.linalg.inv(camera_to_world).T
    return np.stack([cx + fx * local[:, 0] / -local[:, 2], cy + fy * local[:, 1] / -local[:, 2]])


def check_conventions(
    folder: Path, *, tolerance: float = 0.05, moving: Callable[[int, np.ndarray], np.ndarray] | None = None
) -> dict[int, dict[str, np.ndarray]]:
    """Assert the conventions on every HR frame after the first of the sequence at ``folder``: the median
    motion error of surfaces and of the sky is below ``tolerance`` pixels, normals have unit length on surfaces
    and are 0 on the sky. Returns each frame's buffers, with ``world`` (H, W, 3 points) and ``surface`` added.

    ``moving(frame, world)``: where the scene's moving objects are (an ``(H, W)`` mask); when given, 99 % of
    the other surface pixels' motion must be within ``tolerance`` of the reprojection, not only the median (a
    silhouette pixel may hold the depth of one surface and the motion of another)."""
    meta, cameras = load_sidecar(folder)
    intrinsics = meta["intrinsics"]["fx_fy_cx_cy"]
    seq = Sequence(folder)
    out = {}
    for frame in seq.frames[1:]:
        buffers = seq.read(frame, seq.hr, G_BUFFERS)
        depth = buffers["depth"][0].astype(np.float64)
        surface = depth > 0
        assert surface.any(), f"frame {frame}: nothing but sky"
        world, expected = reproject(depth, cameras[frame], cameras[frame - 1], intrinsics)
        error = np.hypot(*(buffers["motion"] - expected))
        assert np.median(error[surface]) < tolerance, f"frame {frame}: motion against reprojected depth"
        if moving is not None:
            still = surface & ~moving(frame, world)
            assert still.sum() > 0.25 * surface.sum(), f"frame {frame}: too little static surface to check"
            wrong = float(np.mean(error[still] >= tolerance))
            assert wrong < 0.01, f"frame {frame}: static surface motion off by {tolerance} px or more at {wrong:.1%}"
        if (~surface).any():  # the sky moves as directions at infinity do
            _, at_infinity = reproject(np.full_like(depth, 1e7), cameras[frame], cameras[frame - 1], intrinsics)
            sky_error = np.hypot(*(buffers["motion"] - at_infinity))[~surface]
            assert np.median(sky_error) < tolerance, f"frame {frame}: sky motion against the camera rotation"
        length = np.linalg.norm(buffers["normal"], axis=0)
        np.testing.assert_allclose(length[surface], 1.0, atol=1e-3, err_msg=f"frame {frame}: normal length")
        assert np.all(length[~surface] == 0.0)
        out[frame] = {**buffers, "world": world, "surface": surface}
    return out
