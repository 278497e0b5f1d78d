"""The HOVR RenderEngine: each method is one call into render.py, where the work is written as
plain functions (the shape of Cycles' add-on)."""
from __future__ import annotations

import bpy

from . import render


def _engine_api(engine):
    """What final renders report progress to and poll for cancellation: the engine (tests
    wrap it, since RNA methods cannot be patched on the class)."""
    return engine


class HovrRenderEngine(bpy.types.RenderEngine):
    bl_idname = "HOVR"
    bl_label = "HOVR"
    bl_use_preview = False  # no material/world previews: HOVR renders only its volumes
    bl_use_eevee_viewport = True  # Material Preview shading falls back to EEVEE

    def __init__(self, *args, **kwargs):
        super().__init__(*args, **kwargs)  # required since Blender 4.4
        from .viewport import ProgressiveViewport

        self.viewport = ProgressiveViewport()
        render.VIEWPORTS.add(self.viewport)
        self.texture = None  # (version, GPUTexture) of the viewport's last frame
        self.viewport_error = None
        self.viewport_status = None  # the stats text last shown in the viewport

    def __del__(self):
        # Nothing per instance to free (uploads are cached at module level); chain to the
        # parent if a future Blender defines __del__, tolerating an already-freed RNA struct.
        parent_del = getattr(super(), "__del__", None)
        if parent_del is not None:
            try:
                parent_del()
            except ReferenceError:
                pass

    def update_render_passes(self, scene=None, renderlayer=None):
        render.declare_passes(self, scene, renderlayer)

    def render(self, depsgraph):
        render.final_render(self, _engine_api(self), depsgraph)

    def view_update(self, context, depsgraph):
        render.view_update(self, context, depsgraph)

    def view_draw(self, context, depsgraph):
        render.view_draw(self, context, depsgraph)


classes = (HovrRenderEngine,)


def register():
    for cls in classes:
        bpy.utils.register_class(cls)


def unregister():
    for cls in reversed(classes):
        bpy.utils.unregister_class(cls)
    render.clear_cache()
