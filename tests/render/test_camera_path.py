"""Fitted camera paths (wdss.render.camera_path) against analytic scenes of boxes: no Blender needed."""

from __future__ import annotations

import numpy as np
import pytest

from wdss.render.camera_path import EYE_HEIGHT, check_poses, fit_camera, look_pose


class Boxes:
    """Axis-aligned boxes as a ray caster: solid boxes have outward normals, rooms inward ones (their walls
    seen from inside are front faces)."""

    def __init__(self, *boxes: tuple[list[float], list[float], bool]):
        self.boxes = [(np.array(lo, float), np.array(hi, float), room) for lo, hi, room in boxes]

    def __call__(self, frame: int, origins: np.ndarray, directions: np.ndarray):
        distances = np.full(len(origins), np.inf)
        normals = np.zeros((len(origins), 3))
        with np.errstate(divide="ignore", invalid="ignore"):
            for lo, hi, room in self.boxes:
                for axis in range(3):
                    for bound, sign in ((lo, -1.0), (hi, 1.0)):
                        t = (bound[axis] - origins[:, axis]) / directions[:, axis]
                        point = origins + t[:, None] * directions
                        others = [a for a in range(3) if a != axis]
                        within = np.all((point[:, others] >= lo[others]) & (point[:, others] <= hi[others]), axis=1)
                        closer = within & (t > 1e-9) & (t < distances)
                        distances[closer] = t[closer]
                        normals[closer] = 0.0
                        normals[closer, axis] = -sign if room else sign
        return distances, normals

    def bounds(self):
        return np.min([b[0] for b in self.boxes], 0), np.max([b[1] for b in self.boxes], 0)


ROOM = Boxes(([-5, -5, 0], [5, 5, 3], True), ([-0.5, -0.5, 0], [0.5, 0.5, 3], False))  # a room with a pillar
YARD = Boxes(([-6, -6, -0.1], [6, 6, 0], False), ([-1, -1, 0], [1, 1, 2], False))  # a ground slab and a block


def test_a_fly_through_walks_at_eye_height_through_the_free_space_of_a_room():
    path, poses, _ = fit_camera("fly", 3, *ROOM.bounds(), ROOM, frames=40, aspect=1.5)
    eyes = np.array([pose[:3, 3] for pose in poses.values()])
    assert np.all(np.abs(eyes[:, :2]) < 5 - 0.1) and not np.any(np.all(np.abs(eyes[:, :2]) < 0.5, axis=1))
    np.testing.assert_allclose(eyes[:, 2], EYE_HEIGHT, atol=0.05)
    steps = np.linalg.norm(np.diff(eyes, axis=0), axis=1)
    assert steps.min() > 0 and steps.max() < 0.5  # it moves, smoothly
    assert check_poses(poses, path.lens, 1.5, ROOM, clearance=0.1) is None
    again, _, _ = fit_camera("fly", 3, *ROOM.bounds(), ROOM, frames=40, aspect=1.5)
    other, _, _ = fit_camera("fly", 4, *ROOM.bounds(), ROOM, frames=40, aspect=1.5)
    assert again.to_dict() == path.to_dict() != other.to_dict()


def test_a_fly_through_in_centimetres_walks_at_the_same_eye_height_in_metres():
    room = Boxes(*[(100 * np.array(lo), 100 * np.array(hi), inside) for lo, hi, inside in ROOM.boxes])
    metres, poses_m, _ = fit_camera("fly", 3, *ROOM.bounds(), ROOM, frames=20, aspect=1.5)
    path, poses, _ = fit_camera("fly", 3, *room.bounds(), room, frames=20, aspect=1.5, eye_height=100 * EYE_HEIGHT)
    assert path.eye == pytest.approx(100 * metres.eye)
    for frame, pose in poses.items():
        np.testing.assert_allclose(pose[:3, 3], 100 * poses_m[frame][:3, 3], atol=1e-3)  # waypoints: 6 decimals


def test_an_orbit_circles_outside_the_scene_looking_at_it():
    path, poses, _ = fit_camera("orbit", 0, *YARD.bounds(), YARD, frames=30, aspect=1.5)
    eyes = np.array([pose[:3, 3] for pose in poses.values()])
    assert np.all(np.hypot(eyes[:, 0], eyes[:, 1]) > 6 * np.sqrt(2)) and np.all(eyes[:, 2] > 0)
    for pose in poses.values():  # the view's centre ray points at the block's side of the scene
        forward = -pose[:3, 2]
        assert np.dot(forward[:2], -pose[:2, 3]) > 0
    assert path.to_dict()["mode"] == "orbit"
    with pytest.raises(ValueError, match="sees mostly back faces"):  # a closed room is not for orbits
        fit_camera("orbit", 0, *ROOM.bounds(), ROOM, frames=30, aspect=1.5)


def test_cameras_inside_geometry_through_walls_or_at_the_sky_are_refused():
    inside = {f: look_pose(np.array([0.0, 0.0, 1.5]), np.array([1.0, 0.0, 0.0])) for f in range(3)}
    assert "inside geometry at frame 0" in check_poses(inside, 30.0, 1.5, ROOM, clearance=0.05)
    through = {f: look_pose(np.array([4.0 - 1.5 * f, 2.0, 1.5]), np.array([0.0, 1.0, 0.0])) for f in range(3)}
    room = Boxes(([-5, -5, 0], [5, 5, 3], True), ([1.0, -5, 0], [1.2, 5, 3], False))  # a wall across the room
    assert "passes through a surface between frames 1 and 2" in check_poses(through, 30.0, 1.5, room, 0.05)
    up = {f: look_pose(np.array([8.0 + 0.01 * f, 0.0, 1.5]), np.array([0.0, 0.2, 1.0])) for f in range(6)}
    assert "empty sky for more than 3 frames" in check_poses(up, 30.0, 1.5, YARD, clearance=0.05)
    assert check_poses({f: up[f] for f in range(3)}, 30.0, 1.5, YARD, clearance=0.05) is None  # a few frames


def test_a_scene_without_head_room_gets_a_clear_error():
    # A room (3 high, so an eye height of 1.7) split at mid height by a slab: 1 unit free above each floor.
    solid = Boxes(([-5, -5, 0], [5, 5, 3], True), ([-5, -5, 1], [5, 5, 2], False))
    with pytest.raises(ValueError, match="no fly camera path: no floor with head room found for an eye height of 1.7"):
        fit_camera("fly", 0, *solid.bounds(), solid, frames=10, aspect=1.5)
    with pytest.raises(ValueError, match="camera mode must be one of"):
        fit_camera("dolly", 0, *solid.bounds(), solid, frames=10, aspect=1.5)
