"""Procedural scene descriptions from a seed: plain data, no Blender, stored in each sequence's sidecar.

Everything that moves is a function of the frame number evaluated here (camera and moving objects), so
the camera matrices in the sidecar are exact and a sequence is reproducible from its seed alone.
"""

from __future__ import annotations

import math
from dataclasses import asdict, dataclass, field

import numpy as np

__all__ = ["CameraPath", "SceneSpec", "camera_pose", "object_pose", "random_scene"]

SHAPES = ("cube", "uv_sphere", "ico_sphere", "cylinder", "cone", "torus", "suzanne", "rounded_cube")
TEXTURES = ("noise", "voronoi", "brick", "wave", "checker")
HDRIS = ("city", "courtyard", "forest", "interior", "night", "studio", "sunrise", "sunset")


@dataclass
class Material:
    texture: str
    color_a: list[float]
    color_b: list[float]
    scale: float
    roughness: list[float]  # noise-driven between these two values
    metallic: float  # 0 or 1
    bump: float  # strength of the fine-detail bump
    emission: float = 0.0  # radiance multiplier of emissive objects (HDR peaks)
    emission_color: list[float] = field(default_factory=lambda: [1.0, 1.0, 1.0])


@dataclass
class Thing:
    shape: str
    location: list[float]
    rotation: list[float]
    scale: float
    material: Material
    velocity: list[float] = field(default_factory=lambda: [0.0, 0.0, 0.0])  # units per frame
    spin: float = 0.0  # radians per frame about z
    bob: float = 0.0  # amplitude of a vertical sine, units


@dataclass
class CameraPath:
    radius: float
    height: float
    angle0: float
    speed: float  # radians per frame, mean
    speed_wobble: float  # relative variation of the speed
    wobble_period: float  # frames
    target: list[float]
    target_sway: float  # units: how far the look-at point turns
    lens: float  # mm, sensor width 36 mm


@dataclass
class SceneSpec:
    seed: int
    ground: Material
    things: list[Thing]
    hdri: str
    hdri_strength: float
    hdri_rotation: float
    sun_rotation: list[float]
    sun_energy: float
    camera: CameraPath

    def to_dict(self) -> dict:
        return asdict(self)

    @classmethod
    def from_dict(cls, data: dict) -> SceneSpec:
        """The spec a ``sequence.json`` records under ``scene`` (:meth:`to_dict`'s inverse; plain data only)."""
        things = [Thing(**{**t, "material": Material(**t["material"])}) for t in data["things"]]
        fields = {k: v for k, v in data.items() if k not in ("ground", "things", "camera")}
        return cls(**fields, ground=Material(**data["ground"]), things=things, camera=CameraPath(**data["camera"]))


def _material(rng: np.random.Generator, *, emissive: bool = False) -> Material:
    metallic = float(rng.random() < 0.3)
    low = float(rng.uniform(0.02, 0.4))
    return Material(
        texture=str(rng.choice(TEXTURES)),
        color_a=rng.uniform(0.02, 0.95, 3).round(4).tolist(),
        color_b=rng.uniform(0.02, 0.95, 3).round(4).tolist(),
        scale=float(rng.uniform(2.0, 12.0)),
        roughness=[low, float(min(1.0, low + rng.uniform(0.1, 0.6)))],
        metallic=metallic,
        bump=float(rng.uniform(0.05, 0.4)),
        # 1-5x the radiance of sun-lit surfaces, as lamps and signs are in games. Brighter whole-object emitters
        # saturate much of a frame at any exposure that still shows the rest of the scene.
        emission=float(rng.uniform(1.0, 5.0)) if emissive else 0.0,
        emission_color=rng.uniform(0.3, 1.0, 3).round(4).tolist(),
    )


def random_scene(seed: int, *, min_objects: int = 10, max_objects: int = 40) -> SceneSpec:
    """A random scene: ground, ``min..max`` objects (some emissive, some moving), an HDRI, a sun, a camera path."""
    rng = np.random.default_rng(seed)
    things = []
    for _ in range(int(rng.integers(min_objects, max_objects + 1))):
        radius, angle = 7.0 * math.sqrt(rng.random()), rng.uniform(0, 2 * math.pi)
        scale = float(rng.uniform(0.3, 1.3))
        moving = rng.random() < 0.2
        things.append(
            Thing(
                shape=str(rng.choice(SHAPES)),
                location=[radius * math.cos(angle), radius * math.sin(angle), scale * float(rng.uniform(0.6, 1.6))],
                rotation=[float(rng.uniform(-0.4, 0.4)), float(rng.uniform(-0.4, 0.4)), float(rng.uniform(0, 6.3))],
                scale=scale,
                material=_material(rng, emissive=rng.random() < 0.1),
                velocity=(rng.uniform(-0.06, 0.06, 2).tolist() + [0.0]) if moving else [0.0, 0.0, 0.0],
                spin=float(rng.uniform(-0.08, 0.08)) if moving else 0.0,
                bob=float(rng.uniform(0.0, 0.3)) if moving else 0.0,
            )
        )
    camera = CameraPath(
        radius=float(rng.uniform(8.0, 13.0)),
        height=float(rng.uniform(1.5, 5.0)),
        angle0=float(rng.uniform(0, 2 * math.pi)),
        speed=float(rng.choice([-1, 1]) * rng.uniform(0.008, 0.03)),
        speed_wobble=float(rng.uniform(0.0, 0.8)),
        wobble_period=float(rng.uniform(12.0, 40.0)),
        target=[float(rng.uniform(-1.5, 1.5)), float(rng.uniform(-1.5, 1.5)), float(rng.uniform(0.3, 1.2))],
        target_sway=float(rng.uniform(0.2, 1.5)),
        lens=float(rng.uniform(24.0, 45.0)),
    )
    return SceneSpec(
        seed=seed,
        ground=_material(rng),
        things=things,
        hdri=str(rng.choice(HDRIS)),
        hdri_strength=float(rng.uniform(0.5, 1.5)),
        hdri_rotation=float(rng.uniform(0, 2 * math.pi)),
        sun_rotation=[float(rng.uniform(0.3, 1.2)), 0.0, float(rng.uniform(0, 2 * math.pi))],
        sun_energy=float(rng.uniform(1.5, 5.0)),
        camera=camera,
    )


def camera_pose(path: CameraPath, frame: int) -> np.ndarray:
    """The 4x4 camera-to-world matrix at ``frame`` (Blender camera: looks down -z, y up)."""
    t = float(frame)
    # Integrated angular speed: the mean speed plus a sine wobble, so the camera accelerates and slows.
    angle = path.angle0 + path.speed * (
        t + path.speed_wobble * path.wobble_period / (2 * math.pi) * math.sin(2 * math.pi * t / path.wobble_period)
    )
    radius = path.radius * (1.0 + 0.08 * math.sin(t / 17.0))
    eye = np.array([radius * math.cos(angle), radius * math.sin(angle), path.height + 0.3 * math.sin(t / 11.0)])
    sway = path.target_sway * np.array([math.sin(t / 13.0), math.cos(t / 19.0), 0.2 * math.sin(t / 7.0)])
    target = np.asarray(path.target) + sway
    back = eye - target
    back /= np.linalg.norm(back)
    right = np.cross([0.0, 0.0, 1.0], back)
    right /= np.linalg.norm(right)
    up = np.cross(back, right)
    pose = np.eye(4)
    pose[:3, 0], pose[:3, 1], pose[:3, 2], pose[:3, 3] = right, up, back, eye
    return pose


def object_pose(thing: Thing, frame: int) -> tuple[list[float], list[float]]:
    """Location and Euler rotation of an object at ``frame``."""
    t = float(frame)
    location = [thing.location[i] + thing.velocity[i] * t for i in range(3)]
    location[2] += thing.bob * math.sin(t / 5.0)
    rotation = [thing.rotation[0], thing.rotation[1], thing.rotation[2] + thing.spin * t]
    return location, rotation


def intrinsics(lens: float, width: int, height: int, sensor: float = 36.0) -> np.ndarray:
    """Pixel projection of a Blender camera (sensor fit AUTO): ``[fx, fy, cx, cy]``, y up from the bottom."""
    focal = lens / sensor * max(width, height)
    return np.array([focal, focal, width / 2.0, height / 2.0])
