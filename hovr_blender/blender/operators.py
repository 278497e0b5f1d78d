"""Operators: add the built-in sphere volume, create a transfer function, apply a preset,
fit the value range to the data (which also gives the panel its histogram)."""
import bpy

from ..core.cache import LRUCache
from ..core.outline import outline_edges
from ..io.sources import VolumeSource, cached_volume, load_volume
from .scene import DEFAULT_PRESET, TF_PRESETS, field_samples, value_histogram


def field_range(mesh, samples: int = 9):
    """(min, max) of the field over a lattice of reference points in every element."""
    values = field_samples(mesh, samples)
    return float(values.min()), float(values.max())


# Field samples per volume source key (never stored in the .blend): the histogram is drawn
# from here, so panels never load data while drawing.
SAMPLES = LRUCache(4)
HISTOGRAM_BINS = 16


def _volume_object(context):
    obj = context.object
    if obj is not None and obj.hovr.is_volume:
        return obj
    return next((o for o in context.scene.objects if o.hovr.is_volume), None)


def _source_of(obj, scene):
    return VolumeSource.resolve(obj.hovr.source, obj.hovr.solution, obj.hovr.field, scene.frame_current,
                                abspath=lambda p: bpy.path.abspath(p, library=obj.library), component=obj.hovr.component)


def histogram_for(context):
    """Fractions per bin of [value_min, value_max] for the scene's volume, if sampled."""
    obj = _volume_object(context)
    if obj is None:
        return None
    try:
        key = _source_of(obj, context.scene).key
    except ValueError:
        return None
    values = SAMPLES.get(key)
    if values is None:
        return None
    s = context.scene.hovr
    return value_histogram(values, s.value_min, s.value_max, HISTOGRAM_BINS)


def set_ramp_stops(ramp, stops):
    """Replace a colour ramp's stops with [(position, (r, g, b, a)), ...], linear RGB."""
    ramp.interpolation = 'LINEAR'
    ramp.color_mode = 'RGB'
    while len(ramp.elements) > 1:
        ramp.elements.remove(ramp.elements[-1])
    ramp.elements[0].position = stops[0][0]
    ramp.elements[0].color = stops[0][1]
    for pos, rgba in stops[1:]:
        ramp.elements.new(pos).color = rgba


def new_transfer_function_texture(name: str = "HOVR Transfer Function"):
    """A Blend texture whose linear RGB ramp holds the default preset (three thin tents)."""
    tex = bpy.data.textures.new(name, type='BLEND')
    tex.use_color_ramp = True
    set_ramp_stops(tex.color_ramp, TF_PRESETS[DEFAULT_PRESET][2])
    return tex


def create_volume_object(context, name, mesh, source, solution="", field="", component="", location=None):
    """A wire object outlining the domain of `mesh`, marked as a HOVR volume reading `source`;
    selected and active. Nothing is left behind if it fails."""
    verts, edges = outline_edges(mesh)
    me = obj = None
    try:
        me = bpy.data.meshes.new(name)
        me.vertices.add(len(verts))
        me.vertices.foreach_set("co", verts.astype("float32").ravel())
        me.edges.add(len(edges))
        me.edges.foreach_set("vertices", edges.astype("int32").ravel())
        me.update()
        obj = bpy.data.objects.new(name, me)
        obj.display_type = 'WIRE'
        if location is not None:
            obj.location = location
        h = obj.hovr
        h.is_volume, h.source, h.solution, h.field, h.component = True, source, solution, field, component
        (context.collection or context.scene.collection).objects.link(obj)
    except Exception:
        if obj is not None:
            bpy.data.objects.remove(obj)
        if me is not None:
            bpy.data.meshes.remove(me)
        raise
    for other in context.selected_objects:
        other.select_set(False)
    obj.select_set(True)
    context.view_layer.objects.active = obj
    return obj


class HOVR_OT_new_transfer_function(bpy.types.Operator):
    """Create a transfer-function texture (three coloured tents) for the scene"""

    bl_idname = "hovr.new_transfer_function"
    bl_label = "New Transfer Function"
    bl_options = {'REGISTER', 'UNDO'}

    def execute(self, context):
        context.scene.hovr.transfer_function = new_transfer_function_texture()
        return {'FINISHED'}


class HOVR_OT_fit_value_range(bpy.types.Operator):
    """Set Value Min/Max to the range of the volume's field (sampled in every element)"""

    bl_idname = "hovr.fit_value_range"
    bl_label = "Fit to Data Range"
    bl_options = {'REGISTER', 'UNDO'}

    @classmethod
    def poll(cls, context):
        return context.scene is not None and _volume_object(context) is not None

    def execute(self, context):
        obj = _volume_object(context)
        try:
            source = _source_of(obj, context.scene)
            values = SAMPLES.get(source.key)
            if values is None:
                values = field_samples(cached_volume(source))
        except (ValueError, OSError, MemoryError) as exc:
            self.report({'ERROR'}, f"HOVR: cannot read {obj.name!r}: {exc}")
            return {'CANCELLED'}
        if values.size == 0:
            self.report({'ERROR'}, f"HOVR: {obj.name!r} has no finite field values")
            return {'CANCELLED'}
        SAMPLES.put(source.key, values)
        lo, hi = float(values.min()), float(values.max())
        if hi <= lo:  # a constant field: a range around it keeps Value Max > Value Min
            lo, hi = lo - 0.5 * max(abs(lo), 1.0), hi + 0.5 * max(abs(hi), 1.0)
        s = context.scene.hovr
        s.value_min, s.value_max = lo, hi
        self.report({'INFO'}, f"HOVR: value range [{lo:.4g}, {hi:.4g}] from {values.size} samples")
        return {'FINISHED'}


# Explicit indices: saved operator presets and keymaps keep working if items are reordered.
PRESET_ITEMS = tuple((key, label, desc, i) for i, (key, (label, desc, _)) in enumerate(TF_PRESETS.items()))


class HOVR_OT_transfer_function_preset(bpy.types.Operator):
    """Replace the transfer function's colour ramp with a preset"""

    bl_idname = "hovr.transfer_function_preset"
    bl_label = "Transfer Function Preset"
    bl_options = {'REGISTER', 'UNDO'}

    preset: bpy.props.EnumProperty(name="Preset", items=PRESET_ITEMS)

    def execute(self, context):
        settings = context.scene.hovr
        if settings.transfer_function is None:
            settings.transfer_function = new_transfer_function_texture()
        texture = settings.transfer_function
        texture.use_color_ramp = True
        set_ramp_stops(texture.color_ramp, TF_PRESETS[self.preset][2])
        return {'FINISHED'}


class HOVR_OT_add_sphere_volume(bpy.types.Operator):
    """Add the paper's sphere volume (one hexahedron, f = x^2 + y^2 + z^2), shown as its outline"""

    bl_idname = "hovr.add_sphere_volume"
    bl_label = "HOVR Sphere Volume"
    bl_options = {'REGISTER', 'UNDO'}

    source = "builtin:sphere"

    def execute(self, context):
        volume = load_volume(VolumeSource.resolve(self.source))
        create_volume_object(context, "HOVR Sphere", volume, self.source, location=context.scene.cursor.location)

        settings = context.scene.hovr
        if settings.transfer_function is None:
            settings.transfer_function = new_transfer_function_texture()
            settings.value_min, settings.value_max = field_range(volume)
            self.report({'INFO'}, f"HOVR: new transfer function over [{settings.value_min:.3g}, {settings.value_max:.3g}]")
        return {'FINISHED'}


def menu_add(self, _context):
    self.layout.operator(HOVR_OT_add_sphere_volume.bl_idname, icon='VOLUME_DATA')


classes = (HOVR_OT_new_transfer_function, HOVR_OT_fit_value_range, HOVR_OT_transfer_function_preset,
           HOVR_OT_add_sphere_volume)


def register():
    for cls in classes:
        bpy.utils.register_class(cls)
    bpy.types.VIEW3D_MT_add.append(menu_add)


def unregister():
    bpy.types.VIEW3D_MT_add.remove(menu_add)
    for cls in reversed(classes):
        bpy.utils.unregister_class(cls)
