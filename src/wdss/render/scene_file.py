"""Scenes from files (``render.scene=path.{glb,gltf,blend}``): checked, loaded into Blender, lit, framed.

* Checks before anything is created (:func:`check_scene`): the extension is one of :data:`SCENE_KINDS`, the
  file exists and so does every external buffer and image a glTF references (:func:`scene_resources`),
  ``camera`` is one of :data:`CAMERAS` and ``lighting`` one of :data:`LIGHTINGS`; loading then refuses a file
  with no geometry to render. Errors name the config key, the sequence and the file. :func:`file_digest`
  covers the file and those resources (a resumed render refuses a changed scene).
* Loading uses Blender's own readers: the glTF 2.0 importer into an empty scene, or ``.blend`` opened as it
  is (its active scene and view layer; other view layers, compositing and the sequencer off), with Python in
  the file never run (``use_scripts=False``, auto-execution off): a scene file is data. The viewport is made
  to show what renders, since the geometry, its bounds and the ray casts come from the viewport's depsgraph.
* The file's materials, lights and cameras are kept; :func:`wdss.render.materials.wire_aovs` sends each
  material's base colour, roughness and metallic to the AOVs (fallbacks recorded in the sidecar).
* Lighting (``lighting``): ``auto`` keeps the file's when it has a light or a world with an environment or
  sky texture, and otherwise adds, as the procedural scenes have, one of Blender's HDRIs and a sun (seeded);
  ``hdri`` adds them in any case; ``file`` never does.
* Camera (``camera``): ``file`` renders the file's camera (the scene's, else the first by name) as
  animated; ``orbit`` and ``fly`` fit a seeded path to the scene's bounds
  (:mod:`wdss.render.camera_path`); ``auto`` is ``file`` when the file's camera moves, else ``orbit``. The
  file's camera is made a pinhole with Blender's default 36 mm sensor (same field of view at the rendered
  size, no lens shift, no depth of field, its lens, sensor and shift no longer keyed or driven), so one
  ``intrinsics`` entry describes every frame.
* Frame 0 of the sequence is the file's first frame: the ``.blend`` scene's start frame, or a glTF's
  earliest keyframe (0 without animation). A glTF's animated objects all play, each its first animation.
"""

from __future__ import annotations

import hashlib
import json
import logging
import os
import struct
from pathlib import Path
from typing import Any
from urllib.parse import unquote

import numpy as np

from wdss.errors import ConfigError
from wdss.render.cycles_scene import CyclesScene

__all__ = ["CAMERAS", "LIGHTINGS", "SCENE_KINDS", "FileScene", "check_scene", "file_digest", "scene_resources"]

log = logging.getLogger(__name__)

SCENE_KINDS = {".glb": "gltf", ".gltf": "gltf", ".blend": "blend"}
CAMERAS = ("auto", "file", "orbit", "fly")
LIGHTINGS = ("auto", "file", "hdri")


def check_scene(scene: str | Path | None, camera: str, lighting: str, *, where: str) -> Path | None:
    """The resolved scene file (None for a procedural scene) after checking the ``scene``, ``camera`` and
    ``lighting`` settings of one sequence (``where``, e.g. ``"sequence 'a'"``, goes into the errors)."""
    if camera not in CAMERAS:
        raise ConfigError(f"render.camera ({where}) must be one of {', '.join(CAMERAS)}; got {camera!r}")
    if lighting not in LIGHTINGS:
        raise ConfigError(f"render.lighting ({where}) must be one of {', '.join(LIGHTINGS)}; got {lighting!r}")
    if scene is None:
        if camera in ("file", "fly") or lighting == "file":
            setting = f"camera={camera}" if camera in ("file", "fly") else f"lighting={lighting}"
            raise ConfigError(f"render.{setting} ({where}) needs a scene file: set render.scene")
        return None
    path = Path(str(scene)).expanduser()
    if path.suffix.lower() not in SCENE_KINDS:
        raise ConfigError(f"render.scene ({where}): {path} is not a scene file wdss reads ({', '.join(SCENE_KINDS)})")
    if not path.is_file():
        raise FileNotFoundError(f"render.scene ({where}): {path} does not exist")
    for uri, resource in scene_resources(path, where=f"render.scene ({where})"):
        if not resource.is_file():
            raise FileNotFoundError(f"render.scene ({where}): {path} references {uri!r}, and {resource} does not exist")
    return path.resolve()


def _gltf_json(path: Path, where: str) -> dict[str, Any]:
    """The JSON of a ``.gltf``, or of a ``.glb``'s first chunk (read without the binary chunk)."""
    try:
        with open(path, "rb") as handle:
            if path.suffix.lower() == ".glb":
                magic, version, _, length, kind = struct.unpack("<4sIII4s", handle.read(20))
                if magic != b"glTF" or version != 2 or kind != b"JSON":
                    raise ValueError("not a glTF 2.0 binary (header)")
                text = handle.read(length)
            else:
                text = handle.read()
        gltf = json.loads(text.decode("utf-8-sig"))
    except (struct.error, UnicodeDecodeError, ValueError) as err:
        raise ConfigError(f"{where}: {path} could not be read: {err}") from err
    if not isinstance(gltf, dict):
        raise ConfigError(f"{where}: {path} could not be read: its JSON is not an object")
    return gltf


def scene_resources(path: Path, *, where: str = "render.scene") -> list[tuple[str, Path]]:
    """The external files a glTF (``.gltf``, or a ``.glb`` with external textures) references, as ``(uri,
    path)`` sorted by URI: the URIs of its buffers and images other than ``data:`` URIs, resolved as Blender's
    importer resolves them (unquoted, relative to the file's folder); none for a ``.blend``.

    A URI that leads outside the file's folder (``../``, an absolute path, a link out of it) is refused naming it,
    before Blender reads anything: a scene file is data, and would otherwise read (and render, and hash into the
    sidecar) any file its author names."""
    if SCENE_KINDS[path.suffix.lower()] != "gltf":
        return []
    gltf = _gltf_json(path, where)
    uris = set()
    for key in ("buffers", "images"):
        entries = gltf.get(key) or []
        for entry in entries if isinstance(entries, list) else []:
            uri = entry.get("uri") if isinstance(entry, dict) else None
            if isinstance(uri, str) and uri and not uri.startswith("data:"):
                uris.add(uri)
    folder = path.resolve().parent  # what Blender reads the URIs against (check_scene hands it the resolved path)
    found = []
    for uri in sorted(uris):
        relative = unquote(uri.replace("\\", "/"))
        resource = path.parent / os.path.normpath(relative)
        if os.path.isabs(relative) or not (folder / relative).resolve().is_relative_to(folder):
            raise ConfigError(
                f"{where}: {path} references {uri!r}, which lies outside the scene file's folder {folder}: refused "
                "(a glTF's buffers and images must lie in its folder or below)"
            )
        found.append((uri, resource))
    return found


def _sha256(path: Path) -> str:
    digest = hashlib.sha256()
    with open(path, "rb") as handle:
        for block in iter(lambda: handle.read(1 << 20), b""):
            digest.update(block)
    return digest.hexdigest()


def file_digest(path: Path) -> str:
    """SHA-256 of a scene (a resumed render refuses a changed one): of the file itself, or, for a glTF that
    references external buffers or images (:func:`scene_resources`), of a ``sha256sum``-style listing of the
    file and each of them (``<sha256>  <uri>`` lines), so a changed ``.bin`` or texture changes it too.

    A ``.blend``'s external images and libraries are not covered (pack them: File > External Data > Pack)."""
    resources = scene_resources(path)
    if not resources:
        return _sha256(path)
    lines = [f"{_sha256(path)}  {path.name}"]
    for uri, resource in resources:
        if not resource.is_file():
            raise FileNotFoundError(f"render.scene: {path} references {uri!r}, and {resource} does not exist")
        lines.append(f"{_sha256(resource)}  {uri}")
    return hashlib.sha256("\n".join(lines).encode()).hexdigest()


def _orthonormal(matrix: np.ndarray) -> np.ndarray:
    """A camera-to-world matrix without scale (Cycles ignores a camera's scale)."""
    out = np.array(matrix, dtype=np.float64)
    for i in range(3):
        out[:3, i] /= np.linalg.norm(out[:3, i])
    return out


class FileScene(CyclesScene):
    """A scene file in Blender, framed by its own or a fitted camera; renders like
    :class:`wdss.render.blender.BlenderScene`. ``poses`` (frames -1..frames+1), ``lens`` and ``description``
    (for the sidecar) are known once it is built."""

    def __init__(
        self,
        path: Path,
        *,
        seed: int,
        frames: int,
        resolution: tuple[int, int],
        camera: str = "auto",
        lighting: str = "auto",
        samples: int = 8,
        denoise: bool = True,
        filter_width: float = 0.01,
        threads: int = 0,
        where: str = "",
        digest: str | None = None,
    ):
        import bpy

        from wdss.render.materials import wire_aovs

        self.samples, self.denoise, self.filter_width = samples, denoise, filter_width
        self.kind = SCENE_KINDS[path.suffix.lower()]
        where = f"render.scene ({where}): {path}" if where else f"render.scene: {path}"
        self._load(path, where)
        scene = self.scene = bpy.context.scene
        layer = bpy.context.view_layer
        self._show_what_renders(layer)
        played = self._play_gltf_animations() if self.kind == "gltf" else None
        self.offset, self.last = self._animation_range()
        scene.frame_set(self.offset)
        geometry, bounds = self._geometry()
        if bounds is None:
            raise ConfigError(f"{where} has no mesh to render")
        lo, hi = bounds
        self._configure_render(layer, seed, threads)
        materials = wire_aovs(geometry, alpha_threshold=layer.pass_alpha_threshold)
        lights = self._light(lighting, seed)
        width, height = resolution
        scene.render.resolution_x, scene.render.resolution_y, scene.render.resolution_percentage = width, height, 100
        mode, camera_info = self._frame(camera, seed, frames, lo, hi, width, height, where)
        self.description = {
            "file": str(path),
            "kind": self.kind,
            "sha256": digest or file_digest(path),
            "resources": [uri for uri, _ in scene_resources(path)],
            "frame_offset": self.offset,
            **({"animations": played} if played is not None else {}),
            "bounds": [lo.round(6).tolist(), hi.round(6).tolist()],
            "camera": {"mode": mode, **camera_info},
            "lighting": lights,
            "material_fallbacks": materials,
        }

    # -- loading -------------------------------------------------------------------------------------------------
    def _load(self, path: Path, where: str) -> None:
        """Open the file in a factory-fresh Blender (its scripts never run); one Blender cannot read is an error
        naming it."""
        import bpy

        from wdss.render.blender import _quiet

        bpy.ops.wm.read_factory_settings(use_empty=True)
        bpy.context.preferences.filepaths.use_scripts_auto_execute = False
        try:
            with _quiet():
                if self.kind == "gltf":
                    bpy.ops.import_scene.gltf(filepath=str(path), loglevel=logging.WARNING)  # not a line per node
                else:
                    bpy.ops.wm.open_mainfile(filepath=str(path), load_ui=False, use_scripts=False)
        except RuntimeError as err:
            raise ConfigError(f"{where} could not be read: {str(err).strip()}") from err

    def _configure_render(self, layer: Any, seed: int, threads: int) -> None:
        """Cycles as wdss renders, on ``layer`` alone: no compositing, sequencer or border, square pixels, and
        radiance in scene units (the sequence's exposure is calibrated later)."""
        from wdss.render.blender import configure_cycles

        scene = self.scene
        for other in scene.view_layers:
            other.use = other == layer
        configure_cycles(scene, layer, seed=seed, threads=threads)
        render = scene.render
        render.use_compositing = render.use_sequencer = render.use_border = False
        render.pixel_aspect_x = render.pixel_aspect_y = 1.0
        scene.cycles.film_exposure = 1.0

    @staticmethod
    def _play_gltf_animations() -> dict[str, str]:
        """Let every animated object of a glTF play, each its first animation; which ones, by object.

        Blender's importer makes the file's first animation active and leaves the others as muted NLA tracks,
        but an exporter writes one animation per animated object (Blender's does), so a camera animated in
        the second one would stand still."""
        import bpy

        played = {}
        for obj in bpy.data.objects:
            data = obj.animation_data
            if data is None:
                continue
            if data.action is None:
                strips = [strip for track in data.nla_tracks for strip in track.strips if strip.action]
                if not strips:
                    continue
                data.action = strips[0].action
            played[obj.name] = data.action.name
        return played

    @staticmethod
    def _show_what_renders(layer) -> None:
        """Make the viewport show what renders: the depsgraph that finds the geometry (its bounds, the materials
        wired for AOVs) and that ray casts check camera paths against is the viewport's, so an object hidden in
        the viewport but rendered would be missed, and one hidden from renders would block the camera."""
        import bpy

        for collection in bpy.data.collections:
            if collection.library is None:
                collection.hide_viewport = collection.hide_render

        def unhide(layer_collection) -> None:  # the eye in the outliner, per view layer
            layer_collection.hide_viewport = False
            for child in layer_collection.children:
                unhide(child)

        unhide(layer.layer_collection)
        for obj in bpy.data.objects:
            if obj.library is not None:
                continue
            obj.hide_viewport = obj.hide_render
            for modifier in obj.modifiers:
                modifier.show_viewport = modifier.show_render
            if obj.name in layer.objects:
                obj.hide_set(False, view_layer=layer)

    def _animation_range(self) -> tuple[int, int]:
        """The file's first and last frames: the ``.blend`` scene's, or a glTF's first and last keyframes."""
        import bpy

        if self.kind == "blend":
            return int(self.scene.frame_start), int(self.scene.frame_end)
        ranges = [action.frame_range for action in bpy.data.actions]
        if not ranges:
            return 0, 0
        return int(np.floor(min(r[0] for r in ranges))), int(np.ceil(max(r[1] for r in ranges)))

    def _each_frame(self, frames: int):
        """Frames ``-1..frames+1`` of the sequence, each set in turn; back at frame 0 after the last."""
        try:
            for f in range(-1, frames + 2):
                self.scene.frame_set(self.offset + f)
                yield f
        finally:
            self.scene.frame_set(self.offset)

    @staticmethod
    def _geometry() -> tuple[list[Any], tuple[np.ndarray, np.ndarray] | None]:
        """The objects with geometry to render (instanced ones included, e.g. linked collections) and the world
        bounds of all their instances, None without any."""
        import bpy

        from wdss.render.materials import GEOMETRY_TYPES

        corners, objects = [], {}
        for instance in bpy.context.evaluated_depsgraph_get().object_instances:
            evaluated = instance.object
            if evaluated.type not in GEOMETRY_TYPES or evaluated.original.hide_render:
                continue
            if evaluated.type == "MESH" and not len(evaluated.data.polygons):
                continue
            local = np.array([list(c) for c in evaluated.bound_box], dtype=np.float64)
            matrix = np.array(instance.matrix_world, dtype=np.float64)
            corners.append(local @ matrix[:3, :3].T + matrix[:3, 3])
            objects[evaluated.original.name] = evaluated.original
        if not corners:
            return [], None
        points = np.concatenate(corners)
        return list(objects.values()), (points.min(0), points.max(0))

    def _light(self, lighting: str, seed: int) -> dict[str, Any]:
        import bpy

        from wdss.render.blender import add_hdri_and_sun
        from wdss.render.spec import HDRIS

        scene = self.scene
        lights = sorted(o.name for o in bpy.context.view_layer.objects if o.type == "LIGHT" and not o.hide_render)
        world = scene.world
        environment = bool(
            world and world.node_tree and any(n.type in ("TEX_ENVIRONMENT", "TEX_SKY") for n in world.node_tree.nodes)
        )
        mode = lighting if lighting != "auto" else ("file" if lights or environment else "hdri")
        info: dict[str, Any] = {"mode": mode, "file_lights": lights, "file_environment": environment}
        if mode == "hdri":
            rng = np.random.default_rng([seed, 9])
            added = {
                "hdri": str(rng.choice(HDRIS)),
                "strength": float(rng.uniform(0.5, 1.5)),
                "rotation": float(rng.uniform(0, 2 * np.pi)),
                "sun_rotation": [float(rng.uniform(0.3, 1.2)), 0.0, float(rng.uniform(0, 2 * np.pi))],
                "sun_energy": float(rng.uniform(1.5, 5.0)),
            }
            add_hdri_and_sun(scene, **added)
            info.update(added)
        elif not lights and not environment:
            log.warning("lighting=file but the scene has no light and no environment: only emitters light it")
        return info

    # -- camera --------------------------------------------------------------------------------------------------
    def _file_camera(self):
        scene = self.scene
        if scene.camera is not None and scene.camera.type == "CAMERA":
            return scene.camera
        cameras = sorted((o for o in scene.objects if o.type == "CAMERA"), key=lambda o: o.name)
        return cameras[0] if cameras else None

    def _evaluated_poses(self, obj, frames: int) -> dict[int, np.ndarray]:
        return {f: _orthonormal(np.array(obj.matrix_world)) for f in self._each_frame(frames)}

    def _frame(self, camera, seed, frames, lo, hi, width, height, where) -> tuple[str, dict[str, Any]]:
        import bpy
        from mathutils import Matrix

        from wdss.render.camera_path import EYE_HEIGHT, fit_camera

        scene = self.scene
        own = self._file_camera()
        wanted = own is not None and camera in ("auto", "file")
        file_poses = self._evaluated_poses(own, frames) if wanted else None
        moving = file_poses is not None and any(
            not np.allclose(p, file_poses[0], atol=1e-6) for p in file_poses.values()
        )
        mode = camera if camera != "auto" else ("file" if moving else "orbit")
        if mode == "file":
            if own is None:
                raise ConfigError(f"{where} has no camera (render.camera=file): use camera=orbit or camera=fly")
            self.lens = self._pinhole(own, frames, width, height, where)
            self.poses = file_poses
            scene.camera = own
            if self.offset + frames > self.last:
                log.warning(
                    "%s: frames %d..%d go beyond the file's animation (last frame %d): the camera holds still there",
                    where,
                    self.offset,
                    self.offset + frames,
                    self.last,
                )
            return mode, {"object": own.name, "moving": moving}
        data = bpy.data.cameras.new("wdss_camera")
        data.sensor_width, data.sensor_fit = 36.0, "AUTO"
        diagonal = float(np.linalg.norm(hi - lo))  # clip planes for the scene's scale (Blender: 0.1 to 100)
        data.clip_start, data.clip_end = min(0.1, 1e-3 * diagonal), max(100.0, 10.0 * diagonal)
        obj = bpy.data.objects.new("wdss_camera", data)
        scene.collection.objects.link(obj)
        scene.camera = obj
        try:
            path, poses, attempt = fit_camera(
                mode, seed, lo, hi, self._ray_caster(), frames, width / height, eye_height=EYE_HEIGHT / self._metres()
            )
        except ValueError as err:
            hint = "camera=fly walks through interiors" if mode == "orbit" else "camera=orbit circles the scene"
            raise ConfigError(f"{where}: render.camera={mode}: {err}; {hint}") from err
        data.lens = self.lens = path.lens
        for f, pose in poses.items():
            obj.matrix_world = Matrix(pose.tolist())
            obj.keyframe_insert("location", frame=self.offset + f)
            obj.keyframe_insert("rotation_euler", frame=self.offset + f)
        self.poses = self._evaluated_poses(obj, frames)
        return mode, {"object": None, "attempt": attempt, "path": path.to_dict()}

    def _metres(self) -> float:
        """Metres per scene unit: a ``.blend``'s unit scale (Scene > Units; e.g. 0.01 for a scene modelled in
        centimetres), 1 for a glTF (metres by its specification) or a scene without a unit system."""
        units = self.scene.unit_settings
        return float(units.scale_length) if units.system != "NONE" and units.scale_length > 0 else 1.0

    def _pinhole(self, obj, frames: int, width: int, height: int, where: str) -> float:
        """Make the file's camera a 36 mm-sensor pinhole with the same horizontal field of view at
        ``width x height``; its lens in mm. Refuses what one ``intrinsics`` entry cannot describe."""
        import bpy

        data = obj.data
        if data.type != "PERSP":
            raise ConfigError(f"{where}: camera {obj.name!r} is {data.type}; wdss renders perspective cameras")
        depsgraph = bpy.context.evaluated_depsgraph_get()
        focals = {
            round(obj.evaluated_get(depsgraph).calc_matrix_camera(depsgraph, x=width, y=height)[0][0] * width / 2, 4)
            for _ in self._each_frame(frames)
        }
        if len(focals) > 1:
            raise ConfigError(f"{where}: camera {obj.name!r} zooms (its focal length is animated); use camera=orbit")
        if data.shift_x or data.shift_y:
            log.warning("%s: camera %r has a lens shift; wdss renders it centred", where, obj.name)
        # A keyed or driven lens, sensor or shift (even one that holds still) would undo what is set below at
        # every frame change: the rendered view would no longer be the one ``intrinsics`` describes.
        data.animation_data_clear()
        data.shift_x = data.shift_y = 0.0
        data.dof.use_dof = False
        lens = focals.pop() * 36.0 / max(width, height)
        data.sensor_fit, data.sensor_width, data.lens = "AUTO", 36.0, lens
        return lens

    def _ray_caster(self):
        import bpy
        from mathutils import Vector

        scene, offset = self.scene, self.offset
        animated = bool(bpy.data.actions)
        state = {"frame": 0}

        def ray_cast(frame: int, origins: np.ndarray, directions: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
            if animated and frame != state["frame"]:
                scene.frame_set(offset + frame)
                state["frame"] = frame
            depsgraph = bpy.context.evaluated_depsgraph_get()
            distances = np.full(len(origins), np.inf)
            normals = np.zeros((len(origins), 3))
            for i, (origin, direction) in enumerate(zip(origins, directions, strict=True)):
                hit, location, normal, *_ = scene.ray_cast(depsgraph, Vector(origin), Vector(direction))
                if hit:
                    distances[i] = float(np.dot(np.array(location) - origin, direction))
                    normals[i] = normal
            return distances, normals

        return ray_cast

    # -- rendering -----------------------------------------------------------------------------------------------
    def set_frame(self, frame: int) -> None:
        self.scene.frame_set(self.offset + frame)
