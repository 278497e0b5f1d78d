"""The Blender layer: the RenderEngine, its properties, panels and operators (these import bpy),
and the plain conversions they use (scene.py, camera.py, viewport.py: no bpy, tested without
Blender). It may import hovr_blender.engine and hovr_blender.io; nothing imports it but the
add-on's register().
"""
