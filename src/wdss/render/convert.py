"""Blender's passes -> the buffers of the authors' Unreal layout (pure numpy, no Blender needed).

Conventions (docs/reference.md section 5, verified on bpy 5.0.1):

* Combined: linear HDR radiance -> ``color``.
* Depth.Z: planar camera depth, 1e10 on the background -> ``depth`` with the background mapped to 0 (as the
  authors' loader does with depth > 100).
* Normal: world-space shading normal -> ``normal``, renormalised (samples straddling a silhouette average),
  0 on the background.
* Vector.XY: previous minus current position in pixels of the rendered resolution, x right, y up ->
  ``motion`` = current minus previous, in high-resolution pixels (the authors' convention), filled on the
  background from the two cameras (directions at infinity move with the camera rotation only).
* AOVs basecolor / roughness / metallic, wired from the Principled BSDF inputs -> ``base_color``,
  ``roughness``, ``metallic``.
* ``specular`` is 0.5 on surfaces (Unreal's default) and 0 on the background, so the sky's BRDF factor
  is 0 and it passes through demodulation instead of being divided by 0.04.
* ``nov``: the cosine between the normal and the direction to the camera, from the Position pass.
* Emission (``use_pass_emit``): the emission of directly visible surfaces (noise-free: a material's emission is
  evaluated where the camera ray hits) -> ``emission``, 0 on the background (the sky is in the colour, not
  here). Demodulation subtracts it first, as emitted light is not the BRDF factor times an irradiance.
"""

from __future__ import annotations

import numpy as np

from wdss.render.spec import intrinsics

__all__ = ["BACKGROUND_DEPTH", "background_motion", "to_buffers"]

BACKGROUND_DEPTH = 1e9  # Blender writes 1e10 where no surface was hit


def _pixel_rays(lens: float, width: int, height: int) -> np.ndarray:
    """Camera-space unit directions through the pixel centres, ``(H, W, 3)``, rows top to bottom."""
    fx, fy, cx, cy = intrinsics(lens, width, height)
    xs = np.arange(width) + 0.5
    ys_up = height - (np.arange(height) + 0.5)  # row r has its centre at height - r - 0.5 from the bottom
    x, y = np.meshgrid((xs - cx) / fx, (ys_up - cy) / fy)
    rays = np.stack([x, y, -np.ones_like(x)], axis=-1)
    return rays / np.linalg.norm(rays, axis=-1, keepdims=True)


def background_motion(current: np.ndarray, previous: np.ndarray, lens: float, width: int, height: int) -> np.ndarray:
    """Motion (current minus previous, pixels, y up) of directions at infinity, ``(2, H, W)``.

    ``current``/``previous``: 4x4 camera-to-world matrices. Only the rotation matters at infinity.
    """
    fx, fy, cx, cy = intrinsics(lens, width, height)
    world = _pixel_rays(lens, width, height) @ current[:3, :3].T
    in_previous = world @ previous[:3, :3]  # world -> previous camera (the inverse of a rotation)
    z = -in_previous[..., 2]
    with np.errstate(divide="ignore", invalid="ignore"):
        px = cx + fx * in_previous[..., 0] / z
        py = cy + fy * in_previous[..., 1] / z
    xs = np.arange(width)[None, :] + 0.5
    ys_up = height - (np.arange(height)[:, None] + 0.5)
    motion = np.stack([xs - px, ys_up - py])
    motion[:, ~(z > 1e-6)] = 0.0  # behind the previous camera: no meaningful position
    return motion


def to_buffers(
    passes: dict[str, np.ndarray],
    *,
    camera: np.ndarray,
    previous_camera: np.ndarray | None,
    lens: float,
    motion_scale: float = 1.0,
) -> dict[str, np.ndarray]:
    """The Unreal-layout buffers ``(C, H, W)`` float32 of one rendered frame.

    ``passes`` maps Blender pass names (``Combined``, ``Depth``, ``Normal``, ``Vector``, ``Position``,
    ``basecolor``, ``roughness``, ``metallic``, ``Emission``) to ``(C, H, W)`` arrays. ``motion_scale`` converts the
    rendered resolution's pixels to high-resolution pixels (s for a natively rendered low-resolution frame).
    """
    depth = passes["Depth"][:1].astype(np.float64)
    _, height, width = depth.shape
    surface = depth[0] < BACKGROUND_DEPTH
    normal = np.where(surface, passes["Normal"][:3], 0.0)
    # Samples of one pixel that straddle a silhouette average their normals; renormalise to unit length.
    length = np.linalg.norm(normal, axis=0, keepdims=True)
    normal = np.where(length > 1e-6, normal / np.maximum(length, 1e-6), 0.0)
    to_camera = camera[:3, 3].reshape(3, 1, 1) - passes["Position"][:3]
    to_camera /= np.maximum(np.linalg.norm(to_camera, axis=0, keepdims=True), 1e-12)
    nov = np.where(surface, np.clip((normal * to_camera).sum(0, keepdims=True), 0.0, 1.0), 0.0)
    motion = -passes["Vector"][:2].astype(np.float64)
    if previous_camera is not None:
        motion[:, ~surface] = background_motion(camera, previous_camera, lens, width, height)[:, ~surface]
    else:
        motion[:, ~surface] = 0.0
    buffers = {
        "color": passes["Combined"][:3],
        "base_color": np.where(surface, passes["basecolor"][:3], 0.0),
        "depth": np.where(surface, depth, 0.0),
        "normal": normal,
        "specular": np.where(surface, 0.5, 0.0)[None],
        "metallic": np.where(surface, passes["metallic"][:1], 0.0),
        "roughness": np.where(surface, passes["roughness"][:1], 0.0),
        "nov": nov,
        "motion": motion * motion_scale,
        "emission": np.where(surface, passes["Emission"][:3], 0.0),
    }
    return {k: np.ascontiguousarray(v, dtype=np.float32) for k, v in buffers.items()}
