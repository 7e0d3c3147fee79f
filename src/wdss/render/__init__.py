"""Datasets rendered with Blender Cycles (``bpy``, the ``render`` extra), in the authors' layout, from procedural
scenes (:mod:`wdss.render.spec`) or scene files (``.glb``/``.gltf``/``.blend``, :mod:`wdss.render.scene_file`).

``python -m wdss.render`` (config ``conf/render/``) renders sequences; :func:`render_preset` renders a named
preset, which is how ``conf/data/mini.yaml`` makes the default dataset on first use (:class:`RenderOnFirstUse`).
"""

from wdss.render.sequence import RenderOnFirstUse, render_preset, render_sequence, render_sequences

__all__ = ["RenderOnFirstUse", "render_preset", "render_sequence", "render_sequences"]
