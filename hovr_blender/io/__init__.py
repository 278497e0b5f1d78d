"""Readers: files and built-in datasets -> engine.mesh.VolumeMesh. No bpy here.

Blender-side import operators live in blender/ and call these readers.
"""
