"""Readers: files and built-in datasets -> engine.mesh.VolumeMesh. No bpy here.

One entry point (sources.py): VolumeSource.resolve / from_view_data describe the data,
load_volume reads it, cached_volume keeps the last few. The CLI, the render engine and the
import operators all read through it. Readers import the core, never the Blender layer.
"""
from .sources import SourceError, VolumeSource, cached_volume, load_view_data, load_volume  # noqa: F401
