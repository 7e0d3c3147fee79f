"""Camera paths fitted to a scene's bounds (``camera=orbit|fly``), checked with ray casts: plain numpy.

The scene is seen only through a ray caster, ``ray_cast(frame, origins, directions) -> (distances, normals)``
(``(N, 3)`` world origins and unit directions; distances ``inf`` where nothing is hit; geometric normals in
world space), so the paths are tested here against analytic scenes and fitted in Blender by
:mod:`wdss.render.scene_file` with ``Scene.ray_cast``.

* ``orbit``: the procedural scenes' orbit (:class:`wdss.render.spec.CameraPath`, the same seeded speed
  wobble and look-at sway) in normalised units, scaled and centred on the scene's bounds.
* ``fly``: a walk at eye height through free space: standing points found by vertical ray casts (a floor
  below, head room above), joined by clear lines of sight into a smooth curve, travelled with the same seeded
  speed wobble, looking ahead along the curve with a seeded sway and pitch.

Every candidate path is checked frame by frame (:func:`check_poses`): the camera is never inside geometry
(most rays from it hit back faces) nor within ``clearance`` of a surface, never passes through a surface
between two frames, and never looks at empty sky (fewer than :data:`MIN_HIT_SHARE` of a grid of view rays hit
geometry) or at mostly back faces (a closed room's walls from outside) for more than :data:`MAX_SKY_FRAMES`
frames in a row. :func:`fit_camera` tries seeded candidates
until one passes.
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import asdict, dataclass

import numpy as np

from wdss.render.spec import CameraPath, camera_pose, intrinsics

__all__ = ["CAMERA_MODES", "FlyPath", "OrbitPath", "check_poses", "fit_camera", "look_pose"]

RayCast = Callable[[int, np.ndarray, np.ndarray], tuple[np.ndarray, np.ndarray]]

CAMERA_MODES = ("orbit", "fly")
MAX_SKY_FRAMES = 3  # consecutive frames that may look at (nearly) nothing but sky
MIN_HIT_SHARE = 0.1  # of the view rays that must hit geometry for a frame not to count as sky
ATTEMPTS = 24  # candidate paths tried before giving up
EYE_HEIGHT = 1.7  # metres: eye height of a fly-through (at most 0.6 x the scene's height); fit_camera's eye_height
NO_STANDING_POINT = "no floor with head room found"
PROCEDURAL_EXTENT = 7.0  # objects of the procedural scenes lie within this radius: the orbit's unit scene


def look_pose(eye: np.ndarray, forward: np.ndarray) -> np.ndarray:
    """Camera-to-world 4x4 (Blender camera: looks down -z, y up) at ``eye`` looking along ``forward``, z up."""
    back = -np.asarray(forward, dtype=np.float64)
    back /= np.linalg.norm(back)
    right = np.cross([0.0, 0.0, 1.0], back)
    right /= max(np.linalg.norm(right), 1e-12)
    up = np.cross(back, right)
    pose = np.eye(4)
    pose[:3, 0], pose[:3, 1], pose[:3, 2], pose[:3, 3] = right, up, back, eye
    return pose


@dataclass
class OrbitPath:
    """The procedural orbit ``path`` (normalised units), scaled by ``unit`` and moved to ``center``."""

    path: CameraPath
    center: list[float]
    unit: float

    @property
    def lens(self) -> float:
        return self.path.lens

    def pose(self, frame: int) -> np.ndarray:
        pose = camera_pose(self.path, frame)
        pose[:3, 3] = np.asarray(self.center) + self.unit * pose[:3, 3]
        return pose

    def to_dict(self) -> dict:
        return {"mode": "orbit", **asdict(self)}


@dataclass
class FlyPath:
    """A smooth curve through ``waypoints`` travelled at ``speed`` units per frame (mean, with the procedural
    orbit's wobble), looking ``lookahead`` units ahead along it, turned by a sway of up to ``sway`` radians."""

    waypoints: list[list[float]]
    start: float  # arc length at frame 0
    speed: float
    speed_wobble: float
    wobble_period: float
    lookahead: float
    sway: float
    pitch: float  # radians, negative: looking down
    eye: float  # eye height above the floor, units
    lens: float

    def __post_init__(self) -> None:
        self._points, self._lengths = _catmull_rom(np.asarray(self.waypoints, dtype=np.float64))

    @property
    def length(self) -> float:
        return float(self._lengths[-1])

    def distance(self, frame: int) -> float:
        t = float(frame)
        wobble = self.speed_wobble * self.wobble_period / (2 * math.pi) * math.sin(2 * math.pi * t / self.wobble_period)
        return self.start + self.speed * (t + wobble)

    def point(self, s: float) -> np.ndarray:
        """The curve at arc length ``s``, continued along its end tangents beyond either end."""
        points, lengths = self._points, self._lengths
        if s <= 0.0:
            return points[0] + s * _unit(points[1] - points[0])
        if s >= lengths[-1]:
            return points[-1] + (s - lengths[-1]) * _unit(points[-1] - points[-2])
        return np.array([np.interp(s, lengths, points[:, i]) for i in range(3)])

    def pose(self, frame: int) -> np.ndarray:
        t = float(frame)
        s = self.distance(frame)
        eye = self.point(s) + np.array([0.0, 0.0, 0.02 * self.eye * math.sin(t / 11.0)])  # head bob
        ahead = self.point(s + self.lookahead) - self.point(s)
        heading = math.atan2(ahead[1], ahead[0]) + self.sway * math.sin(t / 13.0) + 0.3 * self.sway * math.sin(t / 5.0)
        pitch = self.pitch + 0.04 * math.sin(t / 7.0)
        forward = np.array([math.cos(heading) * math.cos(pitch), math.sin(heading) * math.cos(pitch), math.sin(pitch)])
        return look_pose(eye, forward)

    def to_dict(self) -> dict:
        return {"mode": "fly", **asdict(self)}


def _unit(v: np.ndarray) -> np.ndarray:
    return v / max(float(np.linalg.norm(v)), 1e-12)


def _catmull_rom(waypoints: np.ndarray, steps: int = 24) -> tuple[np.ndarray, np.ndarray]:
    """Points of the centripetal Catmull-Rom curve through ``waypoints`` and their cumulative arc lengths."""
    padded = np.concatenate([2 * waypoints[:1] - waypoints[1:2], waypoints, 2 * waypoints[-1:] - waypoints[-2:-1]])
    out = [waypoints[:1]]
    for i in range(len(waypoints) - 1):
        p0, p1, p2, p3 = padded[i : i + 4]
        t0 = 0.0
        t1 = t0 + max(np.linalg.norm(p1 - p0) ** 0.5, 1e-6)
        t2 = t1 + max(np.linalg.norm(p2 - p1) ** 0.5, 1e-6)
        t3 = t2 + max(np.linalg.norm(p3 - p2) ** 0.5, 1e-6)
        t = np.linspace(t1, t2, steps + 1)[1:, None]
        a1 = (t1 - t) / (t1 - t0) * p0 + (t - t0) / (t1 - t0) * p1
        a2 = (t2 - t) / (t2 - t1) * p1 + (t - t1) / (t2 - t1) * p2
        a3 = (t3 - t) / (t3 - t2) * p2 + (t - t2) / (t3 - t2) * p3
        b1 = (t2 - t) / (t2 - t0) * a1 + (t - t0) / (t2 - t0) * a2
        b2 = (t3 - t) / (t3 - t1) * a2 + (t - t1) / (t3 - t1) * a3
        out.append((t2 - t) / (t2 - t1) * b1 + (t - t1) / (t2 - t1) * b2)
    points = np.concatenate(out)
    lengths = np.concatenate([[0.0], np.cumsum(np.linalg.norm(np.diff(points, axis=0), axis=1))])
    return points, lengths


def _sphere_directions() -> np.ndarray:
    """14 unit directions: the 6 axes and the 8 cube diagonals."""
    axes = np.concatenate([np.eye(3), -np.eye(3)])
    diagonals = np.array([[x, y, z] for x in (-1, 1) for y in (-1, 1) for z in (-1, 1)], dtype=np.float64)
    return np.concatenate([axes, diagonals / math.sqrt(3.0)])


def _view_rays(pose: np.ndarray, lens: float, aspect: float, columns: int = 8, rows: int = 6) -> np.ndarray:
    """World directions through a ``columns x rows`` grid of the image of a camera with ``lens`` (36 mm sensor)."""
    width, height = 1000.0, 1000.0 / aspect
    fx, fy, cx, cy = intrinsics(lens, int(width), int(round(height)))
    xs = (np.arange(columns) + 0.5) / columns * width
    ys = (np.arange(rows) + 0.5) / rows * height
    x, y = np.meshgrid((xs - cx) / fx, (ys - cy) / fy)
    rays = np.stack([x.ravel(), y.ravel(), -np.ones(x.size)], axis=-1) @ pose[:3, :3].T
    return rays / np.linalg.norm(rays, axis=-1, keepdims=True)


def inside_geometry(ray_cast: RayCast, frame: int, point: np.ndarray) -> tuple[bool, float]:
    """Whether ``point`` is inside geometry (most rays from it hit back faces), and its distance to the nearest
    surface along the 14 directions of :func:`_sphere_directions`."""
    directions = _sphere_directions()
    distances, normals = ray_cast(frame, np.repeat(point[None], len(directions), 0), directions)
    hit = np.isfinite(distances)
    back = hit & ((normals * directions).sum(-1) > 0.0)
    nearest = float(distances[hit].min()) if hit.any() else math.inf
    return bool(back.sum() * 2 >= len(directions)), nearest


def check_poses(
    poses: dict[int, np.ndarray], lens: float, aspect: float, ray_cast: RayCast, clearance: float
) -> str | None:
    """Why the camera at ``poses`` (frame -> camera-to-world) is unusable, or None when it is fine."""
    frames = sorted(poses)
    sky_run = back_run = 0
    for index, frame in enumerate(frames):
        eye = poses[frame][:3, 3]
        inside, nearest = inside_geometry(ray_cast, frame, eye)
        if inside:
            return f"the camera is inside geometry at frame {frame}"
        if nearest < clearance:
            return f"the camera is {nearest:.3g} from a surface at frame {frame} (clearance {clearance:.3g})"
        if index:
            step = eye - poses[frames[index - 1]][:3, 3]
            length = float(np.linalg.norm(step))
            if length > 1e-9:
                distance, _ = ray_cast(frame, eye[None] - step[None], (step / length)[None])
                if distance[0] < length:
                    return f"the camera passes through a surface between frames {frames[index - 1]} and {frame}"
        rays = _view_rays(poses[frame], lens, aspect)
        distances, normals = ray_cast(frame, np.repeat(eye[None], len(rays), 0), rays)
        hit = np.isfinite(distances)
        sky_run = sky_run + 1 if hit.mean() < MIN_HIT_SHARE else 0
        if sky_run > MAX_SKY_FRAMES:
            return f"the camera looks at empty sky for more than {MAX_SKY_FRAMES} frames (frames up to {frame})"
        back = ((normals * rays).sum(-1) > 0.0)[hit]
        back_run = back_run + 1 if back.size and back.mean() > 0.5 else 0
        if back_run > MAX_SKY_FRAMES:
            return (
                f"the camera sees mostly back faces (e.g. a room's walls from outside) for more than "
                f"{MAX_SKY_FRAMES} frames (frames up to {frame})"
            )
    return None


def orbit_path(rng: np.random.Generator, lo: np.ndarray, hi: np.ndarray) -> OrbitPath:
    """A seeded procedural orbit around the bounds ``lo``..``hi``: eye outside the bounds' circle, looking
    at their lower half."""
    size = hi - lo
    extent = max(0.5 * float(np.hypot(size[0], size[1])), 0.5 * float(size[2]), 1e-6)
    unit = extent / PROCEDURAL_EXTENT
    center = [float((lo[0] + hi[0]) / 2), float((lo[1] + hi[1]) / 2), float(lo[2])]
    height_n = float(size[2]) / unit
    path = CameraPath(
        radius=float(rng.uniform(8.0, 13.0)),
        height=float(height_n * rng.uniform(0.4, 1.0) + rng.uniform(0.5, 2.0)),
        angle0=float(rng.uniform(0, 2 * math.pi)),
        speed=float(rng.choice([-1, 1]) * rng.uniform(0.008, 0.03)),
        speed_wobble=float(rng.uniform(0.0, 0.8)),
        wobble_period=float(rng.uniform(12.0, 40.0)),
        target=[float(rng.uniform(-1.5, 1.5)), float(rng.uniform(-1.5, 1.5)), float(height_n * rng.uniform(0.2, 0.5))],
        target_sway=float(rng.uniform(0.2, 1.5)),
        lens=float(rng.uniform(24.0, 45.0)),
    )
    return OrbitPath(path=path, center=center, unit=unit)


def _standing_point(ray_cast: RayCast, x: float, y: float, lo, hi, eye: float, headroom: float) -> np.ndarray | None:
    """The eye position above the lowest walkable floor at ``(x, y)`` with ``eye + headroom`` free above it."""
    size = float(np.max(hi - lo))
    eps = 1e-4 * size
    origin = np.array([x, y, lo[2] - 10 * eps])
    up = np.array([[0.0, 0.0, 1.0]])
    surfaces = []  # (z, normal z) from the bottom up
    for _ in range(32):
        distance, normal = ray_cast(0, origin[None], up)
        if not np.isfinite(distance[0]):
            break
        origin = origin + (distance[0] + eps) * up[0]
        surfaces.append((float(origin[2]), float(normal[0][2])))
    for i, (z, nz) in enumerate(surfaces):
        if nz < 0.5:  # not the top of something one can stand on
            continue
        ceiling = surfaces[i + 1][0] if i + 1 < len(surfaces) else math.inf
        if ceiling - z >= eye + headroom:
            return np.array([x, y, z + eye])
    return None


def _clear(ray_cast: RayCast, a: np.ndarray, b: np.ndarray, margin: float) -> bool:
    """Whether the segment ``a``-``b`` and its copies ``margin`` to either side and below are free."""
    step = b - a
    length = float(np.linalg.norm(step))
    direction = step / length
    side = np.cross(direction, [0.0, 0.0, 1.0])
    side = side / max(float(np.linalg.norm(side)), 1e-12) * margin
    origins = np.stack([a, a + side, a - side, a - [0.0, 0.0, margin]])
    distances, _ = ray_cast(0, origins, np.repeat(direction[None], 4, 0))
    return bool((distances > length + margin).all())


def fly_path(
    rng: np.random.Generator,
    lo: np.ndarray,
    hi: np.ndarray,
    ray_cast: RayCast,
    frames: int,
    eye_height: float = EYE_HEIGHT,
) -> FlyPath | str:
    """A seeded walk at ``eye_height`` (scene units) through free space long enough for ``frames`` frames, or why
    there is none."""
    size = hi - lo
    eye = min(eye_height, 0.6 * float(size[2])) if size[2] > 0 else eye_height
    clearance = 0.25 * eye
    speed = eye * float(rng.uniform(0.025, 0.09))
    speed_wobble, wobble_period = float(rng.uniform(0.0, 0.8)), float(rng.uniform(12.0, 40.0))
    start = 2.0 * speed
    needed = start + speed * (frames + 1) * (1.0 + speed_wobble)  # beyond its end the curve goes straight on
    floor = _Floor(ray_cast, lo, hi, eye, clearance)
    first = floor.first_point(rng)
    if first is None:
        return f"{NO_STANDING_POINT} for an eye height of {eye:.3g} (64 tries)"
    radius = min(max(needed, 4 * eye), 0.5 * float(np.hypot(size[0], size[1])))
    candidates = floor.points_around(rng, first, radius)
    waypoints = _Walk(rng, ray_cast, candidates, eye, clearance, needed).extend([first], None, 0.0)
    if waypoints is None:
        return f"no walk of {needed:.3g} units through free space from {first.round(3).tolist()}"
    return FlyPath(
        waypoints=[p.round(6).tolist() for p in waypoints],
        start=start,
        speed=speed,
        speed_wobble=speed_wobble,
        wobble_period=wobble_period,
        lookahead=3.0 * eye,
        sway=float(rng.uniform(0.05, 0.35)),
        pitch=float(-rng.uniform(0.0, 0.2)),
        eye=eye,
        lens=float(rng.uniform(20.0, 32.0)),
    )


class _Floor:
    """Standing points of a fly-through: ``eye`` above a floor, with head room, in free space at least twice
    ``clearance`` from any surface, and not on the scene's very edge."""

    def __init__(self, ray_cast: RayCast, lo: np.ndarray, hi: np.ndarray, eye: float, clearance: float) -> None:
        self.ray_cast, self.lo, self.hi, self.eye, self.clearance = ray_cast, lo, hi, eye, clearance
        size = hi - lo
        self.inner_lo, self.inner_hi = lo[:2] + 0.1 * size[:2], hi[:2] - 0.1 * size[:2]

    def free(self, point: np.ndarray | None) -> bool:
        if point is None:
            return False
        inside, nearest = inside_geometry(self.ray_cast, 0, point)
        return not inside and nearest >= 2 * self.clearance

    def standing(self, x: float, y: float) -> np.ndarray | None:
        point = _standing_point(self.ray_cast, x, y, self.lo, self.hi, self.eye, self.clearance)
        return point if self.free(point) else None

    def first_point(self, rng: np.random.Generator) -> np.ndarray | None:
        """A standing point at a seeded place (64 tries), or None."""
        first = None
        for _ in range(64):
            first = self.standing(*rng.uniform(self.inner_lo, self.inner_hi))
            if first is not None:
                break
        return first

    def points_around(self, rng: np.random.Generator, first: np.ndarray, radius: float) -> list[np.ndarray]:
        """The standing points among 64 seeded places within ``radius`` of ``first``: the walk's candidates."""
        candidates = []
        for _ in range(64):
            angle, r = rng.uniform(0, 2 * math.pi), radius * math.sqrt(rng.random())
            x, y = np.clip(first[:2] + r * np.array([math.cos(angle), math.sin(angle)]), self.inner_lo, self.inner_hi)
            point = self.standing(float(x), float(y))
            if point is not None:
                candidates.append(point)
        return candidates


class _Walk:
    """A depth-first search for a walk of at least ``needed`` units through ``candidates`` (joined by clear lines of
    sight), within a budget of 400 line-of-sight tests."""

    def __init__(
        self,
        rng: np.random.Generator,
        ray_cast: RayCast,
        candidates: list[np.ndarray],
        eye: float,
        clearance: float,
        needed: float,
    ) -> None:
        self.rng, self.ray_cast, self.candidates = rng, ray_cast, candidates
        self.eye, self.clearance, self.needed = eye, clearance, needed
        self.budget = 400

    def extend(self, waypoints: list[np.ndarray], heading: np.ndarray | None, length: float) -> list[np.ndarray] | None:
        """Waypoints from ``waypoints`` on, at least ``needed`` long: at most 4 branches per waypoint, turns
        under 100 degrees; a waypoint may be visited again (loops), but not one of the last two."""
        if length >= self.needed:
            return waypoints
        here = waypoints[-1]
        for point in self._branches(waypoints, heading):
            if self.budget <= 0:
                return None
            self.budget -= 1
            if _clear(self.ray_cast, here, point, self.clearance):
                step = point - here
                found = self.extend([*waypoints, point], step[:2], length + float(np.linalg.norm(step)))
                if found is not None:
                    return found
        return None

    def _branches(self, waypoints: list[np.ndarray], heading: np.ndarray | None) -> list[np.ndarray]:
        """The next waypoints to try from the last, at most 4: the gentlest turns first, with a seeded jitter."""
        here = waypoints[-1]
        options = []
        for point in self.candidates:
            step = point - here
            distance = float(np.linalg.norm(step[:2]))
            if not 1.5 * self.eye <= distance <= 6.0 * self.eye or any(point is w for w in waypoints[-2:]):
                continue
            turn = 0.0 if heading is None else abs(_angle(heading, step[:2]))
            if turn < math.radians(100):
                options.append((turn / math.pi + 0.5 * self.rng.random(), point))
        return [point for _, point in sorted(options, key=lambda option: option[0])[:4]]


def _angle(a: np.ndarray, b: np.ndarray) -> float:
    return math.atan2(a[0] * b[1] - a[1] * b[0], a[0] * b[0] + a[1] * b[1])


def fit_camera(
    mode: str, seed: int, lo, hi, ray_cast: RayCast, frames: int, aspect: float, *, eye_height: float = EYE_HEIGHT
) -> tuple[OrbitPath | FlyPath, dict[int, np.ndarray], int]:
    """The first of :data:`ATTEMPTS` seeded ``mode`` paths (``orbit`` or ``fly``) whose poses of frames
    ``-1..frames+1`` pass :func:`check_poses`; returns the path, those poses and the attempt's index.
    ``eye_height``: a fly-through's, in scene units (:data:`EYE_HEIGHT` metres in a scene measured in metres).

    Raises ``ValueError`` with the last reason when none passes.
    """
    if mode not in CAMERA_MODES:
        raise ValueError(f"camera mode must be one of {CAMERA_MODES}, got {mode!r}")
    lo, hi = np.asarray(lo, dtype=np.float64), np.asarray(hi, dtype=np.float64)
    rng = np.random.default_rng([seed, 16])
    reason = ""
    for attempt in range(ATTEMPTS):
        path = orbit_path(rng, lo, hi) if mode == "orbit" else fly_path(rng, lo, hi, ray_cast, frames, eye_height)
        if isinstance(path, str):
            reason = path
            if reason.startswith(NO_STANDING_POINT):  # the scene has no floor with head room: no retry finds one
                raise ValueError(f"no {mode} camera path: {reason}")
            continue
        poses = {f: path.pose(f) for f in range(-1, frames + 2)}
        # the curve between waypoints (which keep 2 x 0.25 eye heights from walls) may cut corners a little
        clearance = 0.005 * float(np.linalg.norm(hi - lo)) if mode == "orbit" else 0.125 * path.eye
        found = check_poses(poses, path.lens, aspect, ray_cast, clearance)
        if found is None:
            return path, poses, attempt
        reason = found
    raise ValueError(f"no {mode} camera path passes the checks after {ATTEMPTS} attempts (last: {reason})")
