"""What the HOVR render engine does, as plain functions (engine.py's RenderEngine only calls
these): read the scene into plain records (snapshot.py), render the scene's Frame through the
engine's one door (engine/frame.render_frame), write pixels; the viewport's step and drawing.

No bpy.context and no operators during a final render, and nothing in the user's data is
written. The core's renderer is imported lazily so that registering the add-on does not
import Warp. The viewport's scheduling lives in viewport.py (no bpy).
"""
from __future__ import annotations

import time
import weakref
from dataclasses import dataclass

import bpy
import numpy as np

from .blender_camera import ray_camera_from_view
from ..engine.lru_cache import LRUCache
from ..engine.words import plural
from ..io.sources import cached_volume
from ..io.sources import clear_cache as clear_mesh_cache
from . import compat
from .compat import write_pass_pixels
from .jobs import KERNELS, ProgressLines, kernel_key
from .scene import combined_pass, depth_pass, flip_rows
from .snapshot import (EXTENTS, POINTS, RenderJob, SceneInputs, render_job, resolve_units, scene_inputs,
                       volume_extent)

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


# A new engine instance is created for every render, so uploaded meshes live here, keyed by
# what determines them; two entries cover toggling an object transform, the device, or the
# previous and current frame of an animation.
RENDERERS = LRUCache(2)
# The scene's opaque meshes uploaded for the ray cast (engine.opaque.OpaqueScene), by geometry digest and device.
OPAQUE = LRUCache(2)


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
    """F12's element segments, kept on the device (or the devices, All CPU Cores and All GPUs) for
    the next F12 (a Frame's SegmentSlot, engine/frame.py): the first F12 of a view traces them and
    shades its image from them, so the next F12 after an edit of the look alone (transfer function,
    density, colours, background, tolerance) shades from the cache without tracing again. A frame
    of an animation, or a render that will not be repeated (`once`: render-blend's frames, each in a
    Blender of its own), renders plainly: it would pay for a trace it never reuses."""

    view: tuple | None = None  # the last traced view (Renderer.trace_key)
    slot: object = None  # its SegmentSlot
    refused: bool = False  # the view's cache did not fit the memory limit: not tried again
    once: bool = False  # every render is a one-off (ui/batch.py sets it)

    @property
    def cache(self):
        """The core SegmentCache kept, or None."""
        return None if self.slot is None else self.slot.cache

    def clear(self):
        self.view, self.slot, self.refused = None, None, False


FINAL = FinalCache()


def render_final(renderer, inputs: SceneInputs, camera, progress=None, tile_pixels=None, animation: bool = False):
    """F12's frame (scene_frame) through FINAL: shaded from the last F12's segments where they hold
    this view, else traced, kept and shaded; plainly for an animation's frame or a one-off render."""
    from ..engine.frame import Capability, SegmentSlot, render_frame

    frame = scene_frame(inputs)
    if Capability.SEGMENT_CACHE not in renderer.capabilities or animation or FINAL.once:
        FINAL.clear()
        return render_frame(renderer, frame, camera, progress=progress, tile_pixels=tile_pixels)
    view = renderer.trace_key(camera, inputs.options, surface_key=frame.opaque_meshes)
    if view != FINAL.view:
        FINAL.clear()  # another view: the old segments go before the new trace allocates
        FINAL.view = view
    if not FINAL.refused:
        FINAL.slot = FINAL.slot or SegmentSlot()
        frame = frame.with_(cache=FINAL.slot)
    result = render_frame(renderer, frame, camera, progress=progress, tile_pixels=tile_pixels)
    if frame.cache is not None:
        FINAL.refused = "refused" in result.stats.get("segment_cache", {})
    return result


def render_kernel_key(renderer, inputs: SceneInputs) -> tuple:
    """The jobs.kernel_key of rendering the scene's volumes with `renderer`."""
    return kernel_key(inputs.options.device, inputs.options.precision, renderer.kernel_variant,
                      inputs.opaque_mode != "NONE", bool(inputs.surfaces))


def clear_cache():
    RENDERERS.clear()
    FINAL.clear()
    OPAQUE.clear()
    EXTENTS.clear()
    POINTS.clear()
    clear_mesh_cache()


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
    parts = [plural(int(stats.get("elements", n_elements)), "element")]
    if "samples_per_ray" in stats:
        parts.append(f"{stats['samples_per_ray']:.1f} samples/ray")
    if "field_evaluations" in stats:
        parts.append(f"{int(stats['field_evaluations']):,} field evaluations")
    use = stats.get("segment_cache", {})
    if use.get("use") == "traced":
        parts.append(f"traced {use.get('segments', 0):,} segments, kept for a look-only edit")
    elif use.get("use") == "shaded":
        parts.append("shaded from the kept segments")
    elif "refused" in use:
        parts.append("segments not kept: " + use["refused"][:80])
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
        job = render_job(engine, depsgraph)
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
            status(f"HOVR | {plural(n_elements, 'element')} | {stage}\u2026")
            KERNELS.compile_now(key)
    except Exception as exc:
        fail(api, f"HOVR render failed: {failure_text(exc)}")
        return
    if api.test_break():
        return
    t1 = time.perf_counter()

    def progress(fraction):
        api.update_progress(fraction)
        status(f"HOVR | {plural(n_elements, 'element')} | tracing rays {100 * fraction:.0f}% | "
               f"{time.perf_counter() - t1:.1f} s", fraction)
        return not api.test_break()

    try:
        result = render_final(renderer, job.inputs, job.camera, progress=progress, tile_pixels=tile_pixels(device),
                              animation=bool(getattr(engine, "is_animation", False)))
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
