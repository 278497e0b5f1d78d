"""Per-datablock settings: Scene.hovr (render), Object.hovr (which objects are volumes, their data)
and ViewLayer.hovr (extra passes)."""
import bpy
from bpy.props import BoolProperty, EnumProperty, FloatProperty, IntProperty, PointerProperty, StringProperty

from ..engine.first_view import DEFAULT_STEPS_ACROSS
from ..engine.looks import DEFAULT_DENSITY
from ..engine.methods import METHOD_IDS
from . import compat

# Explicit indices (the methods' ids) so items can be renamed or reordered without breaking saved .blend files.
METHOD_ITEMS = (
    ("riemann", "Riemann", "Left Riemann sum with a fixed Step: the classic ray marcher, for comparison",
     METHOD_IDS["riemann"]),
    ("trapezoid", "Trapezoid", "Trapezoidal rule with a fixed Step: for comparison with other renderers",
     METHOD_IDS["trapezoid"]),
    ("classified", "Classified", "The paper's Algorithm 1: skips ray segments the transfer function leaves empty, "
                                 "integrates smooth ones adaptively to Tolerance and marches the rest with Step. "
                                 "The default", METHOD_IDS["classified"]),
    ("split", "Split", "Cuts each ray where the field crosses a ramp stop, so every piece is smooth, and integrates "
                       "each adaptively to Tolerance (Step unused). Best for sharp, spiky ramps", METHOD_IDS["split"]),
)
PRECISION_ITEMS = (
    ("float32", "Float32", "Single-precision kernels: fastest; about 1e-5 relative error", 0),
    ("float64", "Float64", "Double-precision kernels (the same kernel source): for error budgets below float32's", 1),
)
DEVICE_ITEMS = (
    ("cpu", "CPU", "Run the Warp kernels on the CPU, a thread a core (one copy of the data)", 0),
    ("cuda:0", "CUDA GPU 0", "Run the Warp kernels on the first CUDA device", 1),
    ("cuda:all", "All GPUs", "Split each frame's rows over every CUDA device (one process a device, "
     "rows balanced by the last frame's cost)", 2),
    ("cpu:all", "All CPU Cores", "Split each frame's rows over one CPU process a core (a copy of the data each)", 3),
)

SURFACE_ITEMS = (
    ("NONE", "Off", "Render the volumes alone: other objects neither stop the rays nor appear", 0),
    ("SHADED", "Shaded", "Visible mesh objects stop the rays and appear in a simple shading (material base colour "
                         "under a headlight): the volume in its scene on its own", 1),
    ("HOLDOUT", "Holdout", "Visible mesh objects stop the rays but stay transparent: the image is the volume in "
                           "front of them, premultiplied, to lay over Cycles' or EEVEE's render of the scene "
                           "(see Set Up Compositing)", 2),
)


PATH_OPTIONS = compat.path_property_options()


DENSITY_UNIT_ITEMS = (
    ("RELATIVE", "Across Volume", "Density is the optical depth along the volume's bounding-box diagonal at ramp "
                                  "alpha 1: the same look at any size", 0),
    ("WORLD", "Per World Unit", "Density is the extinction per world unit at ramp alpha 1 (the render contract's "
                                "own unit)", 1),
)


STEP_UNIT_ITEMS = (
    ("RELATIVE", "Across Volume", "Steps Across: so many steps along the volume's bounding-box diagonal, the same "
                                  "sampling at any size", 0),
    ("WORLD", "World Units", "Step: a length in world units (the render contract's h)", 1),
)


def _volume_ticked(self, context):
    """Ticking HOVR Volume gives the object the transfer function it needs."""
    if self.is_volume and self.transfer_function is None:
        from .operators import new_transfer_function_texture

        self.transfer_function = new_transfer_function_texture(f"{self.id_data.name} Transfer Function")


class HovrRenderSettings(bpy.types.PropertyGroup):
    method: EnumProperty(name="Method", items=METHOD_ITEMS, default="classified",
                         description="Quadrature along each ray")
    # Step Units decide which of the two steps is used; a scene saved before Step Units existed
    # keeps its step in world units (versioning.migrate_step_units)
    step_units: EnumProperty(name="Units", items=STEP_UNIT_ITEMS, default="RELATIVE",
                             description="What the step is measured in")
    steps_across: IntProperty(name="Steps Across", default=DEFAULT_STEPS_ACROSS, min=1, soft_min=10,
                              soft_max=100000,
                              description="Steps along the bounding-box diagonal of the (smallest) volume: the step "
                                          "is that diagonal divided by this. Riemann and Trapezoid, and Classified "
                                          "where the ramp bends inside a segment (Split ignores it)")
    h: FloatProperty(name="Step", default=0.01, min=1e-6, soft_max=1.0, precision=6, step=0.1,
                     description="Step length in world units: Riemann and Trapezoid, and Classified where the "
                                 "ramp bends inside a segment (Split ignores it)")
    tolerance: FloatProperty(name="Tolerance", default=1e-5, min=1e-12, soft_max=1e-1, precision=7,
                             description="Error target of each adaptive panel (Classified and Split; the baselines ignore it)")
    min_transmittance: FloatProperty(name="Cut-off",  default=1e-5, min=0.0, max=0.999, precision=6,
                                     description="Minimum transmittance: stop a ray once the light left through it falls below this")
    device: EnumProperty(name="Device", items=DEVICE_ITEMS, default="cpu",
                         description="Warp device the kernels run on")
    precision: EnumProperty(name="Precision", items=PRECISION_ITEMS, default="float32",
                            description="Arithmetic of the ray kernels")
    # Off in a new scene: data imported into Blender's startup scene sits inside the default cube
    surfaces: EnumProperty(name="Surfaces", items=SURFACE_ITEMS, default="NONE",
                           description="What the scene's visible mesh objects do to the volume's rays")
    show_legend: BoolProperty(name="Legend", default=True,
                              description="Draw the active volume's colour legend (its ramp over Value Min..Max, "
                                          "with the field's name) over the viewport in Rendered shading")
    legend_in_render: BoolProperty(name="Legend in Render", default=False,
                                   description="Draw the same legend onto F12's image (Combined pass), at its right "
                                               "edge: the bar, five values and the field's name")
    # Before 0.2 the look was the scene's, shared by every volume. Kept registered (never drawn)
    # so old .blend files keep their values: versioning.py moves them onto the volumes, and
    # render.py reads them for a volume that has no look of its own yet.
    density_scale: FloatProperty(name="Density Scale (legacy)", default=1.0, min=0.0,
                                 description="Before per-volume looks: extinction per world unit at ramp alpha 1")
    value_min: FloatProperty(name="Value Min (legacy)", default=0.0,
                             description="Before per-volume looks: field value at ramp position 0")
    value_max: FloatProperty(name="Value Max (legacy)", default=1.0,
                             description="Before per-volume looks: field value at ramp position 1")
    transfer_function: PointerProperty(name="Transfer Function (legacy)", type=bpy.types.Texture,
                                       description="Before per-volume looks: the scene's transfer function")

    @classmethod
    def register(cls):
        bpy.types.Scene.hovr = PointerProperty(type=cls, name="HOVR Render Settings")

    @classmethod
    def unregister(cls):
        del bpy.types.Scene.hovr


class HovrObjectSettings(bpy.types.PropertyGroup):
    """A volume: its data (source, solution, field) and its look (transfer function, value range,
    density). Each volume has its own look, so importing or editing one never changes another."""

    is_volume: BoolProperty(name="HOVR Volume", default=False, update=_volume_ticked,
                            description="Render this object's finite-element data with HOVR")
    source: StringProperty(name="Source", default="", subtype='FILE_PATH', options=PATH_OPTIONS,
                           description='"builtin:sphere", or a Nektar++ .xml / .vtu file; a run of # is replaced by '
                                       'the frame number ("flow_####.vtu")')
    solution: StringProperty(name="Solution", default="", subtype='FILE_PATH', options=PATH_OPTIONS,
                             description="Nektar++ field file (.fld/.chk) for the mesh; # runs become the frame number")
    field: StringProperty(name="Field", default="",
                          description='Name of the scalar field to render (empty: the file\'s only or first field); '
                                      'Nektar++: "|u,v,w|" renders the magnitude of the fields u, v, w')
    component: StringProperty(name="Component", default="",
                              description="VTU vector arrays: empty or \"magnitude\" renders the vector's magnitude, "
                                          "an index (0, 1, 2, ...) that component")
    units: StringProperty(name="Units", default="",
                          description="The field's units, shown after its name in the colour legend (e.g. kg/m^3); "
                                      "none of the readers' formats states them")
    # Python cannot define a ColorRamp property, so a Blend texture owns the ramp.
    transfer_function: PointerProperty(name="Transfer Function", type=bpy.types.Texture,
                                       description="Texture whose colour ramp (RGB, alpha) is this volume's transfer "
                                                   "function: colour = ramp RGB, density = ramp alpha x Density")
    value_min: FloatProperty(name="Value Min", default=0.0, precision=4, description="Field value at ramp position 0")
    value_max: FloatProperty(name="Value Max", default=1.0, precision=4, description="Field value at ramp position 1")
    density: FloatProperty(name="Density", default=DEFAULT_DENSITY, min=0.0, soft_max=100.0,
                           description="Extinction at ramp alpha 1, in the units below")
    density_units: EnumProperty(name="Units", items=DENSITY_UNIT_ITEMS, default="RELATIVE",
                                description="What Density is measured in")

    @classmethod
    def register(cls):
        bpy.types.Object.hovr = PointerProperty(type=cls, name="HOVR Object Settings")

    @classmethod
    def unregister(cls):
        del bpy.types.Object.hovr


class HovrViewLayerSettings(bpy.types.PropertyGroup):
    use_pass_error: BoolProperty(name="Error Estimate", default=False,
                                 description='"HOVR Error" pass: the summed Gauss-Kronrod error estimates per pixel '
                                             "(zero for methods without an estimate)",
                                 update=lambda self, context: context.view_layer.update_render_passes())

    @classmethod
    def register(cls):
        bpy.types.ViewLayer.hovr = PointerProperty(type=cls, name="HOVR View Layer Settings")

    @classmethod
    def unregister(cls):
        del bpy.types.ViewLayer.hovr


def _addon_package() -> str:
    """The add-on's module name: "hovr_blender", or bl_ext.<repo>.hovr_blender as an extension."""
    return __package__.rpartition(".")[0]


def _debug_changed(self, _context):
    import os

    if self.debug_output:
        os.environ["HOVR_DEBUG"] = "1"
    else:
        os.environ.pop("HOVR_DEBUG", None)


class HovrPreferences(bpy.types.AddonPreferences):
    """Edit > Preferences > Add-ons > HOVR: which dependencies are installed, debug output."""

    bl_idname = _addon_package()

    debug_output: BoolProperty(name="Debug Output", default=False, update=_debug_changed,
                               description="Let Warp print its start-up, CUDA and module-load lines to the console "
                                           "(from the next Blender session on; silent otherwise)")

    def draw(self, context):
        from .dependencies import dependencies, missing, report_lines

        layout = self.layout
        absent = missing()
        col = layout.column(align=True)
        for module, package, purpose, _required in dependencies():
            ok = all(m != module for m, *_ in absent)
            col.label(text=f"{package}: {'installed' if ok else 'MISSING'} ({purpose})",
                      icon='CHECKMARK' if ok else 'ERROR')
        for line in report_lines(absent)[len(absent):]:
            box = layout.box()
            for k in range(0, len(line), 90):
                box.label(text=line[k:k + 90])
        layout.prop(self, "debug_output")


def report_missing_dependencies():
    """At enable time: say which dependencies are missing and what to do, on the console (the
    Preferences entry shows the same); never first at render time."""
    from .dependencies import missing, report_lines

    lines = report_lines(missing())
    for line in lines:
        print(line, flush=True)
    if lines and not bpy.app.background:
        def popup():
            wm = bpy.context.window_manager
            if wm is not None:
                wm.popup_menu(lambda self, _ctx: [self.layout.label(text=t) for t in lines],
                              title="HOVR: missing dependencies", icon='ERROR')
            return None

        bpy.app.timers.register(popup, first_interval=0.5)


classes = (HovrRenderSettings, HovrObjectSettings, HovrViewLayerSettings, HovrPreferences)


def register():
    for cls in classes:
        bpy.utils.register_class(cls)
    prefs = bpy.context.preferences.addons.get(HovrPreferences.bl_idname) if bpy.context.preferences else None
    if prefs is not None and prefs.preferences is not None and prefs.preferences.debug_output:
        _debug_changed(prefs.preferences, None)
    report_missing_dependencies()


def unregister():
    for cls in reversed(classes):
        bpy.utils.unregister_class(cls)
