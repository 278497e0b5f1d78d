"""What the panels, operators and renderers read from the scene, as plain records: each HOVR
volume (VolumeInputs: its data source at the scene's frame, object matrix and look), the scene's
settings, background, opaque meshes, isosurfaces and planes (SceneInputs), F12's camera and
region (RenderJob), and the loaded data's extents and points (cached by source key). Below
render.py, the panels and the operators, so that none of them imports another in a circle."""
from __future__ import annotations

from dataclasses import dataclass, field

import bpy
import numpy as np

from ..engine.first_view import framing_points
from ..engine.lru_cache import LRUCache
from ..engine.isosurfaces import CLIP_SIDES
from ..io.sources import VolumeSource, cached_volume
from .blender_camera import border_region, ray_camera_from_blender, render_size, sub_camera
from .scene import render_background, transfer_function_from_ramp


class SceneError(ValueError):
    """The scene cannot be rendered by HOVR; the message tells the user what to fix."""


@dataclass
class VolumeInputs:
    """One HOVR volume: its data, where it is, and its look as the contract's transfer function
    still to be scaled: `density` in `density_units` (engine/first_view.density_per_world_unit)."""

    name: str
    source: VolumeSource
    object_matrix: tuple
    transfer_function: object  # TransferFunction with density scale 1 (ramp alpha)
    density: float
    density_units: str

    @property
    def data_key(self) -> tuple:
        return (self.source.key, self.object_matrix)


@dataclass
class SceneInputs:
    """What a final render and the viewport share: the volumes, settings, background."""

    volumes: list  # [VolumeInputs], sorted by object name
    background: np.ndarray
    film_transparent: bool
    options: object  # RenderOptions
    warnings: list = field(default_factory=list)
    transfer_functions: list | None = None  # per volume, per world unit: resolve_units() sets it
    opaque_meshes: list = field(default_factory=list)  # [engine.opaque.OpaqueMesh] (ui/opaque_meshes.py)
    opaque_mode: str = "NONE"  # Scene.hovr.surfaces (its saved name): NONE, SHADED or HOLDOUT
    opaque_key: str = ""  # digest of the opaque meshes (ui/opaque_meshes.opaque_key)
    # Scene.hovr's step: options.h is in world units once resolve_units() ran (a relative step
    # needs the volumes' sizes, i.e. their data)
    step_units: str = "WORLD"
    steps_across: int = 0
    surfaces: object = None  # engine.isosurfaces.Surfaces: the volumes' isosurfaces and planes (ui/surface_panels.py)

    @property
    def data_key(self) -> tuple:
        return (tuple(v.data_key for v in self.volumes), self.options.device, self.opaque_mode, self.opaque_key)

    @property
    def transfer_function(self):
        """The core's argument: one TransferFunction per volume (resolve_units first)."""
        if self.transfer_functions is None:
            raise RuntimeError("resolve_units() has not run")
        return self.transfer_functions


@dataclass
class RenderJob:
    width: int  # of the rendered region (the border's size under a render border)
    height: int
    camera: object  # RayCamera of the region
    inputs: SceneInputs
    region: tuple = (0, 0, 0, 0)  # (x0, y0 from the bottom, w, h) in the full frame

    @property
    def transfer_function(self):
        return self.inputs.transfer_function

    @property
    def background(self):
        return self.inputs.background

    @property
    def film_transparent(self):
        return self.inputs.film_transparent

    @property
    def options(self):
        return self.inputs.options

    @property
    def warnings(self):
        return self.inputs.warnings


# Object-space bounding boxes of loaded volumes, by source key (for relative density, framing).
EXTENTS = LRUCache(16)


def volume_extent(source: VolumeSource) -> tuple:
    """(lo, hi) object-space bounding box of a volume's elements (their corner vertices)."""
    def measure():
        v = cached_volume(source).vertices.reshape(-1, 3)
        return v.min(axis=0), v.max(axis=0)

    return EXTENTS.get(source.key, measure)


POINTS = LRUCache(8)


def volume_points(source: VolumeSource) -> np.ndarray:
    """(n, 3) object-space points that Frame Camera fits (engine/first_view.framing_points)."""
    return POINTS.get(source.key, lambda: framing_points(cached_volume(source)))


def volume_source(obj, scene):
    """The volume's data (io.sources.VolumeSource) at the scene's frame."""
    return VolumeSource.resolve(obj.hovr.source, obj.hovr.solution, obj.hovr.field, scene.frame_current,
                                abspath=lambda p: bpy.path.abspath(p, library=obj.library), component=obj.hovr.component)


def world_diagonal(v: VolumeInputs) -> float:
    """The volume's bounding-box diagonal in world units (its data read once and cached)."""
    from ..engine.first_view import volume_diagonal

    lo, hi = volume_extent(v.source)
    return volume_diagonal(lo, hi, np.array(v.object_matrix).reshape(4, 4))


def resolve_units(inputs: SceneInputs) -> SceneInputs:
    """What is given relative to the volumes' sizes, in the render contract's absolute units:
    each volume's transfer function per world unit (a relative density becomes density / the
    volume's diagonal; inputs.transfer_functions) and the step h in world units (a relative
    step: the smallest volume's diagonal / Steps Across; inputs.options.h). A view file means
    what it always meant: only these numbers reach the core."""
    from dataclasses import replace

    from ..engine.first_view import density_per_world_unit
    from .framing import step_world_length

    tfs = []
    for v in inputs.volumes:
        diag = world_diagonal(v) if v.density_units != "WORLD" else 0.0
        scale = density_per_world_unit(v.density, v.density_units, diag)
        tf = v.transfer_function
        tfs.append(replace(tf, density_tau=np.asarray(tf.density_tau, dtype=np.float64) * scale))
    inputs.transfer_functions = tfs
    if inputs.step_units != "WORLD":
        try:
            h = step_world_length(inputs.options.h, inputs.steps_across, inputs.step_units,
                                  [world_diagonal(v) for v in inputs.volumes])
        except ValueError as exc:
            raise SceneError(str(exc)) from exc
        inputs.options = replace(inputs.options, h=h)
        inputs.step_units = "WORLD"  # resolved: options.h is the world step now
    return inputs


def _matrix_tuple(m) -> tuple:
    return tuple(float(x) for row in m for x in row)


def volume_objects(depsgraph, original: bool = False) -> list:
    """The HOVR volumes the depsgraph shows, by name (a stable order: volume k of the merged mesh)."""
    def hovr_of(o):
        return o.original.hovr if original else o.hovr

    return sorted((o for o in depsgraph.objects if hovr_of(o).is_volume), key=lambda o: o.name)


def volume_inputs(obj, hovr, scene) -> VolumeInputs:
    """One volume's record: its data source at the scene's frame and its look."""
    from .versioning import volume_look

    library = obj.original.library if obj.original is not None else None
    if not hovr.source.strip():
        raise SceneError(f"the HOVR volume {obj.name!r} has no source: set Object > HOVR Volume > Source")
    source = VolumeSource.resolve(hovr.source, hovr.solution, hovr.field, scene.frame_current,
                                  abspath=lambda p: bpy.path.abspath(p, library=library), component=hovr.component)
    look = volume_look(hovr, scene)
    texture = look.texture
    if texture is None:
        raise SceneError(f"the HOVR volume {obj.name!r} has no transfer function: create one in "
                         "Object > HOVR Volume > Look")
    if not texture.use_color_ramp or texture.color_ramp is None:
        raise SceneError(f"transfer function texture {texture.name!r} of {obj.name!r} has no colour ramp enabled")
    ramp = texture.color_ramp
    try:
        tf = transfer_function_from_ramp(
            ramp.interpolation, ramp.color_mode,
            [e.position for e in ramp.elements], [tuple(e.color) for e in ramp.elements],
            1.0, look.value_min, look.value_max,
        )
    except ValueError as exc:
        raise SceneError(f"{obj.name!r}: {exc}") from exc
    if not (np.isfinite(look.density) and look.density >= 0):
        raise SceneError(f"{obj.name!r}: density must be >= 0, got {look.density:.6g}")
    return VolumeInputs(name=obj.name, source=source, object_matrix=_matrix_tuple(obj.matrix_world),
                        transfer_function=tf, density=float(look.density), density_units=look.density_units)


def legend_volume_inputs(obj, scene):
    """(transfer function, Value Min, Value Max, title, units) of a volume's look, for its legend
    (ui/legend_overlay.py); ValueError where the look cannot be drawn."""
    from .versioning import volume_look

    look = volume_look(obj.hovr, scene)
    texture = look.texture
    if texture is None or not texture.use_color_ramp or texture.color_ramp is None:
        raise SceneError(f"{obj.name!r} has no transfer function ramp")
    ramp = texture.color_ramp
    tf = transfer_function_from_ramp(ramp.interpolation, ramp.color_mode, [e.position for e in ramp.elements],
                                     [tuple(e.color) for e in ramp.elements], 1.0, look.value_min, look.value_max)
    return tf, float(look.value_min), float(look.value_max), obj.hovr.field or obj.name, obj.hovr.units.strip()


def scene_isosurfaces(objects):
    """The engine's Surfaces of the volumes `objects` (volume k: objects[k], volume_objects'
    order): each one's isosurfaces, and the planes of all of them (one per plane object)."""
    import numpy as np

    from ..engine.isosurfaces import CutPlane, Isosurface, Surfaces

    isos, planes, seen = [], [], set()
    for k, obj in enumerate(objects):
        settings = obj.original.hovr_surfaces if obj.original is not None else obj.hovr_surfaces
        for item in settings.isosurfaces:
            isos.append(Isosurface(float(item.value), tuple(float(c) for c in item.color), float(item.opacity), k))
        for item in settings.planes:
            plane = item.object
            if plane is None or plane.name in seen:
                continue
            seen.add(plane.name)
            m = np.array(plane.matrix_world)
            planes.append(CutPlane.through(m[:3, 3], m[:3, 2], float(item.opacity), CLIP_SIDES[item.clip]))
    return Surfaces(tuple(isos), tuple(planes))


def plane_object_names(objects) -> set:
    """The names of the objects the volumes use as cut planes (they are no opaque surfaces)."""
    names = set()
    for obj in objects:
        settings = obj.original.hovr_surfaces if obj.original is not None else obj.hovr_surfaces
        names |= {item.object.name for item in settings.planes if item.object is not None}
    return names


def scene_inputs(depsgraph, original: bool = False) -> SceneInputs:
    """The volumes, their looks and the settings of the scene, as plain records.

    F12 reads the evaluated scene of its freshly built render depsgraph. The viewport's
    depsgraph is not re-evaluated when only add-on (Python-defined) properties change, so
    it reads those from the original datablocks (`original=True`); object matrices always
    come from the evaluated objects. Call resolve_units() before using the transfer functions or
    the step (options.h)."""
    from ..engine.view import RenderOptions

    scene = depsgraph.scene if original else depsgraph.scene_eval
    render = scene.render
    settings = scene.hovr
    objects = volume_objects(depsgraph, original)
    if not objects:
        raise SceneError("no HOVR volume in the scene: import one (File > Import > HOVR ...) or add one with "
                         "Add > HOVR Sphere Volume")
    volumes = [volume_inputs(o, o.original.hovr if original else o.hovr, scene) for o in objects]
    world_color = tuple(scene.world.color) if scene.world is not None else None
    options = RenderOptions(method=settings.method, h=settings.h, tolerance=settings.tolerance,
                            min_transmittance=settings.min_transmittance, device=settings.device,
                            precision=settings.precision)
    try:
        isosurfaces = scene_isosurfaces(objects)
    except ValueError as exc:
        raise SceneError(str(exc)) from exc
    mode = settings.surfaces  # the opaque meshes' mode (its saved name)
    opaque, key = [], ""
    if mode != "NONE":
        from .opaque_meshes import opaque_key, scene_opaque_meshes

        planes = plane_object_names(objects)  # cut planes are no opaque meshes
        opaque = [m for m in scene_opaque_meshes(depsgraph) if m.name.rpartition("[")[0] not in planes]
        key = opaque_key(opaque)
    return SceneInputs(volumes=volumes, background=render_background(world_color, render.film_transparent),
                       film_transparent=bool(render.film_transparent), options=options, opaque_meshes=opaque,
                       opaque_mode=mode, opaque_key=key, step_units=settings.step_units,
                       steps_across=int(settings.steps_across), surfaces=isosurfaces)


def render_job(engine: bpy.types.RenderEngine, depsgraph) -> RenderJob:
    """Everything render() needs, as plain data, read from the evaluated depsgraph. Adds
    a warning for each volume the camera's clip planes hide in whole or in part."""
    scene = depsgraph.scene_eval
    render = scene.render
    cam = engine.camera_override or scene.camera
    if cam is None:
        raise SceneError("no camera: set the scene's active camera (or use Frame Volume, which makes one)")
    camera = ray_camera_from_blender(cam, depsgraph, render)
    inputs = scene_inputs(depsgraph)
    width, height = render_size(render)
    x0, y0, w, h = border_region(width, height, render.use_border, render.border_min_x, render.border_max_x,
                                 render.border_min_y, render.border_max_y)
    if (w, h) != (width, height):
        camera = sub_camera(camera, x0, height - y0 - h, w, h)  # sub_camera counts rows from the top
    return RenderJob(width=w, height=h, camera=camera, inputs=inputs, region=(x0, y0, w, h))
