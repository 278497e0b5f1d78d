"""A volume's isosurfaces, cut planes and field chooser (render contract §7, §8): Object.hovr_surfaces,
the Surfaces panel under HOVR Volume, and the operators that edit them.

Each volume keeps its own iso values (colour, opacity); cut planes are objects of the scene
picked per volume (their world location and local +Z axis: a Blender Plane's normal), each with an
opacity and a clip side. snapshot.py turns them into the engine's Surfaces (scene_isosurfaces); the
viewport re-renders when a plane object moves (the planes are part of its request's signature).
The field chooser lists the file's fields and the derived fields they give (Q, vorticity, speed,
|grad|: engine/derived_fields.derived_field_names) and sets the volume's Field.
"""
import bpy
from bpy.props import (CollectionProperty, EnumProperty, FloatProperty, FloatVectorProperty, IntProperty,
                       PointerProperty)

from ..engine.isosurfaces import CLIP_SIDES, MAX_ISOSURFACES, MAX_PLANES
from ..engine.methods import samples_segments
from .panels import VolumeSubPanel

CLIP_ITEMS = (
    ("none", "None", "The plane only shows the field where it cuts the volume", 0),
    ("front", "Front", "Also remove the volume on the side the plane's normal (local +Z) points to", 1),
    ("back", "Back", "Also remove the volume behind the plane (against its normal)", 2),
)
assert {i[0] for i in CLIP_ITEMS} == set(CLIP_SIDES)


class HovrIsosurfaceItem(bpy.types.PropertyGroup):
    value: FloatProperty(name="Value", default=0.0, precision=5, description="The level, in the field's own units")
    color: FloatVectorProperty(name="Colour", subtype='COLOR', size=3, min=0.0, soft_max=1.0,
                               default=(1.0, 0.8, 0.2), description="Linear RGB of the surface (headlight-shaded)")
    opacity: FloatProperty(name="Opacity", default=1.0, min=0.0, max=1.0, description="Alpha of the surface")


class HovrPlaneItem(bpy.types.PropertyGroup):
    object: PointerProperty(name="Plane", type=bpy.types.Object,
                            description="The object whose location and local +Z axis give the cut plane")
    opacity: FloatProperty(name="Opacity", default=1.0, min=0.0, max=1.0,
                           description="Alpha of the field's colour on the plane (0: the plane only clips)")
    clip: EnumProperty(name="Clip", items=CLIP_ITEMS, default="none", description="Which side of the volume it removes")


class HovrSurfaceSettings(bpy.types.PropertyGroup):
    isosurfaces: CollectionProperty(type=HovrIsosurfaceItem)
    planes: CollectionProperty(type=HovrPlaneItem)

    @classmethod
    def register(cls):
        bpy.types.Object.hovr_surfaces = PointerProperty(type=cls, name="HOVR Isosurfaces and Planes")

    @classmethod
    def unregister(cls):
        del bpy.types.Object.hovr_surfaces


class HOVR_OT_isosurface_add(bpy.types.Operator):
    """Add an isosurface to the active volume, at the middle of its value range"""

    bl_idname = "hovr.isosurface_add"
    bl_label = "Add Isosurface"
    bl_options = {'REGISTER', 'UNDO'}

    @classmethod
    def poll(cls, context):
        obj = context.object
        return obj is not None and obj.hovr.is_volume and len(obj.hovr_surfaces.isosurfaces) < MAX_ISOSURFACES

    def execute(self, context):
        obj = context.object
        item = obj.hovr_surfaces.isosurfaces.add()
        item.value = 0.5 * (obj.hovr.value_min + obj.hovr.value_max)
        return {'FINISHED'}


class HOVR_OT_surface_remove(bpy.types.Operator):
    """Remove this isosurface or cut plane (a plane's object stays)"""

    bl_idname = "hovr.surface_remove"
    bl_label = "Remove"
    bl_options = {'REGISTER', 'UNDO'}
    collection: EnumProperty(items=(("isosurfaces", "Isosurface", ""), ("planes", "Cut Plane", "")))
    index: IntProperty()

    def execute(self, context):
        items = getattr(context.object.hovr_surfaces, self.collection)
        if 0 <= self.index < len(items):
            items.remove(self.index)
        return {'FINISHED'}


class HOVR_OT_plane_add(bpy.types.Operator):
    """Add a cut plane to the active volume: the selected object other than the volume, else a new
    Plane through the volume's centre"""

    bl_idname = "hovr.plane_add"
    bl_label = "Add Cut Plane"
    bl_options = {'REGISTER', 'UNDO'}

    @classmethod
    def poll(cls, context):
        obj = context.object
        return obj is not None and obj.hovr.is_volume and len(obj.hovr_surfaces.planes) < MAX_PLANES

    def execute(self, context):
        obj = context.object
        picked = next((o for o in context.selected_objects if o is not obj and not o.hovr.is_volume), None)
        if picked is None:
            import numpy as np
            from mathutils import Vector

            corners = np.array([obj.matrix_world @ Vector(c) for c in obj.bound_box])
            size = float(np.linalg.norm(corners.max(axis=0) - corners.min(axis=0))) or 1.0
            mesh = bpy.data.meshes.new("HOVR Cut Plane")
            h = 0.5 * size
            mesh.from_pydata([(-h, -h, 0), (h, -h, 0), (h, h, 0), (-h, h, 0)], [], [(0, 1, 2, 3)])
            picked = bpy.data.objects.new("HOVR Cut Plane", mesh)
            picked.location = corners.mean(axis=0).tolist()
            picked.display_type = 'WIRE'
            picked.hide_render = True
            context.collection.objects.link(picked)
        item = obj.hovr_surfaces.planes.add()
        item.object = picked
        return {'FINISHED'}


_FIELD_ITEMS = []  # the chooser's last list (Blender keeps no reference to dynamic enum items itself)


def _field_items(self, context):
    return _FIELD_ITEMS or [("", "(no fields found)", "")]


def field_choices(obj, scene) -> list[str]:
    """The volume's file's fields, then the derived fields they give (an empty list where the file
    cannot be listed: the source's own error shows when it renders)."""
    from ..engine.derived_fields import derived_field_names
    from ..io import formats, isolation
    from .snapshot import volume_source

    try:
        source = volume_source(obj, scene)
        data_format = formats.format_of(source.path)
        fields = isolation.list_fields(data_format.name, source.path)
    except Exception:  # a missing or unreadable file: nothing to choose from
        return []
    names = list(fields) if isinstance(fields, dict) else [str(f) for f in fields]
    return names + derived_field_names(fields)


class HOVR_OT_choose_field(bpy.types.Operator):
    """Choose the volume's field: one of its file's fields, or a field derived from them exactly
    (Q, vorticity, speed of a velocity; |grad| of a scalar)"""

    bl_idname = "hovr.choose_field"
    bl_label = "Choose Field"
    bl_options = {'REGISTER', 'UNDO'}
    bl_property = "field"
    field: EnumProperty(name="Field", items=_field_items)

    @classmethod
    def poll(cls, context):
        obj = context.object
        return obj is not None and obj.hovr.is_volume and not obj.hovr.source.startswith("builtin:")

    def invoke(self, context, event):
        _FIELD_ITEMS[:] = [(n, n, "") for n in field_choices(context.object, context.scene)]
        if not _FIELD_ITEMS:
            self.report({'ERROR'}, "no fields to choose from: check the volume's Source")
            return {'CANCELLED'}
        context.window_manager.invoke_search_popup(self)
        return {'RUNNING_MODAL'}

    def execute(self, context):
        if self.field:
            context.object.hovr.field = self.field
        return {'FINISHED'}


class HOVR_OBJECT_PT_surfaces(VolumeSubPanel, bpy.types.Panel):
    """The volume's isosurfaces and cut planes (contract §7)."""

    bl_label = "Isosurfaces and Planes"

    def draw(self, context):
        layout = self.layout
        obj = context.object
        layout.active = obj.hovr.is_volume
        if not obj.hovr.source.startswith("builtin:"):
            layout.operator("hovr.choose_field", icon='VIEWZOOM', text=f"Field: {obj.hovr.field or '(first)'}")
        settings = obj.hovr_surfaces
        for k, item in enumerate(settings.isosurfaces):
            box = layout.box()
            row = box.row(align=True)
            row.prop(item, "value")
            row.prop(item, "color", text="")
            remove = row.operator("hovr.surface_remove", text="", icon='X')
            remove.collection, remove.index = "isosurfaces", k
            box.prop(item, "opacity", slider=True)
        layout.operator("hovr.isosurface_add", icon='ADD')
        for k, item in enumerate(settings.planes):
            box = layout.box()
            row = box.row(align=True)
            row.prop(item, "object", text="")
            remove = row.operator("hovr.surface_remove", text="", icon='X')
            remove.collection, remove.index = "planes", k
            row = box.row(align=True)
            row.prop(item, "opacity", slider=True)
            row.prop(item, "clip", text="")
        layout.operator("hovr.plane_add", icon='MESH_PLANE')
        if (settings.isosurfaces or settings.planes) and not samples_segments(context.scene.hovr.method):
            layout.label(text="Needs the Classified or Split method", icon='ERROR')


classes = (HovrIsosurfaceItem, HovrPlaneItem, HovrSurfaceSettings, HOVR_OT_isosurface_add, HOVR_OT_surface_remove,
           HOVR_OT_plane_add, HOVR_OT_choose_field, HOVR_OBJECT_PT_surfaces)


def register():
    for cls in classes:
        bpy.utils.register_class(cls)


def unregister():
    for cls in reversed(classes):
        bpy.utils.unregister_class(cls)
