"""Rendering a scene file (slow): a small scene built with bpy and exported to .glb renders with the procedural
scenes' conventions, from its own animated camera and from a fitted orbit; bad files are refused up front."""

from __future__ import annotations

import logging
import math

import numpy as np
import pytest

from tests.render.conventions import check_conventions, load_sidecar, project
from wdss.data import Sequence

pytest.importorskip("bpy", reason="needs the render extra: make setup-render")
pytestmark = pytest.mark.slow

from wdss.render.sequence import render_sequence  # noqa: E402

SIZE = (48, 32)
SETTINGS = dict(frames=2, resolution=SIZE, scales=(2,), samples=2, denoise=False)
# The wall's 2x2 texture (8-bit sRGB), by (row from the bottom, column): v < 0.5 is the lower row.
BLOCKS = {(0, 0): (200, 40, 30), (0, 1): (30, 160, 60), (1, 0): (40, 60, 200), (1, 1): (220, 200, 40)}
TILT = math.radians(30)  # the ground's normal map tilts every normal by this angle towards +u (world +x)
CAMERA = [(-0.5 + 0.3 * f, -6.0, 1.5) for f in range(4)]  # the file camera's keyed positions, frames 0..3
LAMP = (1.8, 0.0, 0.4)  # centre of the emissive sphere (radius 0.4) at frame 0; it moves by DRIFT per frame
DRIFT = np.array([-0.1, 0.0, 0.0])


def near_lamp(frame: int, world: np.ndarray) -> np.ndarray:
    """The moving emitter and a margin around its silhouette (whose pixels reproject as static ones do not)."""
    return np.linalg.norm(world - (LAMP + frame * DRIFT), axis=-1) < 0.6


def srgb_to_linear(c: np.ndarray) -> np.ndarray:
    return np.where(c <= 0.04045, c / 12.92, ((c + 0.055) / 1.055) ** 2.4)


def _image(bpy, name: str, folder, texels: dict[tuple[int, int], tuple[int, int, int]], size: int, data: bool):
    image = bpy.data.images.new(name, size, size, alpha=False)
    pixels = []
    for row in range(size):  # Blender's pixel rows go bottom-up, as v does
        for col in range(size):
            pixels += [c / 255.0 for c in texels[(row * 2 // size, col * 2 // size)]] + [1.0]
    image.pixels = pixels
    image.filepath_raw = str(folder / f"{name}.png")
    image.file_format = "PNG"
    image.save()
    if data:
        image.colorspace_settings.name = "Non-Color"
    return image


def build_scene(folder, *, camera: bool = True, meshes: bool = True, light: bool = True, custom_material: bool = False):
    """The test scene in a fresh Blender: a textured wall, a normal-mapped ground, an emissive sphere, a point
    light and a camera keyed on frames 0..3. ``custom_material`` adds a box whose material is a node group."""
    import bpy
    from mathutils import Vector

    bpy.ops.wm.read_factory_settings(use_empty=True)
    scene = bpy.context.scene

    def principled(name: str):
        material = bpy.data.materials.new(name)
        return material, material.node_tree, material.node_tree.nodes["Principled BSDF"]

    if meshes:
        wall, nt, bsdf = principled("wall")
        texture = nt.nodes.new("ShaderNodeTexImage")
        texture.image = _image(bpy, "blocks", folder, BLOCKS, 2, data=False)
        texture.interpolation = "Closest"
        nt.links.new(texture.outputs["Color"], bsdf.inputs["Base Color"])
        bsdf.inputs["Roughness"].default_value = 0.4
        bpy.ops.mesh.primitive_plane_add(size=2.0, location=(0.0, 1.0, 1.0), rotation=(math.pi / 2, 0.0, 0.0))
        bpy.context.object.data.materials.append(wall)

        ground, nt, bsdf = principled("ground")
        tilted = tuple(round(255 * (0.5 + 0.5 * c)) for c in (math.sin(TILT), 0.0, math.cos(TILT)))
        normal_texture = nt.nodes.new("ShaderNodeTexImage")
        normal_texture.image = _image(bpy, "tilt", folder, dict.fromkeys(BLOCKS, tilted), 4, data=True)
        normal_map = nt.nodes.new("ShaderNodeNormalMap")
        nt.links.new(normal_texture.outputs["Color"], normal_map.inputs["Color"])
        nt.links.new(normal_map.outputs["Normal"], bsdf.inputs["Normal"])
        bsdf.inputs["Base Color"].default_value = (0.5, 0.5, 0.5, 1.0)
        bsdf.inputs["Roughness"].default_value = 0.6
        bpy.ops.mesh.primitive_plane_add(size=8.0)
        bpy.context.object.data.materials.append(ground)

        lamp, _, bsdf = principled("lamp")
        bsdf.inputs["Base Color"].default_value = (1.0, 0.5, 0.1, 1.0)
        bsdf.inputs["Emission Color"].default_value = (1.0, 0.5, 0.1, 1.0)
        bsdf.inputs["Emission Strength"].default_value = 5.0
        bpy.ops.mesh.primitive_uv_sphere_add(radius=0.4, location=LAMP)
        bpy.context.object.data.materials.append(lamp)
        for frame in range(4):  # the file's own object animation
            bpy.context.object.location = np.asarray(LAMP) + frame * DRIFT
            bpy.context.object.keyframe_insert("location", frame=frame)

    if custom_material:
        group = bpy.data.node_groups.new("toon", "ShaderNodeTree")
        group.interface.new_socket("Shader", in_out="OUTPUT", socket_type="NodeSocketShader")
        diffuse = group.nodes.new("ShaderNodeBsdfDiffuse")
        output = group.nodes.new("NodeGroupOutput")
        group.links.new(diffuse.outputs["BSDF"], output.inputs[0])
        toon = bpy.data.materials.new("toon")
        toon.diffuse_color = (0.2, 0.3, 0.4, 1.0)
        toon.roughness, toon.metallic = 0.25, 0.5
        nt = toon.node_tree
        nt.nodes.remove(nt.nodes["Principled BSDF"])
        node = nt.nodes.new("ShaderNodeGroup")
        node.node_tree = group
        nt.links.new(node.outputs[0], nt.nodes["Material Output"].inputs["Surface"])
        bpy.ops.mesh.primitive_cube_add(size=0.6, location=(-1.8, 0.0, 0.3))
        bpy.context.object.name = "box"
        bpy.context.object.data.materials.append(toon)

    if light:
        bulb = bpy.data.objects.new("bulb", bpy.data.lights.new("bulb", "POINT"))
        bulb.data.energy = 500.0
        bulb.location = (-1.0, -2.0, 3.0)
        scene.collection.objects.link(bulb)
    if camera:
        data = bpy.data.cameras.new("camera")
        data.lens = 35.0
        obj = bpy.data.objects.new("camera", data)
        scene.collection.objects.link(obj)
        scene.camera = obj
        for frame, location in enumerate(CAMERA):
            obj.location = location
            obj.rotation_euler = (Vector((0.0, 0.0, 0.8)) - Vector(location)).to_track_quat("-Z", "Y").to_euler()
            obj.keyframe_insert("location", frame=frame)
            obj.keyframe_insert("rotation_euler", frame=frame)
    return bpy


def export_glb(folder, name: str = "scene.glb", **kwargs):
    bpy = build_scene(folder, **kwargs)
    path = folder / name
    bpy.ops.export_scene.gltf(filepath=str(path), export_format="GLB", export_cameras=True, export_lights=True)
    return path


@pytest.fixture(scope="module")
def glb(tmp_path_factory):
    return export_glb(tmp_path_factory.mktemp("scene"))


def test_a_glb_renders_from_its_animated_camera_with_the_conventions(glb, tmp_path):
    folder = render_sequence(tmp_path, "file", 1, scene=str(glb), **SETTINGS)
    assert Sequence(folder).frames == [0, 1, 2] and Sequence(folder).resolutions == [32, 16]
    frames = check_conventions(folder, moving=near_lamp)
    meta, cameras = load_sidecar(folder)
    scene = meta["scene"]
    assert scene["camera"] == {"mode": "file", "object": "camera", "moving": True}
    assert scene["lighting"]["mode"] == "file" and scene["lighting"]["file_lights"] == ["bulb"]
    assert scene["material_fallbacks"] == [] and meta["settings"]["scene"]["file"] == "scene.glb"
    assert scene["animations"] == {"camera": "cameraAction", "Sphere": "SphereAction"}  # two glTF animations
    for frame in (0, 1, 2):  # frame 0 is the file's first keyed frame
        np.testing.assert_allclose(cameras[frame][:3, 3], CAMERA[frame], atol=1e-4)
    blocks = normals = lamp = 0
    intrinsics = meta["intrinsics"]["fx_fy_cx_cy"]
    for frame, buffers in frames.items():
        world, surface, base = buffers["world"], buffers["surface"], buffers["base_color"]
        # The wall (y = 1): base colour is its texture's texel, linear; u = (x + 1) / 2, v = z / 2. (Away from
        # texel borders and the wall's own edges, where a pixel's samples may straddle two surfaces.)
        u, v = (world[..., 0] + 1) / 2, world[..., 2] / 2
        inner = [(np.abs(t - 0.5) > 0.05) & (t > 0.05) & (t < 0.95) for t in (u, v)]
        wall = surface & (np.abs(world[..., 1] - 1.0) < 0.01) & inner[0] & inner[1]
        for (row, col), srgb in BLOCKS.items():
            texel = wall & ((v >= 0.5) == bool(row)) & ((u >= 0.5) == bool(col))
            expected = srgb_to_linear(np.array(srgb) / 255.0)
            np.testing.assert_allclose(base[:, texel].T, np.broadcast_to(expected, (texel.sum(), 3)), atol=2e-3)
            blocks += texel.sum() > 0
        # The ground (z = 0): shading normals tilted by the normal map, not the plane's +z.
        ground = surface & (np.abs(world[..., 2]) < 0.01)
        expected = [math.sin(TILT), 0.0, math.cos(TILT)]
        np.testing.assert_allclose(np.median(buffers["normal"][:, ground], axis=1), expected, atol=0.03)
        normals += ground.sum()
        # The emissive sphere outshines the lit ground, and moves as the file animates it: its points were
        # DRIFT back in the previous frame.
        sphere = surface & (np.abs(np.linalg.norm(world - (LAMP + frame * DRIFT), axis=-1) - 0.4) < 0.02)
        luminance = buffers["color"].astype(np.float64).mean(0)
        assert np.median(luminance[sphere]) > 3 * np.median(luminance[ground])
        current = project(world[sphere], cameras[frame], intrinsics)
        previous = project(world[sphere] - DRIFT, cameras[frame - 1], intrinsics)
        assert np.median(np.hypot(*(buffers["motion"][:, sphere] - (current - previous)))) < 0.05
        lamp += sphere.sum()
    assert blocks == 8 and normals > 200 and lamp > 10


def test_a_glb_renders_from_a_fitted_orbit(glb, tmp_path):
    folder = render_sequence(tmp_path, "orbit", 2, scene=str(glb), camera="orbit", **SETTINGS)
    frames = check_conventions(folder, moving=near_lamp)
    meta, cameras = load_sidecar(folder)
    camera, bounds = meta["scene"]["camera"], np.array(meta["scene"]["bounds"])
    assert camera["mode"] == "orbit" and camera["path"]["mode"] == "orbit"
    centre, extent = bounds.mean(0), 0.5 * np.hypot(*(bounds[1] - bounds[0])[:2])
    for frame, pose in cameras.items():  # outside the scene, looking at it
        assert np.hypot(*(pose[:3, 3] - centre)[:2]) > extent, frame
    for buffers in frames.values():
        assert buffers["surface"].mean() > 0.3
    # Seeded: the same seed fits the same path.
    again = render_sequence(tmp_path, "again", 2, scene=str(glb), camera="orbit", **{**SETTINGS, "frames": 1})
    assert load_sidecar(again)[0]["scene"]["camera"] == camera


def test_a_file_scene_resumes_and_refuses_a_changed_file(glb, tmp_path):
    copy = tmp_path / "copy.glb"
    copy.write_bytes(glb.read_bytes())
    folder = render_sequence(tmp_path, "seq", 2, scene=str(copy), camera="orbit", **SETTINGS)
    files = sorted(folder.rglob("*.exr"))
    stamps = {p: p.stat().st_mtime_ns for p in files}
    victim = folder / "16P" / "NormalSpecular.0001.exr"  # as if the render died while writing frame 1
    victim.unlink()
    render_sequence(tmp_path, "seq", 2, scene=str(copy), camera="orbit", **SETTINGS)
    changed = {p for p in files if p.stat().st_mtime_ns != stamps[p]}
    assert victim.exists() and changed and all(".0001." in p.name for p in changed)
    copy.write_bytes(glb.read_bytes() + b"\0" * 4)  # another scene under the same name
    with pytest.raises(ValueError, match="rendered with other settings"):
        render_sequence(tmp_path, "seq", 2, scene=str(copy), camera="orbit", **SETTINGS)


def test_a_file_without_a_mesh_or_camera_is_refused_before_anything_is_written(tmp_path):
    empty = export_glb(tmp_path, "lights.glb", meshes=False)
    with pytest.raises(ValueError, match=r"render\.scene \(sequence 'a'\): .*lights\.glb has no mesh"):
        render_sequence(tmp_path / "out", "a", 0, scene=str(empty), **SETTINGS)
    still = export_glb(tmp_path, "still.glb", camera=False)
    with pytest.raises(ValueError, match=r"still\.glb has no camera \(render\.camera=file\)"):
        render_sequence(tmp_path / "out", "b", 0, scene=str(still), camera="file", **SETTINGS)
    broken = tmp_path / "broken.glb"
    broken.write_bytes(b"glTF" + bytes(20))
    with pytest.raises(ValueError, match=r"render\.scene \(sequence 'c'\): .*broken\.glb could not be read"):
        render_sequence(tmp_path / "out", "c", 0, scene=str(broken), **SETTINGS)
    assert not (tmp_path / "out").exists()


def test_a_blend_file_names_the_materials_it_cannot_read_and_records_their_fallbacks(tmp_path, caplog):
    from wdss.render.scene_file import FileScene

    bpy = build_scene(tmp_path, custom_material=True)
    path = tmp_path / "scene.blend"
    bpy.ops.wm.save_as_mainfile(filepath=str(path))
    with caplog.at_level(logging.WARNING):
        scene = FileScene(path, seed=0, frames=2, resolution=SIZE, where="sequence 'a'")
    assert scene.description["camera"]["mode"] == "file"  # auto: the file's camera moves
    [fallback] = scene.description["material_fallbacks"]
    assert fallback["material"] == "toon" and fallback["objects"] == ["box"]
    assert "node group 'toon'" in fallback["reason"]
    assert fallback["base_color"] == pytest.approx([0.2, 0.3, 0.4]) and fallback["roughness"] == pytest.approx(0.25)
    assert any("'toon'" in r.message and "box" in r.message for r in caplog.records if r.levelno == logging.WARNING)
    aovs = {n.aov_name: n for n in bpy.data.materials["toon"].node_tree.nodes if n.type == "OUTPUT_AOV"}
    assert tuple(aovs["basecolor"].inputs["Color"].default_value)[:3] == pytest.approx((0.2, 0.3, 0.4))
    assert aovs["metallic"].inputs["Value"].default_value == pytest.approx(0.5)


def test_a_file_without_lights_gets_an_hdri_and_a_sun(tmp_path):
    import bpy

    from wdss.render.scene_file import FileScene
    from wdss.render.spec import HDRIS

    path = export_glb(tmp_path, "dark.glb", light=False)
    lighting = FileScene(path, seed=5, frames=2, resolution=SIZE).description["lighting"]
    assert lighting["mode"] == "hdri" and lighting["hdri"] in HDRIS and lighting["file_lights"] == []
    assert [o.name for o in bpy.context.scene.objects if o.type == "LIGHT"] == ["sun"]
    again = FileScene(path, seed=5, frames=2, resolution=SIZE).description["lighting"]
    assert again == lighting  # seeded
    lit = export_glb(tmp_path, "lit.glb")
    added = FileScene(lit, seed=5, frames=2, resolution=SIZE, lighting="hdri").description["lighting"]
    assert added["mode"] == "hdri" and added["file_lights"] == ["bulb"]  # beside the file's own light


@pytest.mark.parametrize("cutout", ["principled_alpha", "mix_transparent"])
def test_g_buffers_see_through_the_cut_out_parts_of_a_material(cutout):
    """Foliage and fences: where a surface is see-through, depth, normals and AOVs all come from behind it."""
    import bpy

    from wdss.render.blender import configure_cycles, render_passes
    from wdss.render.materials import wire_aovs

    bpy.ops.wm.read_factory_settings(use_empty=True)
    scene = bpy.context.scene
    configure_cycles(scene, scene.view_layers[0], seed=0)

    def plane(z: float, color: tuple[float, float, float]):
        bpy.ops.mesh.primitive_plane_add(size=10.0, location=(0.0, 0.0, z))
        material = bpy.data.materials.new(f"plane_{z}")
        bpy.context.object.data.materials.append(material)
        nt = material.node_tree
        bsdf = nt.nodes["Principled BSDF"]
        bsdf.inputs["Base Color"].default_value = (*color, 1.0)
        return nt, bsdf

    plane(0.0, (0.2, 0.8, 0.2))
    nt, bsdf = plane(1.0, (0.9, 0.1, 0.1))  # a leaf covering the view, see-through on the left half
    coords, separate = nt.nodes.new("ShaderNodeTexCoord"), nt.nodes.new("ShaderNodeSeparateXYZ")
    step = nt.nodes.new("ShaderNodeMath")
    step.operation = "GREATER_THAN"
    nt.links.new(coords.outputs["Object"], separate.inputs[0])
    nt.links.new(separate.outputs["X"], step.inputs[0])
    step.inputs[1].default_value = 0.0
    if cutout == "principled_alpha":
        nt.links.new(step.outputs[0], bsdf.inputs["Alpha"])
    else:
        mix, transparent = nt.nodes.new("ShaderNodeMixShader"), nt.nodes.new("ShaderNodeBsdfTransparent")
        nt.links.new(step.outputs[0], mix.inputs[0])
        nt.links.new(transparent.outputs[0], mix.inputs[1])
        nt.links.new(bsdf.outputs[0], mix.inputs[2])
        nt.links.new(mix.outputs[0], nt.nodes["Material Output"].inputs["Surface"])
    assert wire_aovs(scene.objects) == []
    camera = bpy.data.objects.new("camera", bpy.data.cameras.new("camera"))
    scene.collection.objects.link(camera)
    scene.camera, camera.location = camera, (0.0, 0.0, 5.0)
    passes = render_passes(scene, 16, 8, samples=2, denoise=False, filter_width=0.01)
    depth, base = passes["Depth"][0], passes["basecolor"][:3]
    left, right = np.s_[:, :7], np.s_[:, 9:]  # away from the cut at x = 0
    np.testing.assert_allclose(depth[left], 5.0, atol=1e-4)  # the ground, through the leaf
    np.testing.assert_allclose(depth[right], 4.0, atol=1e-4)  # the leaf
    np.testing.assert_allclose(base[(slice(None), *left)].reshape(3, -1).T, [[0.2, 0.8, 0.2]] * 56, atol=1e-4)
    np.testing.assert_allclose(base[(slice(None), *right)].reshape(3, -1).T, [[0.9, 0.1, 0.1]] * 56, atol=1e-4)


@pytest.mark.parametrize("unit", [1.0, 0.01], ids=["metres", "centimetres"])
def test_a_fly_through_stays_inside_a_room_at_eye_height(tmp_path, unit):
    """Blender's ray casts find the floor, the head room and the walls of a closed room (planes facing in); a
    room modelled in centimetres (unit scale 0.01) is walked at the same eye height in metres."""
    import bpy

    from wdss.render.camera_path import EYE_HEIGHT
    from wdss.render.scene_file import FileScene

    bpy.ops.wm.read_factory_settings(use_empty=True)
    bpy.context.scene.unit_settings.scale_length = unit
    k = 1.0 / unit  # scene units per metre
    for location, rotation in (
        ((0, 0, 0), (0, 0, 0)),  # floor
        ((0, 0, 3), (math.pi, 0, 0)),  # ceiling
        ((0, 4, 1.5), (math.pi / 2, 0, 0)),
        ((0, -4, 1.5), (-math.pi / 2, 0, 0)),
        ((4, 0, 1.5), (0, -math.pi / 2, 0)),
        ((-4, 0, 1.5), (0, math.pi / 2, 0)),
    ):
        bpy.ops.mesh.primitive_plane_add(size=8.0 * k, location=[k * c for c in location], rotation=rotation)
    bpy.ops.mesh.primitive_cube_add(size=1.0 * k, location=(0.0, 0.0, 0.5 * k))  # a crate in the middle
    bpy.ops.wm.save_as_mainfile(filepath=str(tmp_path / "room.blend"))
    scene = FileScene(tmp_path / "room.blend", seed=3, frames=30, resolution=SIZE, camera="fly", lighting="file")
    assert scene.description["camera"]["mode"] == "fly"
    eyes = np.array([pose[:3, 3] for pose in scene.poses.values()]) / k
    assert np.all(np.abs(eyes[:, :2]) < 4.0 - 0.2)
    assert not np.any(np.all(np.abs(eyes[:, :2]) < 0.5 + 0.2, axis=1))  # not through the crate
    np.testing.assert_allclose(eyes[:, 2], EYE_HEIGHT, atol=0.05)
    assert np.linalg.norm(eyes[-1] - eyes[0]) > 0.5


def test_a_file_cameras_own_sensor_and_keyed_lens_render_as_the_recorded_intrinsics(tmp_path):
    """A camera with a 24x20 mm sensor fitted vertically, its lens and shift keyed (holding still): every frame
    renders with the focal length the sidecar's intrinsics give, not the file's."""
    from wdss.render.scene_file import FileScene
    from wdss.render.spec import intrinsics

    bpy = build_scene(tmp_path)
    data = bpy.context.scene.camera.data
    data.sensor_fit, data.sensor_width, data.sensor_height = "VERTICAL", 24.0, 20.0
    for frame in range(4):
        data.lens, data.shift_x = 50.0, 0.1
        data.keyframe_insert("lens", frame=frame)
        data.keyframe_insert("shift_x", frame=frame)
    path = tmp_path / "zoom.blend"
    bpy.ops.wm.save_as_mainfile(filepath=str(path))
    scene = FileScene(path, seed=0, frames=2, resolution=SIZE, camera="file")
    fx = intrinsics(scene.lens, *SIZE)[0]
    assert fx == pytest.approx(50.0 / 20.0 * SIZE[1])  # the file camera's field of view, kept
    for frame in range(3):
        scene.scene.frame_set(scene.offset + frame)
        camera = scene.scene.camera
        depsgraph = bpy.context.evaluated_depsgraph_get()
        projection = camera.evaluated_get(depsgraph).calc_matrix_camera(depsgraph, x=SIZE[0], y=SIZE[1])
        assert projection[0][0] * SIZE[0] / 2 == pytest.approx(fx, rel=1e-5), frame
        assert projection[0][2] == pytest.approx(0.0, abs=1e-6) and camera.data.shift_x == 0.0, frame
    # A zoom is refused, naming the camera: one intrinsics entry describes every frame.
    bpy = build_scene(tmp_path)
    data = bpy.context.scene.camera.data
    for frame, lens in ((0, 35.0), (3, 50.0)):
        data.lens = lens
        data.keyframe_insert("lens", frame=frame)
    bpy.ops.wm.save_as_mainfile(filepath=str(path))
    with pytest.raises(ValueError, match=r"zoom\.blend: camera 'camera' zooms"):
        FileScene(path, seed=0, frames=2, resolution=SIZE, camera="file")


def test_objects_hidden_in_the_viewport_but_rendered_are_framed_and_wired(tmp_path):
    """Bounds, AOV wiring and ray casts see what renders: not what the viewport happens to show."""
    import bpy

    from wdss.render.scene_file import FileScene

    bpy.ops.wm.read_factory_settings(use_empty=True)
    bpy.ops.mesh.primitive_plane_add(size=4.0)
    bpy.ops.mesh.primitive_cube_add(size=1.0, location=(6.0, 0.0, 0.5))
    crate = bpy.context.object
    crate.name, crate.hide_viewport = "crate", True  # the monitor icon: hidden in viewports, rendered
    crate.data.materials.append(bpy.data.materials.new("crate"))
    bpy.ops.mesh.primitive_cube_add(size=1.0, location=(0.0, 0.0, 9.0))
    bpy.context.object.name, bpy.context.object.hide_render = "helper", True  # shown, never rendered
    path = tmp_path / "hidden.blend"
    bpy.ops.wm.save_as_mainfile(filepath=str(path))
    scene = FileScene(path, seed=0, frames=2, resolution=SIZE, camera="orbit", lighting="file")
    np.testing.assert_allclose(scene.description["bounds"], [[-2.0, -2.0, 0.0], [6.5, 2.0, 1.0]], atol=1e-5)
    nodes = bpy.data.materials["crate"].node_tree.nodes
    assert {n.aov_name for n in nodes if n.type == "OUTPUT_AOV"} == {"basecolor", "roughness", "metallic"}
    ray_cast = scene._ray_caster()
    distances, _ = ray_cast(0, np.array([[6.0, -5.0, 0.5], [0.0, 0.0, 5.0]]), np.array([[0, 1.0, 0], [0, 0, 1.0]]))
    assert distances[0] == pytest.approx(4.5) and np.isinf(distances[1])


def test_a_blend_files_own_render_settings_do_not_override_wdss_s(tmp_path):
    import bpy

    from wdss.render.scene_file import FileScene

    build_scene(tmp_path)
    scene = bpy.context.scene
    scene.view_layers[0].samples = 512  # a view layer's sample override
    scene.cycles.time_limit, scene.cycles.use_sample_subset = 0.5, True
    scene.render.use_multiview = True
    scene.render.threads_mode, scene.render.threads = "FIXED", 1
    aov = scene.view_layers[0].aovs.add()
    aov.name, aov.type = "basecolor", "VALUE"  # one channel where wdss reads three
    path = tmp_path / "samples.blend"
    bpy.ops.wm.save_as_mainfile(filepath=str(path))
    loaded = FileScene(path, seed=0, frames=2, resolution=SIZE, samples=3).scene
    layer = loaded.view_layers[0]
    assert layer.samples == 0 and loaded.cycles.time_limit == 0.0
    assert not loaded.cycles.use_sample_subset and not loaded.render.use_multiview
    assert loaded.render.threads_mode == "AUTO"  # threads=0: all cores
    assert [(a.name, a.type) for a in layer.aovs] == [
        ("basecolor", "COLOR"),
        ("roughness", "VALUE"),
        ("metallic", "VALUE"),
    ]


def test_a_blend_files_scripts_and_python_drivers_never_run(tmp_path):
    """A scene file is data: a registered text block (run on load when scripts are trusted) and a Python driver
    expression would each leave a file behind."""
    import bpy

    from wdss.render.scene_file import FileScene

    build_scene(tmp_path)
    marker_text, marker_driver = tmp_path / "text_ran", tmp_path / "driver_ran"
    text = bpy.data.texts.new("evil.py")
    text.write(f"import pathlib\npathlib.Path({str(marker_text)!r}).touch()\n")
    text.use_module = True
    driver = bpy.data.objects["Sphere"].driver_add("scale", 0).driver
    driver.type = "SCRIPTED"
    driver.expression = f"__import__('pathlib').Path({str(marker_driver)!r}).touch() or 1.0"
    path = tmp_path / "evil.blend"
    bpy.ops.wm.save_as_mainfile(filepath=str(path))
    assert not marker_text.exists() and not marker_driver.exists()
    scene = FileScene(path, seed=0, frames=2, resolution=SIZE, lighting="file")
    scene.scene.frame_set(scene.offset + 1)
    assert not marker_text.exists() and not marker_driver.exists()
