"""Readers: files and built-in datasets -> engine.mesh.VolumeMesh. No bpy here.

One entry point (sources.py): VolumeSource.resolve / from_view_data describe the data,
load_volume reads it, cached_volume keeps the last few. The CLI, the render engine and the
import operators all read through it. Readers import the core, never the Blender layer.
"""
_SOURCES = ("SourceError", "VolumeSource", "cached_volume", "load_view_data", "load_volume")


def __getattr__(name):
    """sources.py's names, imported on first use: `from hovr_blender.io import isolation` stays
    light, so the `hovr` command starts its reader process before its own heavy imports."""
    if name in _SOURCES:
        from . import sources

        return getattr(sources, name)
    raise AttributeError(f"module {__name__!r} has no attribute {name!r}")
