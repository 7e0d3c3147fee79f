"""Build a :class:`~wdss.render.spec.SceneSpec` in Blender (``bpy``) and render frames with Cycles on the CPU.

Importing this module needs the ``render`` extra (``pip install 'wdss[render]'``, i.e. ``bpy==5.0.1``).
"""

from __future__ import annotations

import contextlib
import math
import os
import sys
import tempfile
from pathlib import Path

import numpy as np

from wdss.data.exr import read_exr
from wdss.render.cycles_scene import CyclesScene
from wdss.render.spec import Material, SceneSpec, camera_pose, object_pose

try:
    import bpy
except ImportError as err:  # pragma: no cover - exercised only without the extra
    raise ImportError(
        "rendering needs Blender's Python module: run `make setup-render` "
        "(or `pip install -c constraints.txt 'bpy==5.0.1'`)"
    ) from err

__all__ = ["AOVS", "BlenderScene", "add_hdri_and_sun", "configure_cycles", "render_passes"]

AOVS = (("basecolor", "COLOR"), ("roughness", "VALUE"), ("metallic", "VALUE"))


def _principled_material(name: str, spec: Material):
    """A Principled BSDF driven by a procedural texture, with base colour/roughness/metallic also sent to AOVs."""
    mat = bpy.data.materials.new(name)
    mat.use_nodes = True
    nt = mat.node_tree
    nt.nodes.clear()
    out = nt.nodes.new("ShaderNodeOutputMaterial")
    bsdf = nt.nodes.new("ShaderNodeBsdfPrincipled")
    nt.links.new(bsdf.outputs["BSDF"], out.inputs["Surface"])
    coords = nt.nodes.new("ShaderNodeTexCoord")
    base_color = _texture_color(nt, coords, spec)
    roughness = _roughness(nt, coords, spec)
    normal = _fine_bump(nt, coords, spec)
    nt.links.new(normal, bsdf.inputs["Normal"])
    nt.links.new(base_color, bsdf.inputs["Base Color"])
    nt.links.new(roughness, bsdf.inputs["Roughness"])
    bsdf.inputs["Metallic"].default_value = spec.metallic
    if spec.emission > 0:
        bsdf.inputs["Emission Color"].default_value = (*spec.emission_color, 1.0)
        bsdf.inputs["Emission Strength"].default_value = spec.emission
    for aov_name, source in (("basecolor", base_color), ("roughness", roughness), ("metallic", None)):
        aov = nt.nodes.new("ShaderNodeOutputAOV")
        aov.aov_name = aov_name
        if source is None:
            aov.inputs["Value"].default_value = spec.metallic
        else:
            nt.links.new(source, aov.inputs["Color" if aov_name == "basecolor" else "Value"])
    return mat


_TEXTURES = {
    "noise": "ShaderNodeTexNoise",
    "voronoi": "ShaderNodeTexVoronoi",
    "brick": "ShaderNodeTexBrick",
    "wave": "ShaderNodeTexWave",
    "checker": "ShaderNodeTexChecker",
}


def _texture_color(nt, coords, spec: Material):
    """The base colour: the material's procedural texture mapped onto its two colours (the ramp's output)."""
    texture = nt.nodes.new(_TEXTURES[spec.texture])
    texture.inputs["Scale"].default_value = spec.scale
    nt.links.new(coords.outputs["Object"], texture.inputs["Vector"])
    ramp = nt.nodes.new("ShaderNodeValToRGB")
    ramp.color_ramp.elements[0].color = (*spec.color_a, 1.0)
    ramp.color_ramp.elements[1].color = (*spec.color_b, 1.0)
    nt.links.new(texture.outputs["Distance" if spec.texture == "voronoi" else "Fac"], ramp.inputs["Fac"])
    return ramp.outputs["Color"]


def _roughness(nt, coords, spec: Material):
    """The roughness: a second noise mapped into the material's range."""
    rough_noise = nt.nodes.new("ShaderNodeTexNoise")
    rough_noise.inputs["Scale"].default_value = spec.scale * 0.7
    nt.links.new(coords.outputs["Object"], rough_noise.inputs["Vector"])
    rough_map = nt.nodes.new("ShaderNodeMapRange")
    rough_map.inputs["To Min"].default_value = spec.roughness[0]
    rough_map.inputs["To Max"].default_value = spec.roughness[1]
    nt.links.new(rough_noise.outputs["Fac"], rough_map.inputs["Value"])
    return rough_map.outputs["Result"]


def _fine_bump(nt, coords, spec: Material):
    """The normal of a fine bump: the high frequencies super-resolution has to recover."""
    detail = nt.nodes.new("ShaderNodeTexNoise")
    detail.inputs["Scale"].default_value = spec.scale * 6.0
    detail.inputs["Detail"].default_value = 8.0
    nt.links.new(coords.outputs["Object"], detail.inputs["Vector"])
    bump = nt.nodes.new("ShaderNodeBump")
    bump.inputs["Strength"].default_value = spec.bump
    bump.inputs["Distance"].default_value = 0.02
    nt.links.new(detail.outputs["Fac"], bump.inputs["Height"])
    return bump.outputs["Normal"]


_SHAPES = {
    "cube": lambda: bpy.ops.mesh.primitive_cube_add(size=1.6),
    "uv_sphere": lambda: bpy.ops.mesh.primitive_uv_sphere_add(radius=1.0, segments=48, ring_count=24),
    "ico_sphere": lambda: bpy.ops.mesh.primitive_ico_sphere_add(radius=1.0, subdivisions=2),
    "cylinder": lambda: bpy.ops.mesh.primitive_cylinder_add(radius=0.7, depth=1.8, vertices=48),
    "cone": lambda: bpy.ops.mesh.primitive_cone_add(radius1=0.9, depth=1.8, vertices=48),
    "torus": lambda: bpy.ops.mesh.primitive_torus_add(major_radius=0.9, minor_radius=0.3),
    "suzanne": lambda: bpy.ops.mesh.primitive_monkey_add(size=1.8),
    "rounded_cube": lambda: bpy.ops.mesh.primitive_cube_add(size=1.5),
}


class BlenderScene(CyclesScene):
    """One scene in Blender, rendered frame by frame with fixed settings."""

    def __init__(self, spec: SceneSpec, *, samples: int, denoise: bool, filter_width: float, threads: int = 0):
        self.spec = spec
        self.samples = samples
        self.denoise = denoise
        self.filter_width = filter_width
        bpy.ops.wm.read_factory_settings(use_empty=True)
        self.scene = bpy.context.scene
        configure_cycles(self.scene, self.scene.view_layers[0], seed=spec.seed, threads=threads)
        self.scene.cycles.max_bounces = 6
        self._world()
        self._objects()
        self._camera()

    def _world(self) -> None:
        spec = self.spec
        add_hdri_and_sun(
            self.scene,
            hdri=spec.hdri,
            strength=spec.hdri_strength,
            rotation=spec.hdri_rotation,
            sun_rotation=spec.sun_rotation,
            sun_energy=spec.sun_energy,
        )

    def _objects(self) -> None:
        spec = self.spec
        bpy.ops.mesh.primitive_plane_add(size=60.0)
        ground = bpy.context.object
        ground.data.materials.append(_principled_material("ground", spec.ground))
        self.things = []
        for index, thing in enumerate(spec.things):
            _SHAPES[thing.shape]()
            obj = bpy.context.object
            obj.scale = (thing.scale,) * 3
            if thing.shape in ("suzanne", "rounded_cube"):
                sub = obj.modifiers.new("subdivision", "SUBSURF")
                sub.levels = sub.render_levels = 2
            if thing.shape not in ("cube",):
                for polygon in obj.data.polygons:
                    polygon.use_smooth = True
            obj.data.materials.append(_principled_material(f"material_{index}", thing.material))
            self.things.append(obj)

    def _camera(self) -> None:
        data = bpy.data.cameras.new("camera")
        data.lens = self.spec.camera.lens
        data.sensor_width = 36.0
        data.sensor_fit = "AUTO"
        self.camera = bpy.data.objects.new("camera", data)
        self.scene.collection.objects.link(self.camera)
        self.scene.camera = self.camera

    def pose(self, frame: int) -> np.ndarray:
        """Key the camera and moving objects at ``frame`` (and its neighbours, for the Vector pass)."""
        from mathutils import Matrix

        for f in (frame - 1, frame, frame + 1):
            self.camera.matrix_world = Matrix(camera_pose(self.spec.camera, f).tolist())
            self.camera.keyframe_insert("location", frame=f)
            self.camera.keyframe_insert("rotation_euler", frame=f)
            for obj, thing in zip(self.things, self.spec.things, strict=True):
                location, rotation = object_pose(thing, f)
                obj.location, obj.rotation_euler = location, rotation
                obj.keyframe_insert("location", frame=f)
                obj.keyframe_insert("rotation_euler", frame=f)
        self.scene.frame_set(frame)
        return camera_pose(self.spec.camera, frame)

    def set_frame(self, frame: int) -> None:
        self.pose(frame)


def configure_cycles(scene, layer, *, seed: int, threads: int = 0) -> None:
    """Cycles on the CPU with fixed sampling, motion blur off (the Vector pass needs it), every pass wdss reads
    enabled on ``layer`` (AOVs included) and one-part multilayer float EXR output."""
    scene.render.engine = "CYCLES"
    cycles = scene.cycles
    cycles.device = "CPU"
    cycles.use_adaptive_sampling = False
    # The sample count is wdss's (samples, lr_samples): a .blend's view layer override, time limit or sample
    # subset would change it silently. One view, not a stereo pair.
    layer.samples = 0
    cycles.time_limit = 0.0
    cycles.use_sample_subset = False
    scene.render.use_multiview = False
    cycles.seed = seed
    cycles.use_animated_seed = True
    scene.render.use_motion_blur = False
    # Keep the synchronised scene (BVH, shaders, OIDN) between renders: a sequence renders each frame at several
    # resolutions, and without it every render paid the set-up again, most of a small LR render's time.
    # Geometry passes come out identical; the colour differs only as two renders of one seed always do (threads).
    scene.render.use_persistent_data = True
    if threads:
        scene.render.threads_mode = "FIXED"
        scene.render.threads = threads
    else:  # all cores, whatever a .blend fixed
        scene.render.threads_mode = "AUTO"
    scene.render.film_transparent = False
    # Emit: the emission of directly visible surfaces, the part of the colour that is not BRDF times irradiance.
    flags = (
        "use_pass_combined",
        "use_pass_z",
        "use_pass_normal",
        "use_pass_vector",
        "use_pass_position",
        "use_pass_emit",
    )
    for flag in flags:
        setattr(layer, flag, True)
    present = {aov.name: aov for aov in layer.aovs}
    for name, kind in AOVS:
        aov = present.get(name) or layer.aovs.add()
        aov.name, aov.type = name, kind  # a .blend's own AOV of the same name may be of the other type
    image = scene.render.image_settings
    image.media_type = "MULTI_LAYER_IMAGE"
    image.file_format = "OPEN_EXR_MULTILAYER"
    image.color_depth = "32"
    image.exr_codec = "ZIP"
    image.use_exr_interleave = True  # one-part EXR (Blender 5 writes multi-part files otherwise)


def add_hdri_and_sun(
    scene, *, hdri: str, strength: float, rotation: float, sun_rotation: list[float], sun_energy: float
) -> None:
    """A new world lit by one of the HDRIs shipped with Blender (``spec.HDRIS``), and a sun."""
    world = bpy.data.worlds.new("world")
    scene.world = world
    world.use_nodes = True
    nt = world.node_tree
    background = nt.nodes["Background"]
    env = nt.nodes.new("ShaderNodeTexEnvironment")
    path = os.path.join(bpy.utils.system_resource("DATAFILES"), "studiolights", "world", f"{hdri}.exr")
    env.image = bpy.data.images.load(path)
    mapping = nt.nodes.new("ShaderNodeMapping")
    mapping.inputs["Rotation"].default_value = (0.0, 0.0, rotation)
    coords = nt.nodes.new("ShaderNodeTexCoord")
    nt.links.new(coords.outputs["Generated"], mapping.inputs["Vector"])
    nt.links.new(mapping.outputs["Vector"], env.inputs["Vector"])
    nt.links.new(env.outputs["Color"], background.inputs["Color"])
    background.inputs["Strength"].default_value = strength
    sun = bpy.data.lights.new("sun", "SUN")
    sun.energy = sun_energy
    sun.angle = math.radians(1.5)
    sun_object = bpy.data.objects.new("sun", sun)
    sun_object.rotation_euler = sun_rotation
    scene.collection.objects.link(sun_object)


def render_passes(
    scene,
    width: int,
    height: int,
    *,
    samples: int,
    denoise: bool,
    filter_width: float,
    jitter: tuple[float, float] | None = None,
) -> dict[str, np.ndarray]:
    """Render the scene's current frame at ``width x height``; the passes as ``(C, H, W)`` float32 arrays.

    ``jitter``: ``(x, y)`` in pixels (x right, y down): pixel ``i`` is shaded at ``i + 0.5 + x`` instead of its
    centre, every pass alike, by a lens shift of the camera for this render (as an engine jitters its projection).
    """
    render = scene.render
    render.resolution_x, render.resolution_y = width, height
    render.resolution_percentage = 100
    cycles = scene.cycles
    cycles.samples = samples
    cycles.filter_width = filter_width
    cycles.use_denoising = denoise
    if denoise:
        cycles.denoiser = "OPENIMAGEDENOISE"
        cycles.denoising_input_passes = "RGB_ALBEDO_NORMAL"
        # The albedo and normal guides are noise-free here (every sample of a pixel hits its centre: filter_width
        # ~0, no depth of field or motion blur), so they need no prefilter; OIDN's prefilter would treat texture at
        # the pixel scale as noise and blur the guides, and the denoised colour with them (docs/results.md, "Data
        # conventions and what they change").
        cycles.denoising_prefilter = "NONE"
    camera = scene.camera.data
    shift = camera.shift_x, camera.shift_y
    if jitter is not None:
        # Blender's shift is in units of the larger image side; a positive shift_y moves the view up.
        side = max(width, height)
        camera.shift_x, camera.shift_y = shift[0] + jitter[0] / side, shift[1] - jitter[1] / side
    try:
        with tempfile.TemporaryDirectory() as tmp:
            render.filepath = str(Path(tmp) / "frame.exr")
            with _quiet():
                bpy.ops.render.render(write_still=True)
            planes = read_exr(render.filepath)
    finally:
        camera.shift_x, camera.shift_y = shift
    return _group_passes(planes)


@contextlib.contextmanager
def _quiet():
    """Silence Blender's per-tile log lines (written by C code to the process's stdout) during a render."""
    sys.stdout.flush()
    saved = os.dup(1)
    devnull = os.open(os.devnull, os.O_WRONLY)
    try:
        os.dup2(devnull, 1)
        yield
    finally:
        os.dup2(saved, 1)
        os.close(saved)
        os.close(devnull)


def _group_passes(planes: dict[str, np.ndarray]) -> dict[str, np.ndarray]:
    """``ViewLayer.Pass.Channel`` planes -> ``Pass`` arrays ``(C, H, W)`` (channel order R G B A / X Y Z W / V)."""
    order = {c: i for i, c in enumerate("RGBAXYZWV")}
    grouped: dict[str, list[tuple[str, np.ndarray]]] = {}
    for name, plane in planes.items():
        parts = name.split(".")
        pass_name, channel = (parts[-2], parts[-1]) if len(parts) >= 2 else (parts[0], "V")
        grouped.setdefault(pass_name, []).append((channel, plane))
    return {
        name: np.stack([p for _, p in sorted(chs, key=lambda cp: order.get(cp[0], 99))])
        for name, chs in grouped.items()
    }
