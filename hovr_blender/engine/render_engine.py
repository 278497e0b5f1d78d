"""The HOVR render engine: snapshot the depsgraph into plain records, call the core, write pixels.

Thin glue only (notes §1): no bpy.context and no operators during render(), and nothing in
the user's data is written. The numerical core is imported lazily so that registering the
add-on does not import Warp.
"""
from __future__ import annotations

import time
from dataclasses import dataclass, field

import bpy
import numpy as np

from .blender_camera import ray_camera_from_blender, render_size
from .blender_scene import combined_pass, load_volume_source, render_background, transfer_function_from_ramp


class SceneError(ValueError):
    """The scene cannot be rendered by HOVR; the message tells the user what to fix."""


@dataclass
class RenderJob:
    width: int
    height: int
    camera: object  # RayCamera
    transfer_function: object  # TransferFunction
    background: np.ndarray
    film_transparent: bool
    options: object  # RenderOptions
    source: str
    object_matrix: tuple
    warnings: list = field(default_factory=list)


# A new engine instance is created for every render, so uploaded meshes live here, keyed by
# what determines them; two entries cover toggling an object transform or the device.
_RENDERERS: dict = {}
_MAX_RENDERERS = 2


def _renderer(source: str, matrix: tuple, device: str):
    """(Renderer, number of elements) for a volume source placed by an object matrix."""
    key = (source, matrix, device)
    entry = _RENDERERS.pop(key, None)
    if entry is None:
        from .renderer import Renderer

        mesh = load_volume_source(source).transformed(np.array(matrix).reshape(4, 4))
        entry = (Renderer(mesh, device=device), mesh.num_elements)
    _RENDERERS[key] = entry  # re-insert: most recently used last
    while len(_RENDERERS) > _MAX_RENDERERS:
        _RENDERERS.pop(next(iter(_RENDERERS)))
    return entry


def clear_cache():
    _RENDERERS.clear()


def _matrix_tuple(m) -> tuple:
    return tuple(float(x) for row in m for x in row)


def snapshot(engine: bpy.types.RenderEngine, depsgraph) -> RenderJob:
    """Everything render() needs, as plain data, read from the evaluated depsgraph."""
    from .view import RenderOptions

    scene = depsgraph.scene_eval
    render = scene.render
    settings = scene.hovr
    warnings = []

    width, height = render_size(render)
    if render.use_border:
        warnings.append("HOVR renders the full frame; the render region is ignored")

    cam = engine.camera_override or scene.camera
    if cam is None:
        raise SceneError("no camera: set the scene's active camera")
    camera = ray_camera_from_blender(cam, depsgraph, render)

    volumes = sorted((o for o in depsgraph.objects if o.hovr.is_volume), key=lambda o: o.name)
    if not volumes:
        raise SceneError("no HOVR volume in the scene: add one with Add > HOVR Sphere Volume")
    if len(volumes) > 1:
        warnings.append(f"{len(volumes)} HOVR volumes; rendering only {volumes[0].name!r}")
    volume = volumes[0]

    texture = settings.transfer_function
    if texture is None:
        raise SceneError("no transfer function: pick or create one in Render Properties > Transfer Function")
    if not texture.use_color_ramp or texture.color_ramp is None:
        raise SceneError(f"transfer function texture {texture.name!r} has no colour ramp enabled")
    ramp = texture.color_ramp
    tf = transfer_function_from_ramp(
        ramp.interpolation, ramp.color_mode,
        [e.position for e in ramp.elements], [tuple(e.color) for e in ramp.elements],
        settings.density_scale, settings.value_min, settings.value_max,
    )

    world_color = tuple(scene.world.color) if scene.world is not None else None
    options = RenderOptions(method=settings.method, h=settings.h, tolerance=settings.tolerance,
                            min_transmittance=settings.min_transmittance, device=settings.device)
    return RenderJob(
        width=width, height=height, camera=camera, transfer_function=tf,
        background=render_background(world_color, render.film_transparent),
        film_transparent=bool(render.film_transparent), options=options,
        source=volume.hovr.source, object_matrix=_matrix_tuple(volume.matrix_world), warnings=warnings,
    )


class HovrRenderEngine(bpy.types.RenderEngine):
    bl_idname = "HOVR"
    bl_label = "HOVR"
    bl_use_preview = False  # no material/world previews: HOVR renders only its volumes
    bl_use_eevee_viewport = True  # Material Preview shading falls back to EEVEE

    def __init__(self, *args, **kwargs):
        super().__init__(*args, **kwargs)  # required since Blender 4.4

    def __del__(self):
        # Nothing per instance to free (uploads are cached at module level); chain to the
        # parent if a future Blender defines __del__, tolerating an already-freed RNA struct.
        parent_del = getattr(super(), "__del__", None)
        if parent_del is not None:
            try:
                parent_del()
            except ReferenceError:
                pass

    def _fail(self, message: str):
        # report() reaches the status bar and makes bpy.ops.render.render raise for scripts;
        # error_set() as well would only repeat the message.
        self.report({'ERROR'}, message)
        self.update_stats("", f"HOVR | {message}")

    def render(self, depsgraph):
        self.update_stats("", "HOVR | reading scene")
        try:
            job = snapshot(self, depsgraph)
        except ValueError as exc:  # SceneError and the core's Camera/TransferFunction/Mesh/View errors
            self._fail(str(exc))
            return
        for w in job.warnings:
            self.report({'WARNING'}, w)

        self.update_stats("", "HOVR | rendering")
        t0 = time.perf_counter()
        try:
            renderer, n_elements = _renderer(job.source, job.object_matrix, job.options.device)
            result = renderer.render(job.camera, job.transfer_function, job.background, job.options)
            pixels = combined_pass(result.rgba, job.film_transparent)
        except (ValueError, RuntimeError, MemoryError, ImportError) as exc:
            # ImportError: warp-lang missing from Blender's Python (no bundled wheels yet).
            self._fail(f"HOVR render failed: {type(exc).__name__}: {exc}")
            return
        if pixels.size != job.width * job.height * 4:
            self._fail(f"HOVR render failed: image of {pixels.size // 4} pixels for {job.width}x{job.height}")
            return
        if self.test_break():
            return

        res = self.begin_result(0, 0, job.width, job.height)
        res.layers[0].passes["Combined"].rect.foreach_set(pixels)
        self.end_result(res)

        stats = result.stats
        seconds = stats.get("render_seconds", time.perf_counter() - t0)
        n = int(stats.get("elements", n_elements))
        parts = [f"{n} element{'s' if n != 1 else ''}"]
        if "field_evaluations" in stats:
            parts.append(f"{int(stats['field_evaluations']):,} field evaluations")
        parts.append(f"{seconds:.2f} s on {job.options.device}")
        self.update_stats("", "HOVR | " + " | ".join(parts))


classes = (HovrRenderEngine,)


def register():
    for cls in classes:
        bpy.utils.register_class(cls)


def unregister():
    for cls in reversed(classes):
        bpy.utils.unregister_class(cls)
    clear_cache()
