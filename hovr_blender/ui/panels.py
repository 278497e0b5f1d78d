"""Properties-editor panels for the HOVR engine, and the stock panels it reuses."""
import bpy

from ..engine.methods import takes_step
from ..io import formats


def draw_histogram(layout, context, obj):
    """The field's distribution over Value Min..Max (bottom row = Value Min), one bar per
    bin, after the volume's data was sampled (on import, or by Fit to Data Range)."""
    from .operators import histogram_for

    hist = histogram_for(context, obj)
    if hist is None:
        return
    box = layout.box()
    box.label(text="Share of samples per value")
    col = box.column(align=True)
    peak = float(hist.max()) if hist.size and hist.max() > 0 else 1.0
    h = obj.hovr
    width = (h.value_max - h.value_min) / hist.size
    for k in reversed(range(hist.size)):  # largest values on top, like the ramp's right end
        frac, lo = float(hist[k]), h.value_min + k * width
        row = col.row(align=True)
        row.scale_y = 0.5
        text = f"{lo:.3g}"
        if hasattr(row, "progress"):  # Blender 4.0+
            row.progress(factor=float(frac / peak), type='BAR', text=f"{text}: {100 * frac:.1f}%")
        else:
            row.label(text=f"{text:>8} " + "|" * int(round(30 * frac / peak)))


def known_world_step(scene):
    """The world step a relative Step gives the scene's volumes, if all their sizes are known
    already (panels never load data: a volume not yet read or rendered leaves it unknown)."""
    from ..engine.first_view import volume_diagonal
    from .framing import step_world_length
    from .snapshot import EXTENTS, volume_source

    diagonals = []
    for obj in scene.objects:
        if not obj.hovr.is_volume:
            continue
        try:
            extent = EXTENTS.get(volume_source(obj, scene).key)
        except ValueError:
            return None
        if extent is None:
            return None
        diagonals.append(volume_diagonal(*extent, matrix=obj.matrix_world))
    try:
        return step_world_length(scene.hovr.h, scene.hovr.steps_across, scene.hovr.step_units, diagonals)
    except ValueError:
        return None


class HovrButtonsPanel:
    bl_space_type = 'PROPERTIES'
    bl_region_type = 'WINDOW'
    COMPAT_ENGINES = {'HOVR'}

    @classmethod
    def poll(cls, context):
        return context.engine in cls.COMPAT_ENGINES


class HOVR_RENDER_PT_quadrature(HovrButtonsPanel, bpy.types.Panel):
    bl_label = "Quadrature"
    bl_context = "render"

    def draw(self, context):
        layout = self.layout
        layout.use_property_split = True
        layout.use_property_decorate = False
        settings = context.scene.hovr
        layout.prop(settings, "method")
        col = layout.column(align=True)
        col.active = takes_step(settings.method)  # Split needs no step
        if settings.step_units == "WORLD":
            col.prop(settings, "h")
        else:
            col.prop(settings, "steps_across")
        col.prop(settings, "step_units")
        if settings.step_units != "WORLD":
            h = known_world_step(context.scene)
            if h is not None:  # in the property rows' two columns
                split = col.split(factor=0.4)
                name = split.row()
                name.alignment = 'RIGHT'
                name.label(text="Step")
                split.label(text=f"{h:.3g} world units")
        layout.prop(settings, "tolerance")
        layout.prop(settings, "min_transmittance")
        layout.prop(settings, "device")
        layout.prop(settings, "precision")


class HOVR_RENDER_PT_film(HovrButtonsPanel, bpy.types.Panel):
    bl_label = "Film"
    bl_context = "render"

    def draw(self, context):
        layout = self.layout
        layout.use_property_split = True
        layout.use_property_decorate = False
        scene = context.scene
        layout.prop(scene.render, "film_transparent")
        layout.prop(scene.hovr, "surfaces")
        layout.prop(scene.hovr, "show_legend")
        layout.prop(scene.hovr, "legend_in_render")
        layout.operator("hovr.setup_compositing", icon='NODE_COMPOSITING')
        if scene.world is not None:
            row = layout.row()
            row.active = not scene.render.film_transparent
            row.prop(scene.world, "color", text="Background")  # HOVR's background is the world colour


class HOVR_OBJECT_PT_volume(HovrButtonsPanel, bpy.types.Panel):
    bl_label = "HOVR Volume"
    bl_context = "object"

    @classmethod
    def poll(cls, context):
        return super().poll(context) and context.object is not None

    def draw_header(self, context):
        self.layout.prop(context.object.hovr, "is_volume", text="")

    def draw(self, context):
        layout = self.layout
        layout.use_property_split = True
        layout.active = context.object.hovr.is_volume
        hovr = context.object.hovr
        layout.prop(hovr, "source")
        if not hovr.source.startswith("builtin:"):
            data_format = formats.format_of(hovr.source, sniff=False)  # by extension: drawing reads no file
            if data_format is None or data_format.takes_solution:
                layout.prop(hovr, "solution")
                if not hovr.solution.strip() and hovr.source.strip():
                    layout.label(text="No solution: geometry only", icon='ERROR')
            layout.prop(hovr, "field")
            if data_format is not None and data_format.components:
                layout.prop(hovr, "component")
        layout.prop(hovr, "units")
        if "#" in hovr.source or "#" in hovr.solution:
            layout.label(text="# runs are replaced by the frame number", icon='INFO')
        row = layout.row(align=True)
        row.operator("hovr.frame_volume", icon='VIEW_CAMERA')
        row.operator("hovr.add_walls", icon='MESH_GRID')


class VolumeSubPanel(HovrButtonsPanel):
    """A panel under the object's HOVR Volume panel, shown where there is an object."""

    bl_context = "object"
    bl_parent_id = "HOVR_OBJECT_PT_volume"

    @classmethod
    def poll(cls, context):
        return super().poll(context) and context.object is not None


class HOVR_OBJECT_PT_look(VolumeSubPanel, bpy.types.Panel):
    """The volume's own transfer function, value range and density: each volume has its own."""

    bl_label = "Look"

    def draw(self, context):
        from .versioning import volume_look

        layout = self.layout
        obj = context.object
        hovr = obj.hovr
        layout.active = hovr.is_volume
        if volume_look(hovr, context.scene).legacy:
            layout.label(text="Uses the scene's old look (reopen the file to convert)", icon='INFO')
        row = layout.row(align=True)
        row.template_ID(hovr, "transfer_function", new="hovr.new_transfer_function")
        texture = hovr.transfer_function
        if texture is None:
            layout.label(text="Colour = ramp RGB, density = alpha x Density", icon='INFO')
        elif not texture.use_color_ramp:
            layout.prop(texture, "use_color_ramp", text="Use Colour Ramp")
        else:
            layout.template_color_ramp(texture, "color_ramp", expand=True)
            ramp = texture.color_ramp
            if ramp.interpolation != 'LINEAR' or ramp.color_mode != 'RGB':
                col = layout.column(align=True)
                col.label(text="Ramp must be Linear, RGB", icon='ERROR')
                col.label(text="(set both in the ramp's menus)")
        layout.operator_menu_enum("hovr.transfer_function_preset", "preset", text="Presets", icon='PRESET')
        col = layout.column()
        col.use_property_split = True
        col.use_property_decorate = False
        row = col.row(align=True)
        row.prop(hovr, "density")
        col.prop(hovr, "density_units")
        sub = col.column(align=True)
        sub.prop(hovr, "value_min", text="Value Min")
        sub.prop(hovr, "value_max", text="Max")
        col.operator("hovr.fit_value_range", icon='FULLSCREEN_ENTER')
        if hovr.value_max <= hovr.value_min:
            col.label(text="Value Max must exceed Min", icon='ERROR')
        draw_histogram(layout, context, obj)


class HOVR_VIEWLAYER_PT_passes(HovrButtonsPanel, bpy.types.Panel):
    bl_label = "Passes"
    bl_context = "view_layer"

    def draw(self, context):
        layout = self.layout
        layout.use_property_split = True
        layout.use_property_decorate = False
        view_layer = context.view_layer
        col = layout.column(heading="Include")
        col.label(text="Combined (RGBA, scene-linear, premultiplied)")
        col.prop(view_layer, "use_pass_z", text="Depth (view-axis distance at 50% opacity)")
        col.prop(view_layer.hovr, "use_pass_error")


# Stock panels that mean the same under HOVR: image size and output, colour management,
# camera lens, world selection. Everything else (lights, materials, sampling) does not apply.
STOCK_PANELS = {
    "RENDER_PT_format", "RENDER_PT_frame_range", "RENDER_PT_output", "RENDER_PT_output_color_management",
    "RENDER_PT_encoding", "RENDER_PT_encoding_video", "RENDER_PT_encoding_audio", "RENDER_PT_post_processing",
    "RENDER_PT_color_management", "RENDER_PT_color_management_working_space",
    "RENDER_PT_color_management_display_settings", "RENDER_PT_color_management_curves",
    "RENDER_PT_color_management_white_balance", "RENDER_PT_color_management_advanced",
    "DATA_PT_context_camera", "DATA_PT_lens", "DATA_PT_camera", "DATA_PT_camera_display",
    "DATA_PT_camera_safe_areas", "DATA_PT_custom_props_camera",
    "WORLD_PT_context_world", "WORLD_PT_custom_props",
}


def get_panels():
    """Stock panel classes to show under HOVR (those that declare COMPAT_ENGINES)."""
    return [p for p in bpy.types.Panel.__subclasses__()
            if p.__name__ in STOCK_PANELS and isinstance(getattr(p, "COMPAT_ENGINES", None), set)]


# Panels that got 'HOVR' from us, so unregister removes only what register added
# (several stock panels share one COMPAT_ENGINES set).
_added_to = []

classes = (HOVR_RENDER_PT_quadrature, HOVR_RENDER_PT_film, HOVR_OBJECT_PT_volume, HOVR_OBJECT_PT_look,
           HOVR_VIEWLAYER_PT_passes)


def register():
    for cls in classes:
        bpy.utils.register_class(cls)
    for panel in get_panels():
        if 'HOVR' not in panel.COMPAT_ENGINES:
            panel.COMPAT_ENGINES.add('HOVR')
            _added_to.append(panel)


def unregister():
    while _added_to:
        _added_to.pop().COMPAT_ENGINES.discard('HOVR')
    for cls in reversed(classes):
        bpy.utils.unregister_class(cls)
