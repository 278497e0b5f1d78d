"""In-Blender tests: bpy (Blender 5.0 as a Python module) runs inside pytest's process.

Every test module is marked ``blender`` and skips itself (importorskip) when bpy is missing;
the fixtures here import bpy lazily so this file loads without it.
"""
import pytest


@pytest.fixture
def addon():
    """The add-on registered in a factory-fresh, empty session; unregistered afterwards."""
    import bpy

    import hovr_blender

    bpy.ops.wm.read_factory_settings(use_empty=True)
    hovr_blender.register()
    try:
        yield hovr_blender
    finally:
        hovr_blender.unregister()
        bpy.ops.wm.read_factory_settings(use_empty=True)


@pytest.fixture
def scene(addon):
    """An empty scene rendered by HOVR."""
    import bpy

    sc = bpy.context.scene
    sc.render.engine = 'HOVR'
    return sc
