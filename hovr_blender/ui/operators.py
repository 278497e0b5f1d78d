"""Operators: add the built-in sphere volume, create a transfer function, apply a preset,
fit the value range to the data (which also gives the panel its histogram), frame the
volumes with the scene camera. Each acts on one volume's own look (Object.hovr), never
on another volume's."""
import bpy
import numpy as np

from ..engine.lru_cache import LRUCache
from ..engine.outline import outline_edges
from ..io.sources import VolumeSource, cached_volume, load_volume
from ..engine.first_view import FRAME_MARGIN, first_look
from ..engine.looks import DEFAULT_PRESET, FIRST_LOOK, FIRST_LOOKS, TF_PRESETS, field_samples, value_range
from .scene import value_histogram
from .snapshot import volume_source


def field_range(mesh, samples: int = 9):
    """(min, max) of the field over a lattice of reference points in every element."""
    values = field_samples(mesh, samples)
    return float(values.min()), float(values.max())


# Field samples and their volumes (looks.field_samples) per volume source key (never stored in the
# .blend): the histogram is drawn from here, so panels never load data while drawing.
SAMPLES = LRUCache(4)
HISTOGRAM_BINS = 16


def _volume_object(context):
    """The volume the look operators act on: the active object if it is a volume, else the
    scene's only volume (with several, the user picks one by making it active)."""
    obj = context.object
    if obj is not None and obj.hovr.is_volume:
        return obj
    volumes = [o for o in context.scene.objects if o.hovr.is_volume]
    return volumes[0] if len(volumes) == 1 else None


def histogram_for(context, obj=None):
    """Fractions per bin of the volume's [value_min, value_max], if its data was sampled."""
    obj = obj or _volume_object(context)
    if obj is None:
        return None
    try:
        key = volume_source(obj, context.scene).key
    except ValueError:
        return None
    samples = SAMPLES.get(key)
    if samples is None:
        return None
    values = samples[0]
    h = obj.hovr
    return value_histogram(values, h.value_min, h.value_max, HISTOGRAM_BINS)


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


def new_transfer_function_texture(name: str = "HOVR Transfer Function", preset: str = DEFAULT_PRESET):
    """A Blend texture whose linear RGB ramp holds a preset (default: the smooth ramp, opacity
    rising with the value, which shows something for any field once its range is fitted)."""
    tex = bpy.data.textures.new(name, type='BLEND')
    tex.use_color_ramp = True
    set_ramp_stops(tex.color_ramp, TF_PRESETS[preset][2])
    return tex


def discard(obj, me):
    """Remove a half-made object and its mesh: a failed step leaves nothing in the file."""
    if obj is not None:
        bpy.data.objects.remove(obj)
    if me is not None:
        bpy.data.meshes.remove(me)


def create_volume_object(context, name, mesh, source, solution="", field="", component="", location=None):
    """A wire object outlining the domain of `mesh`, marked as a HOVR volume reading `source`;
    selected and active. Nothing is left behind if it fails."""
    verts, edges = outline_edges(mesh)
    me = obj = None
    try:
        me = bpy.data.meshes.new(name)
        # from_pydata, not foreach_set + update(): it marks the edges as loose edges, which
        # Blender 3.x/4.1 need to draw an edges-only mesh at all (the outline was invisible)
        me.from_pydata(verts.astype("float64").tolist(), edges.astype("int64").tolist(), [])
        me.update()
        obj = bpy.data.objects.new(name, me)
        obj.display_type = 'WIRE'
        if location is not None:
            obj.location = location
        h = obj.hovr
        h.is_volume, h.source, h.solution, h.field, h.component = True, source, solution, field, component
        (context.collection or context.scene.collection).objects.link(obj)
    except Exception:
        discard(obj, me)
        raise
    for other in context.selected_objects:
        other.select_set(False)
    obj.select_set(True)
    context.view_layer.objects.active = obj
    return obj


class _OnVolume:
    """Operators that act on the active HOVR volume: available only where there is one."""

    @classmethod
    def poll(cls, context):
        return context.scene is not None and _volume_object(context) is not None


class HOVR_OT_new_transfer_function(_OnVolume, bpy.types.Operator):
    """Give the active HOVR volume a new transfer function of its own (a smooth ramp)"""

    bl_idname = "hovr.new_transfer_function"
    bl_label = "New Transfer Function"
    bl_options = {'REGISTER', 'UNDO'}

    def execute(self, context):
        obj = _volume_object(context)
        obj.hovr.transfer_function = new_transfer_function_texture(f"{obj.name} Transfer Function")
        return {'FINISHED'}


def volume_samples(obj, scene, samples=None):
    """(values, volumes) of the volume's sampled field (looks.field_samples, kept in SAMPLES for the
    histogram): `samples` where the caller has them, else the cached ones, else sampled now."""
    source = volume_source(obj, scene)
    if samples is None:
        samples = SAMPLES.get(source.key)
    if samples is None:
        samples = field_samples(cached_volume(source), weights=True)
    if samples[0].size == 0:
        raise ValueError(f"{obj.name!r} has no finite field values")
    SAMPLES.put(source.key, samples)
    return samples


def fit_value_range(obj, scene, samples=None):
    """Set the volume's Value Min/Max to its field's sampled range (looks.value_range: a field
    constant up to rounding gets a range around its value); returns (lo, hi, samples, warning)."""
    values = volume_samples(obj, scene, samples)[0]
    lo, hi, warning = value_range(values)
    obj.hovr.value_min, obj.hovr.value_max = lo, hi
    return lo, hi, values.size, warning


class HOVR_OT_fit_value_range(_OnVolume, bpy.types.Operator):
    """Set the volume's Value Min/Max to the range of its field (sampled in every element)"""

    bl_idname = "hovr.fit_value_range"
    bl_label = "Fit to Data Range"
    bl_options = {'REGISTER', 'UNDO'}

    def execute(self, context):
        obj = _volume_object(context)
        try:
            lo, hi, n, warning = fit_value_range(obj, context.scene)
        except (ValueError, OSError, MemoryError) as exc:
            self.report({'ERROR'}, f"HOVR: cannot read {obj.name!r}: {exc}")
            return {'CANCELLED'}
        if warning:
            self.report({'WARNING'}, f"HOVR: {obj.name}: {warning}")
        else:
            self.report({'INFO'}, f"HOVR: {obj.name}: value range [{lo:.4g}, {hi:.4g}] from {n} samples")
        return {'FINISHED'}


# ------------------------------------------------------------------------------------ framing


def volume_points(obj, scene):
    """World points that outline a volume: its elements' corners (from its data, read once and
    cached), or the corners of the object's own bounds when the data cannot be read."""
    from .framing import transform_points
    from .snapshot import volume_points as data_points

    M = np.array(obj.matrix_world)
    try:
        return transform_points(data_points(volume_source(obj, scene)), M)
    except Exception:
        return transform_points(np.array([tuple(c) for c in obj.bound_box]), M)


def frame_volumes(context, objects, margin: float = FRAME_MARGIN):
    """Point the scene camera (made if there is none) at `objects` from its current direction,
    near enough that they fill the frame, with clip start/end set from their size; the 3D
    views' clip range and view follow. Returns the camera object."""
    from mathutils import Matrix

    from .blender_camera import ray_camera_from_blender
    from ..engine.first_view import FACTORY_FORWARD, camera_pose, clip_planes, fit_view, frame_tangents, look_at_matrix

    scene = context.scene
    corners = np.concatenate([volume_points(o, scene) for o in objects])
    cam = scene.camera
    if cam is None or cam.type != 'CAMERA':
        cam = bpy.data.objects.new("Camera", bpy.data.cameras.new("Camera"))
        scene.collection.objects.link(cam)
        scene.camera = cam
        forward = np.array(FACTORY_FORWARD, float)  # as Blender's factory camera
        cam.matrix_world = Matrix(look_at_matrix(np.zeros(3), forward, (0, 0, 1)).tolist())
    else:
        forward = -np.array(cam.matrix_world.to_3x3().col[2])
    depsgraph = context.evaluated_depsgraph_get()
    cam.data.clip_start, cam.data.clip_end = 1e-3, 1e3  # any valid range: only the angles are read
    depsgraph.update()
    rays = ray_camera_from_blender(cam, depsgraph, scene.render)
    ortho = rays.projection == "orthographic"
    tan_x, tan_y = frame_tangents(rays)
    eye, height, near, far = fit_view(corners, forward, (0, 0, 1), tan_x, tan_y, ortho, margin)
    if ortho:
        cam.data.ortho_scale *= height / (2.0 * tan_y)
    location, euler, _ = camera_pose(eye, forward, (0, 0, 1))
    if cam.parent is None and cam.rotation_mode == 'XYZ' and not any(cam.delta_location) and \
            not any(cam.delta_rotation_euler) and tuple(cam.delta_scale) == (1.0, 1.0, 1.0):
        cam.location, cam.rotation_euler = location, euler  # as `hovr render FILE` frames it, to the bit
    else:
        cam.matrix_world = Matrix(look_at_matrix(eye, forward, (0, 0, 1)).tolist())
    cam.data.clip_start, cam.data.clip_end = clip_planes(near, far)
    size = float(np.linalg.norm(corners.max(axis=0) - corners.min(axis=0)))
    cam.data.display_size = max(0.2 * size, 1e-4)  # the default 1 m wire camera would dwarf a 2 cm volume
    _frame_3d_views(context, corners)
    return cam


def _frame_3d_views(context, corners):
    """Every 3D view: a clip range that holds the volume, and (outside camera view) the view
    centred on it. Background mode has no windows; nothing to do there."""
    size = float(np.linalg.norm(corners.max(axis=0) - corners.min(axis=0))) or 1.0
    centre = 0.5 * (corners.min(axis=0) + corners.max(axis=0))
    wm = getattr(context, "window_manager", None)
    for window in (wm.windows if wm is not None else ()):
        for area in window.screen.areas:
            if area.type != 'VIEW_3D':
                continue
            space = area.spaces.active
            space.clip_start = min(space.clip_start, max(1e-3 * size, 1e-6))
            space.clip_end = max(space.clip_end, 100.0 * size)
            r3d = space.region_3d
            if r3d is not None and r3d.view_perspective != 'CAMERA':
                r3d.view_location = centre.tolist()
                r3d.view_distance = 1.5 * size
            area.tag_redraw()


class HOVR_OT_frame_volume(bpy.types.Operator):
    """Move the scene camera (or a new one) so the selected HOVR volumes, or all of them, fill
    the frame, and set its clip start/end from their size"""

    bl_idname = "hovr.frame_volume"
    bl_label = "Frame HOVR Volume"
    bl_options = {'REGISTER', 'UNDO'}

    margin: bpy.props.FloatProperty(name="Margin", default=FRAME_MARGIN, min=1.0, soft_max=3.0,
                                    description="Room around the volumes (1: they touch the frame's edge)")

    @classmethod
    def poll(cls, context):
        return context.scene is not None and any(o.hovr.is_volume for o in context.scene.objects)

    def execute(self, context):
        selected = [o for o in context.selected_objects if o.hovr.is_volume] if hasattr(context, "selected_objects") \
            else []
        objects = selected or [o for o in context.scene.objects if o.hovr.is_volume and o.visible_get()]
        if not objects:
            self.report({'ERROR'}, "HOVR: no visible HOVR volume to frame")
            return {'CANCELLED'}
        cam = frame_volumes(context, objects, self.margin)
        self.report({'INFO'}, f"HOVR: {cam.name} frames {', '.join(o.name for o in objects)} "
                              f"(clip {cam.data.clip_start:.3g}-{cam.data.clip_end:.3g} m)")
        return {'FINISHED'}


def set_look(obj, stops, density: float):
    """The volume's ramp stops and Density (across the volume)."""
    if obj.hovr.transfer_function is None:
        obj.hovr.transfer_function = new_transfer_function_texture(f"{obj.name} Transfer Function")
    obj.hovr.transfer_function.use_color_ramp = True
    set_ramp_stops(obj.hovr.transfer_function.color_ramp, stops)
    obj.hovr.density, obj.hovr.density_units = density, 'RELATIVE'


def apply_look(obj, samples, look: str = FIRST_LOOK):
    """Give the volume a look chosen from its field's samples, (values, volumes) (looks.FIRST_LOOKS),
    over its Value Min/Max: the ramp's stops and Density (across the volume)."""
    values, weights = samples
    set_look(obj, *FIRST_LOOKS[look][2](values, obj.hovr.value_min, obj.hovr.value_max, weights))


def give_first_look(obj, scene, samples=None) -> str | None:
    """An import's Fit Value Range: the volume's Value Min/Max and look from its field's samples,
    (values, volumes) (engine/first_view.first_look, what `hovr render FILE` renders too); returns
    the warning of a field constant up to rounding (it keeps the smooth ramp)."""
    values, weights = volume_samples(obj, scene, samples)
    look = first_look(values, weights=weights)
    obj.hovr.value_min, obj.hovr.value_max = look.value_min, look.value_max
    set_look(obj, look.stops, look.density)
    return look.warning


# The fixed ramps, then the looks chosen from the data (placed by the field's samples over Value
# Min/Max, with their Density). Explicit indices: saved operator presets and keymaps keep working
# if items are reordered.
PRESET_ITEMS = tuple((key, label, desc, i) for i, (key, (label, desc, _)) in enumerate(TF_PRESETS.items())) + tuple(
    (key, f"{label} (from data)", " ".join(fn.__doc__.split()), len(TF_PRESETS) + i)
    for i, (key, (label, _, fn)) in enumerate((k, v) for k, v in FIRST_LOOKS.items() if k not in TF_PRESETS))


class HOVR_OT_transfer_function_preset(_OnVolume, bpy.types.Operator):
    """Replace the transfer function's colour ramp with a preset"""

    bl_idname = "hovr.transfer_function_preset"
    bl_label = "Transfer Function Preset"
    bl_options = {'REGISTER', 'UNDO'}

    preset: bpy.props.EnumProperty(name="Preset", items=PRESET_ITEMS)

    def execute(self, context):
        obj = _volume_object(context)
        if obj.hovr.transfer_function is None:
            obj.hovr.transfer_function = new_transfer_function_texture(f"{obj.name} Transfer Function")
        if self.preset not in TF_PRESETS:  # a look from the data
            try:
                apply_look(obj, volume_samples(obj, context.scene), self.preset)
            except Exception as exc:  # the data cannot be read: say so, change nothing
                self.report({'ERROR'}, f"HOVR: {exc}")
                return {'CANCELLED'}
            return {'FINISHED'}
        texture = obj.hovr.transfer_function
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
        obj = create_volume_object(context, "HOVR Sphere", volume, self.source, location=context.scene.cursor.location)
        obj.hovr.value_min, obj.hovr.value_max = field_range(volume)
        self.report({'INFO'}, f"HOVR: {obj.name}: transfer function over "
                              f"[{obj.hovr.value_min:.3g}, {obj.hovr.value_max:.3g}]")
        return {'FINISHED'}


SURFACES_SCENE_SUFFIX = " Surfaces"


def setup_compositing(scene, engine: str = "CYCLES"):
    """Make `scene` (rendered by HOVR) composite its volumes over another engine's render of
    the same objects: a scene "<name> Surfaces" sharing the scene's objects (its collections and
    objects linked, not copied; camera, world and resolution taken over) rendered by `engine`,
    HOVR set to Holdout surfaces on a transparent film (its Combined pass: the volume in front of
    the surfaces, premultiplied), and the compositor: Alpha Over of HOVR's image on the other's.
    Re-running updates the same scene and replaces the compositor. Returns the surfaces scene."""
    from .compat import alpha_over, new_compositor

    name = scene.name + SURFACES_SCENE_SUFFIX
    other = bpy.data.scenes.get(name) or bpy.data.scenes.new(name)
    root = other.collection
    for child in scene.collection.children:
        if child.name not in root.children:
            root.children.link(child)
    for obj in scene.collection.objects:
        if obj.name not in root.objects:
            root.objects.link(obj)
    other.camera, other.world = scene.camera, scene.world
    other.frame_current = scene.frame_current
    r, o = scene.render, other.render
    o.resolution_x, o.resolution_y, o.resolution_percentage = r.resolution_x, r.resolution_y, r.resolution_percentage
    o.pixel_aspect_x, o.pixel_aspect_y = r.pixel_aspect_x, r.pixel_aspect_y
    o.use_border, o.use_crop_to_border = r.use_border, r.use_crop_to_border
    o.border_min_x, o.border_max_x, o.border_min_y, o.border_max_y = (r.border_min_x, r.border_max_x,
                                                                      r.border_min_y, r.border_max_y)
    o.engine = engine
    o.film_transparent = r.film_transparent
    scene.hovr.surfaces = "HOLDOUT"
    r.film_transparent = True
    tree, image = new_compositor(scene, f"HOVR over {engine.title()}")
    hovr_layer = tree.nodes.new("CompositorNodeRLayers")
    hovr_layer.scene = scene
    surf_layer = tree.nodes.new("CompositorNodeRLayers")
    surf_layer.scene = other
    node, background, foreground = alpha_over(tree)
    tree.links.new(surf_layer.outputs["Image"], background)
    tree.links.new(hovr_layer.outputs["Image"], foreground)
    tree.links.new(node.outputs[0], image)
    surf_layer.location, hovr_layer.location, node.location = (-300, -200), (-300, 200), (0, 0)
    return other


class HOVR_OT_setup_compositing(bpy.types.Operator):
    """Composite HOVR's volumes over Cycles' (or EEVEE's) render of the scene's objects: a scene
    sharing the objects rendered by that engine, HOVR's surfaces set to Holdout on a transparent
    film, and an Alpha Over compositor"""

    bl_idname = "hovr.setup_compositing"
    bl_label = "Set Up Compositing with Surfaces"
    bl_options = {'REGISTER', 'UNDO'}

    engine: bpy.props.EnumProperty(name="Surfaces Engine", items=(
        ("CYCLES", "Cycles", "Render the surfaces with Cycles", 0),
        ("EEVEE", "EEVEE", "Render the surfaces with EEVEE", 1)), default="CYCLES")

    @classmethod
    def poll(cls, context):
        return context.scene is not None and context.scene.render.engine == 'HOVR'

    def execute(self, context):
        from .compat import eevee_engine

        engine = "CYCLES" if self.engine == "CYCLES" else eevee_engine()
        other = setup_compositing(context.scene, engine)
        self.report({'INFO'}, f"HOVR: the volumes are composited over {other.name!r} ({engine.title()})")
        return {'FINISHED'}


def menu_add(self, _context):
    self.layout.operator(HOVR_OT_add_sphere_volume.bl_idname, icon='VOLUME_DATA')


def menu_view(self, _context):
    self.layout.operator(HOVR_OT_frame_volume.bl_idname, icon='VIEW_CAMERA')


classes = (HOVR_OT_new_transfer_function, HOVR_OT_fit_value_range, HOVR_OT_transfer_function_preset,
           HOVR_OT_add_sphere_volume, HOVR_OT_frame_volume, HOVR_OT_setup_compositing)


def register():
    for cls in classes:
        bpy.utils.register_class(cls)
    bpy.types.VIEW3D_MT_add.append(menu_add)
    bpy.types.VIEW3D_MT_view.append(menu_view)


def unregister():
    bpy.types.VIEW3D_MT_view.remove(menu_view)
    bpy.types.VIEW3D_MT_add.remove(menu_add)
    for cls in reversed(classes):
        bpy.utils.unregister_class(cls)
