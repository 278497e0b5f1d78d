"""Per-datablock settings: Scene.hovr (render), Object.hovr (which objects are volumes, their data)
and ViewLayer.hovr (extra passes)."""
import bpy
from bpy.props import BoolProperty, EnumProperty, FloatProperty, PointerProperty, StringProperty

# Explicit indices so items can be renamed or reordered without breaking saved .blend files.
METHOD_ITEMS = (
    ("riemann", "Riemann", "Left Riemann sum with fixed step h", 0),
    ("trapezoid", "Trapezoid", "Trapezoidal rule with fixed step h", 1),
    ("classified", "Classified", "Segment each ray at transfer-function breakpoints, adaptive quadrature per segment", 2),
    ("split", "Split", "Split each ray into smooth segments before integrating", 3),
)
PRECISION_ITEMS = (
    ("float32", "Float32", "Single-precision kernels: fastest; about 1e-5 relative error", 0),
    ("float64", "Float64", "Double-precision kernels (the same kernel source): for error budgets below float32's", 1),
)
DEVICE_ITEMS = (
    ("cpu", "CPU", "Run the Warp kernels on the CPU", 0),
    ("cuda:0", "CUDA GPU 0", "Run the Warp kernels on the first CUDA device", 1),
    ("cuda:all", "All GPUs", "Split each frame's rows over every CUDA device (one process a device, "
     "rows balanced by the last frame's cost)", 2),
)


def _path_options() -> set:
    """String options of a data path: Blender 4.5+ wants '//' paths declared as supported
    (older versions have no such option; their Property has no is_path_supports_blend_relative)."""
    if "is_path_supports_blend_relative" in bpy.types.Property.bl_rna.properties:
        return {'ANIMATABLE', 'PATH_SUPPORTS_BLEND_RELATIVE'}
    return {'ANIMATABLE'}


PATH_OPTIONS = _path_options()


def _is_blend_texture(_self, texture):
    return texture.type == 'BLEND'


class HovrRenderSettings(bpy.types.PropertyGroup):
    method: EnumProperty(name="Method", items=METHOD_ITEMS, default="classified",
                         description="Quadrature along each ray")
    h: FloatProperty(name="Step", default=0.01, min=1e-6, soft_max=1.0, precision=4, step=0.1,
                     description="Step length in world units (Riemann, trapezoid, smooth segments)")
    tolerance: FloatProperty(name="Tolerance", default=1e-5, min=1e-12, soft_max=1e-1, precision=7,
                             description="Absolute error target of each adaptive panel")
    min_transmittance: FloatProperty(name="Min Transmittance", default=1e-5, min=0.0, max=0.999, precision=6,
                                     description="Stop a ray once its transmittance falls below this")
    device: EnumProperty(name="Device", items=DEVICE_ITEMS, default="cpu",
                         description="Warp device the kernels run on")
    precision: EnumProperty(name="Precision", items=PRECISION_ITEMS, default="float32",
                            description="Arithmetic of the ray kernels")
    density_scale: FloatProperty(name="Density Scale", default=1.0, min=0.0, soft_max=100.0,
                                 description="Extinction per world unit at ramp alpha 1")
    value_min: FloatProperty(name="Value Min", default=0.0,
                             description="Field value at ramp position 0")
    value_max: FloatProperty(name="Value Max", default=1.0,
                             description="Field value at ramp position 1")
    # Python cannot define a ColorRamp property, so a Blend texture owns the ramp.
    transfer_function: PointerProperty(name="Transfer Function", type=bpy.types.Texture, poll=_is_blend_texture,
                                       description="Blend texture whose colour ramp (RGB, alpha) is the transfer function")

    @classmethod
    def register(cls):
        bpy.types.Scene.hovr = PointerProperty(type=cls, name="HOVR Render Settings")

    @classmethod
    def unregister(cls):
        del bpy.types.Scene.hovr


class HovrObjectSettings(bpy.types.PropertyGroup):
    is_volume: BoolProperty(name="HOVR Volume", default=False,
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


classes = (HovrRenderSettings, HovrObjectSettings, HovrViewLayerSettings)


def register():
    for cls in classes:
        bpy.utils.register_class(cls)


def unregister():
    for cls in reversed(classes):
        bpy.utils.unregister_class(cls)
