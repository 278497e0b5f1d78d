"""What the HOVR render engine does, as plain functions (engine.py's RenderEngine only calls
these): snapshot the depsgraph into plain records, call the core, write pixels; the viewport's
step and drawing.

No bpy.context and no operators during a final render, and nothing in the user's data is
written. The core's renderer is imported lazily so that registering the add-on does not
import Warp. The viewport's scheduling lives in viewport.py (no bpy).
"""
from __future__ import annotations

import time
import weakref
from dataclasses import dataclass, field

import bpy
import numpy as np

from .camera import border_region, ray_camera_from_blender, ray_camera_from_view, render_size, sub_camera
from ..engine.cache import LRUCache
from ..io.sources import VolumeSource, cached_volume
from ..io.sources import clear_cache as clear_mesh_cache
from . import compat
from .compat import write_pass_pixels
from .jobs import KERNELS, ProgressLines, kernel_key
from .scene import combined_pass, depth_pass, flip_rows, render_background, transfer_function_from_ramp

# Pixels per kernel launch between test_break() checks in F12. A CPU launch runs on one
# thread: 256 pixels cost ~5 ms on the sphere and stay well under the 0.5 s cancel target
# even at ~1 ms per pixel; a GPU needs big launches to fill it and finishes them in ms.
TILE_PIXELS = {"cpu": 256}
TILE_PIXELS_GPU = 1 << 20  # progress and cancel every 2^20 pixels: a tile ends in rounds of few rays, which leave a GPU idle
# Viewport work per view_draw call (seconds): the UI stays responsive between calls.
VIEW_BUDGET_SECONDS = 0.05


# Viewport states of the live engines, for diagnostics and the windowed test (weak: they go
# with their engine when the user leaves Rendered shading).
VIEWPORTS = weakref.WeakSet()


class SceneError(ValueError):
    """The scene cannot be rendered by HOVR; the message tells the user what to fix."""


@dataclass
class VolumeInputs:
    """One HOVR volume: its data, where it is, and its look as the contract's transfer function
    still to be scaled: `density` in `density_units` (framing.density_per_world_unit)."""

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


# A new engine instance is created for every render, so uploaded meshes live here, keyed by
# what determines them; two entries cover toggling an object transform, the device, or the
# previous and current frame of an animation.
RENDERERS = LRUCache(2)
# The scene's opaque meshes uploaded for the ray cast (engine.opaque.OpaqueScene), by geometry digest and device.
OPAQUE = LRUCache(2)
# Object-space bounding boxes of loaded volumes, by source key (for relative density, framing).
EXTENTS = LRUCache(16)


def volume_extent(source: VolumeSource) -> tuple:
    """(lo, hi) object-space bounding box of a volume's elements (their corner vertices)."""
    def measure():
        v = cached_volume(source).vertices.reshape(-1, 3)
        return v.min(axis=0), v.max(axis=0)

    return EXTENTS.get(source.key, measure)


POINTS = LRUCache(8)
MAX_FRAMING_POINTS = 50_000


def volume_points(source: VolumeSource) -> np.ndarray:
    """(n, 3) object-space element corners of a volume (at most ~MAX_FRAMING_POINTS, evenly
    strided): what framing fits, tighter than the bounding box for round domains."""
    def collect():
        v = np.unique(cached_volume(source).vertices.reshape(-1, 3), axis=0)
        step = max(1, len(v) // MAX_FRAMING_POINTS)
        return v[::step]

    return POINTS.get(source.key, collect)


def _renderer(volumes, device: str):
    """(Renderer, number of elements) of the volumes (VolumeInputs), each placed by its object
    matrix and merged into one mesh (engine.mesh.concatenate: element e tagged with its volume,
    one BVH, one pass). A file is re-read only when its path (the frame's file), size or
    mtime changes: the object-space meshes come from io.sources.cached_volume, so a moved
    object or another device uploads again without reading the file."""
    def upload():
        from ..engine.mesh import concatenate
        from ..engine.multi_device import make_renderer  # "cuda:all": every GPU (engine/multi_device.py)

        meshes = [cached_volume(v.source).transformed(np.array(v.object_matrix).reshape(4, 4)) for v in volumes]
        mesh = concatenate(meshes)
        return make_renderer(mesh, device), mesh.num_elements

    return RENDERERS.get((tuple(v.data_key for v in volumes), device), upload)


def opaque_scene(inputs: SceneInputs):
    """The uploaded OpaqueScene of the scene's opaque meshes (cached), or None: off, or none there."""
    if inputs.opaque_mode == "NONE" or not inputs.opaque_meshes:
        return None
    from ..engine.multi_device import expand_devices
    from ..engine.opaque import OpaqueScene

    device = expand_devices(inputs.options.device)[0]  # the ray cast runs on one device (the first)
    return OPAQUE.get((inputs.opaque_key, device), lambda: OpaqueScene(inputs.opaque_meshes, device))


def scene_frame(inputs: SceneInputs, cache=None):
    """The engine's Frame of the scene (resolve_units first): its looks, background, settings,
    opaque meshes, isosurfaces and planes; `cache`, a SegmentSlot."""
    from ..engine.frame import Frame

    mode = inputs.opaque_mode if inputs.opaque_mode != "NONE" else "SHADED"
    return Frame(inputs.transfer_function, inputs.background, inputs.options, opaque=opaque_scene(inputs),
                 opaque_mode=mode, surfaces=inputs.surfaces or None, cache=cache)


@dataclass
class FinalCache:
    """F12's element segments, kept on the device for the next F12 (a Frame's SegmentSlot,
    engine/frame.py). A view's segments are traced at its second F12 (the first renders plainly
    and only remembers the view): a one-off render, or an animation whose frames change the data
    or the camera, never pays for a trace it would not reuse; from then on, F12 after an edit of the
    look alone (transfer function, density, colours, background, tolerance) shades from the cache."""

    view: tuple | None = None  # the last F12's view (Renderer.trace_key)
    slot: object = None  # its SegmentSlot, once the view came twice
    refused: bool = False  # the view's cache did not fit the memory limit: not tried again

    @property
    def cache(self):
        """The core SegmentCache kept, or None."""
        return None if self.slot is None else self.slot.cache

    def clear(self):
        self.view, self.slot, self.refused = None, None, False


FINAL = FinalCache()


def render_final(renderer, inputs: SceneInputs, camera, progress=None, tile_pixels=None):
    """F12's frame (scene_frame) through FINAL: shaded from the last F12's segments where they hold
    this view, traced (and kept) where the last F12 had the same view, else a plain render."""
    from ..engine.frame import Capability, SegmentSlot, render_frame

    frame = scene_frame(inputs)
    if Capability.SEGMENT_CACHE not in renderer.capabilities:  # several devices keep no segments
        FINAL.clear()
        return render_frame(renderer, frame, camera, progress=progress, tile_pixels=tile_pixels)
    view = renderer.trace_key(camera, inputs.options, surface_key=frame.opaque_meshes)
    if view != FINAL.view:
        FINAL.clear()
        FINAL.view = view  # a new view: its segments only if it comes again
    elif not FINAL.refused:
        FINAL.slot = FINAL.slot or SegmentSlot()
        frame = frame.with_(cache=FINAL.slot)
    result = render_frame(renderer, frame, camera, progress=progress, tile_pixels=tile_pixels)
    if frame.cache is not None:
        FINAL.refused = "refused" in result.stats.get("segment_cache", {})
    return result


def world_diagonal(v: VolumeInputs) -> float:
    """The volume's bounding-box diagonal in world units (its data read once and cached)."""
    from .framing import volume_diagonal

    lo, hi = volume_extent(v.source)
    return volume_diagonal(lo, hi, np.array(v.object_matrix).reshape(4, 4))


def render_kernel_key(renderer, inputs: SceneInputs) -> tuple:
    """The jobs.kernel_key of rendering the scene's volumes with `renderer`."""
    return kernel_key(inputs.options.device, inputs.options.precision, renderer.kernel_variant,
                      inputs.opaque_mode != "NONE", bool(inputs.surfaces))


def resolve_units(inputs: SceneInputs) -> SceneInputs:
    """What is given relative to the volumes' sizes, in the render contract's absolute units:
    each volume's transfer function per world unit (a relative density becomes density / the
    volume's diagonal; inputs.transfer_functions) and the step h in world units (a relative
    step: the smallest volume's diagonal / Steps Across; inputs.options.h). A view file means
    what it always meant: only these numbers reach the core."""
    from dataclasses import replace

    from .framing import density_per_world_unit, step_world_length

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


def clear_cache():
    RENDERERS.clear()
    FINAL.clear()
    OPAQUE.clear()
    EXTENTS.clear()
    POINTS.clear()
    clear_mesh_cache()


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
    """(transfer function, Value Min, Value Max, title) of a volume's look, for its legend
    (ui/legend_overlay.py); ValueError where the look cannot be drawn."""
    from .versioning import volume_look

    look = volume_look(obj.hovr, scene)
    texture = look.texture
    if texture is None or not texture.use_color_ramp or texture.color_ramp is None:
        raise SceneError(f"{obj.name!r} has no transfer function ramp")
    ramp = texture.color_ramp
    tf = transfer_function_from_ramp(ramp.interpolation, ramp.color_mode, [e.position for e in ramp.elements],
                                     [tuple(e.color) for e in ramp.elements], 1.0, look.value_min, look.value_max)
    return tf, float(look.value_min), float(look.value_max), obj.hovr.field or obj.name


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
    from .surface_panels import plane_object_names, scene_isosurfaces

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


def snapshot(engine: bpy.types.RenderEngine, depsgraph) -> RenderJob:
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


def clip_warnings(job: RenderJob, camera_name: str) -> list:
    """The volumes (data loaded) that the camera's clip planes hide, in words."""
    from .framing import box_corners, clip_warning, transform_points

    near, far = job.camera.extra.get("clip", (0.0, float("inf")))
    eye = np.asarray(job.camera.extra.get("eye", job.camera.o0), dtype=np.float64)
    fwd = np.asarray(job.camera.extra.get("forward", job.camera.d0), dtype=np.float64)
    out = []
    for v in job.inputs.volumes:
        lo, hi = volume_extent(v.source)
        corners = transform_points(box_corners(lo, hi), np.array(v.object_matrix).reshape(4, 4))
        w = clip_warning(corners, eye, fwd, near, far, camera=f"camera {camera_name!r}")
        if w:
            out.append(f"HOVR: {v.name}: {w}")
    return out


def failure_text(exc: BaseException) -> str:
    """One line for the user: the message of an error the code raises on purpose (the readers'
    and the resource policy's ValueErrors, a device failure), the type as well otherwise."""
    if isinstance(exc, MemoryError):
        return "out of memory (lower the image size or the data's size, or set HOVR_MAX_MEMORY below " \
               "what this machine has so that such a render is refused before it starts)"
    if isinstance(exc, ImportError) and getattr(exc, "name", None):
        from .dependencies import dependencies, report_lines

        dep = [d for d in dependencies() if d[0] == exc.name.split(".")[0]]
        if dep:
            return " ".join(report_lines(dep)).replace("HOVR: ", "")
    if isinstance(exc, (ValueError, OSError)):
        return str(exc)
    return f"{type(exc).__name__}: {exc}"


def tile_pixels(device: str) -> int:
    return TILE_PIXELS.get(device, TILE_PIXELS_GPU)


def render_stats(stats: dict, n_elements: int, seconds: float, device: str, load_seconds: float = 0.0) -> str:
    """Status-line text: elements, samples per ray, time (tracing, and reading if it took long)."""
    n = int(stats.get("elements", n_elements))
    parts = [f"{n} element{'s' if n != 1 else ''}"]
    if "samples_per_ray" in stats:
        parts.append(f"{stats['samples_per_ray']:.1f} samples/ray")
    if "field_evaluations" in stats:
        parts.append(f"{int(stats['field_evaluations']):,} field evaluations")
    parts.append(f"{seconds:.2f} s on {device}")
    if load_seconds >= 0.5:
        parts.append(f"{load_seconds:.1f} s loading the data and the kernels")
    return "HOVR | " + " | ".join(parts)


@dataclass
class ViewportFrame:
    pixels: np.ndarray  # (H, W, 4) float32, row 0 at the bottom
    version: int
    converged: bool
    stage: str


def viewport_request(context, depsgraph):
    """(renderer, ViewportRequest) of a 3D viewport: the region's own camera (rv3d matrices,
    camera view included) and the scene's data and settings."""
    from .viewport import ViewportRequest

    region, rv3d = context.region, context.region_data
    camera = ray_camera_from_view(rv3d.window_matrix, rv3d.view_matrix, region.width, region.height)
    inputs = scene_inputs(depsgraph, original=True)
    renderer, _n = _renderer(inputs.volumes, inputs.options.device)
    resolve_units(inputs)
    from ..engine.frame import check_frame

    frame = scene_frame(inputs)
    check_frame(renderer, frame)  # what this renderer cannot draw, said before any work
    return renderer, ViewportRequest(camera=camera, frame=frame, film_transparent=inputs.film_transparent,
                                     data_key=inputs.data_key)


def viewport_step(state, context, depsgraph, budget=VIEW_BUDGET_SECONDS) -> ViewportFrame:
    """All of view_draw except the GPU upload: detect changes (view changes arrive only
    here: moving the view does not call view_update), do a bounded amount of work, return the frame to show."""
    return advance_viewport(state, *viewport_request(context, depsgraph), budget)


def advance_viewport(state, renderer, request, budget=VIEW_BUDGET_SECONDS) -> ViewportFrame:
    state.sync(renderer, request)
    state.step(budget)
    return ViewportFrame(state.display, state.version, state.converged, state.stage)


def fail(api, message: str):
    """report() reaches the status bar and makes bpy.ops.render.render raise for scripts;
    error_set() as well would only repeat the message."""
    api.report({'ERROR'}, message)
    api.update_stats("", f"HOVR | {message}")


def declare_passes(engine, scene, renderlayer):
    """The passes the compositor's Render Layers node offers."""
    engine.register_pass(scene, renderlayer, "Combined", 4, "RGBA", 'COLOR')
    if renderlayer.use_pass_z:
        engine.register_pass(scene, renderlayer, "Depth", 1, "Z", 'VALUE')
    hovr = getattr(renderlayer, "hovr", None)
    if hovr is not None and hovr.use_pass_error:
        engine.register_pass(scene, renderlayer, "HOVR Error", 1, "X", 'VALUE')


def stage_reporter(api, background: bool, printed_by_blender: bool):
    """status(text, fraction=None): the stage or progress in the status bar (update_stats); in
    background mode, where the output is the log, progress only a few times a frame
    (jobs.ProgressLines), each line printed by HOVR where Blender does not print update_stats
    itself (5.0; 4.x prints each one)."""
    lines = ProgressLines()

    def status(text: str, fraction: float | None = None):
        if background and fraction is not None and not lines.due(fraction):
            return
        api.update_stats("", text)
        if background and not printed_by_blender:
            print(text, flush=True)

    return status


def final_render(engine, api, depsgraph):
    """F12: snapshot, load (cached), render in progress tiles, write the passes. Blender's
    progress/break/stats calls go through `api` (the engine itself; tests wrap it, since RNA
    methods cannot be patched on the class)."""
    status = stage_reporter(api, bpy.app.background, compat.update_stats_printed_in_background())
    status("HOVR | reading scene")
    try:
        job = snapshot(engine, depsgraph)
    except ValueError as exc:  # SceneError and the core's Camera/TransferFunction/Mesh/View errors
        fail(api, str(exc))
        return
    except Exception as exc:  # a bug must still end as a report, never as a traceback mid-render
        fail(api, f"HOVR render failed: unexpected {type(exc).__name__}: {exc}")
        return
    for w in job.warnings:
        api.report({'WARNING'}, w)

    device = job.options.device
    names = ", ".join(v.name for v in job.inputs.volumes)
    status(f"HOVR | loading {names} into the renderer")  # read now unless the import or a render kept it
    t0 = time.perf_counter()
    try:
        renderer, n_elements = _renderer(job.inputs.volumes, device)
        resolve_units(job.inputs)
        key = render_kernel_key(renderer, job.inputs)
    except Exception as exc:  # the readers' refusals; ImportError: warp-lang missing from Blender's Python
        fail(api, f"HOVR render failed: {failure_text(exc)}")
        return
    cam_name = (engine.camera_override or depsgraph.scene_eval.camera).name
    warnings = clip_warnings(job, cam_name)
    for w in warnings:
        api.report({'WARNING'}, w)
    if api.test_break():
        return
    try:
        if not KERNELS.is_ready(key):  # their first use in this session: tens of seconds on a CPU
            stage, note = KERNELS.stage(key)
            if note:
                api.report({'WARNING'}, f"HOVR: {note}")
            status(f"HOVR | {n_elements} elements | {stage}\u2026")
            KERNELS.compile_now(key)
    except Exception as exc:
        fail(api, f"HOVR render failed: {failure_text(exc)}")
        return
    if api.test_break():
        return
    t1 = time.perf_counter()

    def progress(fraction):
        api.update_progress(fraction)
        status(f"HOVR | {n_elements} elements | tracing rays {100 * fraction:.0f}% | "
               f"{time.perf_counter() - t1:.1f} s", fraction)
        return not api.test_break()

    try:
        result = render_final(renderer, job.inputs, job.camera, progress=progress, tile_pixels=tile_pixels(device))
        from .legend_render import with_legend

        shown, legend_warning = with_legend(depsgraph.scene_eval, depsgraph.view_layer_eval, result.rgba,
                                            job.inputs.background)
        pixels = combined_pass(shown, job.film_transparent)
    except Exception as exc:
        fail(api, f"HOVR render failed: {failure_text(exc)}")
        return
    if result.cancelled or api.test_break():
        status("HOVR | cancelled")
        return
    for w in result.stats.get("warnings", []) + ([legend_warning] if legend_warning else []):
        api.report({'WARNING'}, f"HOVR: {w}")
    from .framing import image_warning

    empty = image_warning(result.rgba[..., 3])
    if empty:
        api.report({'WARNING'}, f"HOVR: {empty}")
        warnings.append(f"HOVR: {empty}")

    res = engine.begin_result(0, 0, job.width, job.height)
    if (res.resolution_x, res.resolution_y) != (job.width, job.height):
        # Blender chose another border region than border_region() computed: writing
        # would misplace pixels, so drop the result instead.
        engine.end_result(res, cancel=True)
        fail(api, f"HOVR render failed: Blender's result is {res.resolution_x}x{res.resolution_y}, "
                  f"HOVR rendered {job.width}x{job.height}")
        return
    passes = {p.name: p for p in res.layers[0].passes}
    write_pass_pixels(passes["Combined"], pixels)
    if "Depth" in passes:
        write_pass_pixels(passes["Depth"], depth_pass(job.camera, result.depth, result.rgba[..., 3]))
    if "HOVR Error" in passes:
        write_pass_pixels(passes["HOVR Error"], flip_rows(result.error))
    engine.end_result(res)
    api.update_progress(1.0)
    text = render_stats(result.stats, n_elements, result.stats.get("render_seconds", time.perf_counter() - t1), device,
                        load_seconds=t1 - t0)
    if warnings:  # the status line keeps the last word: say the picture is suspect there too
        text += f" | WARNING: {warnings[-1].removeprefix('HOVR: ')}"
    status(text)


def view_update(engine, context, depsgraph):
    """Data changes: view_draw re-reads everything and restarts on any difference; here only
    make sure the mesh upload (and Warp start-up) happens outside view_draw."""
    try:
        inputs = scene_inputs(depsgraph, original=True)
        _renderer(inputs.volumes, inputs.options.device)
    except Exception:
        pass  # view_draw shows the message
    engine.tag_redraw()


def view_draw(engine, context, depsgraph):
    """One bounded step of the progressive viewport, then draw what there is. The render
    kernels' first use compiles them here (the status line says so first)."""
    try:
        renderer, request = viewport_request(context, depsgraph)
        options = request.frame.options
        key = kernel_key(options.device, options.precision, renderer.kernel_variant,
                         depsgraph.scene.hovr.surfaces != "NONE", bool(request.frame.surfaces))
        if not KERNELS.is_ready(key):
            engine.update_stats("", f"HOVR | {KERNELS.stage(key)[0]}\u2026")
            KERNELS.compile_now(key)
        shown = advance_viewport(engine.viewport, renderer, request)
        engine.viewport_error = None
    except Exception as exc:
        message = f"HOVR: {failure_text(exc)}"
        if message != engine.viewport_error:
            engine.viewport_error = message
            engine.report({'WARNING'}, message)
        draw_message(message)
        return
    if not shown.converged:
        engine.tag_redraw()  # keep view_draw coming until the final image is drawn
    if shown.pixels is not None:
        draw_pixels(engine, depsgraph.scene, context.region, shown)
    text = engine.viewport.status_text()
    if text != getattr(engine, "viewport_status", None):
        engine.viewport_status = text
        engine.update_stats("", text)  # Blender shows it in the viewport's corner, as Cycles' samples



def draw_pixels(engine, scene, region, frame):
    import gpu  # lazily: background mode has no GPU module
    from gpu_extras.presets import draw_texture_2d

    h, w = frame.pixels.shape[:2]
    if engine.texture is None or engine.texture[0] != frame.version:
        buf = gpu.types.Buffer('FLOAT', w * h * 4, frame.pixels.ravel())
        # RGBA32F: half floats would overflow to inf for bright emission
        engine.texture = (frame.version, gpu.types.GPUTexture((w, h), format='RGBA32F', data=buf))
    gpu.state.blend_set('ALPHA_PREMULT')
    engine.bind_display_space_shader(scene)
    draw_texture_2d(engine.texture[1], (0, 0), region.width, region.height)
    engine.unbind_display_space_shader()
    gpu.state.blend_set('NONE')


def draw_message(message):
    import blf

    blf.position(0, 20, 50, 0)  # above the last operator's panel in the corner
    blf.size(0, 14)
    blf.color(0, 1.0, 0.4, 0.3, 1.0)
    blf.draw(0, message[:200])
