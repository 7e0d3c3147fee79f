"""G-buffer AOVs of materials wdss did not build (glTF and ``.blend`` scenes), with documented fallbacks.

Cycles has no base-colour, roughness or metallic pass of its own, so every surface sends them to the shader
AOVs ``basecolor``, ``roughness`` and ``metallic`` (:data:`wdss.render.blender.AOVS`). For an imported material
the sources are found by walking back from its active Material Output's Surface input:

* a Principled BSDF: whatever feeds its Base Color, Roughness and Metallic inputs (a texture's output, or the
  input's own value); image textures, normal maps and emission stay as the file made them;
* a Mix Shader: the two branches' sources mixed by the shader's own factor (one branch when only one resolves,
  e.g. a Transparent BSDF mixed with a Principled one);
* cut-outs (a Principled BSDF's Alpha, or a Transparent BSDF in a Mix Shader): where alpha is under the view
  layer's pass alpha threshold the AOVs write nothing, as depth and normals then come from the surface behind;
* an Add Shader: its first branch that resolves; a Reroute: what feeds it.

Anything else (a custom node group, a Diffuse or Emission shader alone, a material without nodes) is *not
read*: its AOVs get the material's viewport display settings (Material > Viewport Display: colour, roughness,
metallic), a warning names the material and the objects that use it, and :func:`wire_aovs` returns a record of
it for the sidecar. Mesh objects without a material get :data:`DEFAULT_MATERIAL`, a grey Principled BSDF close
to Cycles' own default surface, recorded the same way.
"""

from __future__ import annotations

import logging
from collections.abc import Iterable
from typing import Any

import bpy

__all__ = ["DEFAULT_MATERIAL", "GEOMETRY_TYPES", "wire_aovs"]

log = logging.getLogger(__name__)

DEFAULT_MATERIAL = {"base_color": [0.8, 0.8, 0.8], "roughness": 0.5, "metallic": 0.0}
GEOMETRY_TYPES = ("MESH", "CURVE", "SURFACE", "META", "FONT", "CURVES", "POINTCLOUD")
_CHANNELS = (
    ("basecolor", "Base Color", "Color"),
    ("roughness", "Roughness", "Value"),
    ("metallic", "Metallic", "Value"),
)

# A source is an output socket, or a constant (an RGBA tuple or a float).
Source = Any


def _input(socket) -> Source:
    """What feeds an input socket: the linked output socket, else its own value."""
    if socket.is_linked and socket.links[0].is_valid and not socket.links[0].is_muted:
        return socket.links[0].from_socket
    value = socket.default_value
    return tuple(value) if hasattr(value, "__len__") else float(value)


def _linked_type(socket) -> str | None:
    return socket.links[0].from_node.type if socket.is_linked and socket.links[0].is_valid else None


def _sources(nt, socket, threshold: float, depth: int = 0) -> dict[str, Source] | None:
    """The sources of each AOV behind shader input ``socket``, or None when no Principled BSDF is reachable."""
    if not socket.is_linked or depth > 32:
        return None
    link = socket.links[0]
    if not link.is_valid or link.is_muted:
        return None
    node = link.from_node
    if node.mute:
        return None
    if node.type == "REROUTE":
        return _sources(nt, node.inputs[0], threshold, depth + 1)
    if node.type == "BSDF_PRINCIPLED":
        out = {aov: _input(node.inputs[name]) for aov, name, _ in _CHANNELS}
        alpha = _input(node.inputs["Alpha"])
        return out if isinstance(alpha, float) and alpha >= 1.0 else _gate(nt, out, alpha, threshold)
    if node.type == "ADD_SHADER":
        for branch in (node.inputs[0], node.inputs[1]):
            found = _sources(nt, branch, threshold, depth + 1)
            if found is not None:
                return found
        return None
    if node.type == "MIX_SHADER":
        return _mix_shader_sources(nt, node, threshold, depth)
    return None


def _mix_shader_sources(nt, node, threshold: float, depth: int) -> dict[str, Source] | None:
    """The sources behind a Mix Shader ``node``: its branches' mixed by its factor, or the one branch that resolves
    (gated by the mix's weight of a Transparent BSDF on the other side: a cut-out)."""
    factor = _input(node.inputs[0])
    a, b = _sources(nt, node.inputs[1], threshold, depth + 1), _sources(nt, node.inputs[2], threshold, depth + 1)
    if a is not None and b is not None:
        return {aov: _mix(nt, factor, a[aov], b[aov], aov == "basecolor") for aov, _, _ in _CHANNELS}
    # A cut-out: a Transparent BSDF mixed with the surface, whose alpha is then the mix's weight of it.
    if b is not None and _linked_type(node.inputs[1]) == "BSDF_TRANSPARENT":
        return _gate(nt, b, factor, threshold)
    if a is not None and _linked_type(node.inputs[2]) == "BSDF_TRANSPARENT":
        return _gate(nt, a, _one_minus(nt, factor), threshold)
    return a or b


def _one_minus(nt, value: Source) -> Source:
    if isinstance(value, float):
        return 1.0 - value
    node = nt.nodes.new("ShaderNodeMath")
    node.operation = "SUBTRACT"
    node.inputs[0].default_value = 1.0
    nt.links.new(value, node.inputs[1])
    return node.outputs[0]


def _gate(nt, sources: dict[str, Source], alpha: Source, threshold: float) -> dict[str, Source]:
    """``sources`` where ``alpha`` reaches the view layer's pass alpha threshold, else 0.

    Cycles writes the AOVs of every surface a camera ray meets until one is opaque enough (alpha at least the
    threshold) and adds them up; depth and normals come from that one surface. A see-through part of a cut-out
    (foliage, fences) must therefore write nothing, so that the surface behind it alone writes its AOVs.
    """
    if isinstance(alpha, float):
        gate: Source = 1.0 if alpha >= threshold else 0.0
    else:
        node = nt.nodes.new("ShaderNodeMath")
        node.operation = "GREATER_THAN"
        nt.links.new(alpha, node.inputs[0])
        node.inputs[1].default_value = threshold - 1e-6  # at least the threshold
        gate = node.outputs[0]
    zero = {"basecolor": (0.0, 0.0, 0.0, 1.0), "roughness": 0.0, "metallic": 0.0}
    return {aov: _mix(nt, gate, zero[aov], sources[aov], aov == "basecolor") for aov, _, _ in _CHANNELS}


def _mix(nt, factor: Source, a: Source, b: Source, color: bool) -> Source:
    """``a`` and ``b`` mixed as a Mix Shader with ``factor`` mixes its two shaders."""
    mix = nt.nodes.new("ShaderNodeMix")
    mix.data_type = "RGBA" if color else "FLOAT"
    kind = "Color" if color else "Float"
    for identifier, source in (("Factor_Float", factor), (f"A_{kind}", a), (f"B_{kind}", b)):
        _connect(nt, source, next(s for s in mix.inputs if s.identifier == identifier))
    return next(s for s in mix.outputs if s.identifier == f"Result_{kind}")


def _connect(nt, source: Source, target) -> None:
    if isinstance(source, (tuple, list)):
        target.default_value = tuple(source)[: len(target.default_value)]
    elif isinstance(source, float):
        target.default_value = source
    else:
        nt.links.new(source, target)


def _add_aovs(nt, sources: dict[str, Source]) -> None:
    for node in [
        n for n in nt.nodes if n.type == "OUTPUT_AOV" and n.aov_name in dict.fromkeys(a for a, _, _ in _CHANNELS)
    ]:
        nt.nodes.remove(node)  # an earlier wiring of the same names (e.g. a .blend wdss saved)
    for aov_name, _, socket_name in _CHANNELS:
        node = nt.nodes.new("ShaderNodeOutputAOV")
        node.aov_name = aov_name
        _connect(nt, sources[aov_name], node.inputs[socket_name])


def _fallback_sources(material) -> dict[str, Source]:
    return {
        "basecolor": (*material.diffuse_color[:3], 1.0),
        "roughness": float(material.roughness),
        "metallic": float(material.metallic),
    }


def _default_material():
    material = bpy.data.materials.get("wdss_default") or bpy.data.materials.new("wdss_default")
    nt = material.node_tree
    bsdf = next(n for n in nt.nodes if n.type == "BSDF_PRINCIPLED")
    bsdf.inputs["Base Color"].default_value = (*DEFAULT_MATERIAL["base_color"], 1.0)
    bsdf.inputs["Roughness"].default_value = DEFAULT_MATERIAL["roughness"]
    bsdf.inputs["Metallic"].default_value = DEFAULT_MATERIAL["metallic"]
    return material


def wire_aovs(objects: Iterable[Any], *, alpha_threshold: float = 0.5) -> list[dict[str, Any]]:
    """Wire the AOVs of every material of ``objects``; the materials that got fallbacks, one record each:
    ``{"material", "objects", "reason", "base_color", "roughness", "metallic"}`` (``material`` None for objects
    that had none and got :data:`DEFAULT_MATERIAL`). ``alpha_threshold``: the view layer's
    ``pass_alpha_threshold`` (see :func:`_gate`)."""
    users, bare = _material_users(objects)
    records = []
    if bare:
        names = sorted(set(bare))
        log.warning("objects without a material get wdss's default grey Principled BSDF: %s", ", ".join(names))
        records.append({"material": None, "objects": names, "reason": "no material", **DEFAULT_MATERIAL})
    for material, names in sorted(users.items(), key=lambda item: item[0].name):
        record = _wire_material(material, names, alpha_threshold)
        if record is not None:
            records.append(record)
    return records


def _material_users(objects: Iterable[Any]) -> tuple[dict[Any, list[str]], list[str]]:
    """The objects using each material, and those that had none (or an empty slot among filled ones), which get
    :func:`_default_material` here."""
    users: dict[Any, list[str]] = {}
    bare: list[str] = []
    for obj in objects:
        if obj.type not in GEOMETRY_TYPES or not hasattr(obj.data, "materials"):
            continue
        if not obj.material_slots or not any(slot.material for slot in obj.material_slots):
            if not obj.material_slots:
                obj.data.materials.append(_default_material())
            else:
                for slot in obj.material_slots:
                    slot.material = _default_material()
            bare.append(obj.name)
        for slot in obj.material_slots:
            if slot.material is None:  # an empty slot among filled ones
                slot.material = _default_material()
                bare.append(obj.name)
            users.setdefault(slot.material, []).append(obj.name)
    return users, bare


def _wire_material(material: Any, names: list[str], alpha_threshold: float) -> dict[str, Any] | None:
    """Wire one material's AOVs from its sources, or from its viewport display settings where they cannot be read
    (a warning names it and the objects ``names``, and its record is returned; None: read)."""
    nt = material.node_tree
    output = nt.get_output_node("CYCLES") if nt is not None else None
    sources = _sources(nt, output.inputs["Surface"], alpha_threshold) if output is not None else None
    if sources is not None:
        _add_aovs(nt, sources)
        return None
    reason = (
        "no node tree"
        if nt is None
        else "no material output"
        if output is None
        else f"no Principled BSDF reachable from the output (surface: {_surface_kind(output)})"
    )
    sources = _fallback_sources(material)
    if nt is not None:
        _add_aovs(nt, sources)
    record = {
        "material": material.name,
        "objects": sorted(set(names)),
        "reason": reason,
        "base_color": [round(float(c), 6) for c in sources["basecolor"][:3]],
        "roughness": round(sources["roughness"], 6),
        "metallic": round(sources["metallic"], 6),
    }
    log.warning(
        "material %r (objects %s): the G-buffer AOVs cannot be read (%s); base colour, roughness and metallic "
        "fall back to its viewport display settings %s, %s, %s",
        record["material"],
        ", ".join(record["objects"]),
        reason,
        record["base_color"],
        record["roughness"],
        record["metallic"],
    )
    return record


def _surface_kind(output) -> str:
    surface = output.inputs["Surface"]
    if not surface.is_linked:
        return "nothing linked"
    node = surface.links[0].from_node
    return f"node group {node.node_tree.name!r}" if node.type == "GROUP" and node.node_tree else node.bl_idname
