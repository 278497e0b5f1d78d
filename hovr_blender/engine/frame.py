"""The one door into the engine: a Frame holds everything a picture needs besides the mesh and
the camera, and render_frame(renderer, frame, camera) renders it. The `hovr` command, Blender's
F12 and viewport, render-series and render-blend (F12 in a headless Blender) all render through
it, so the same view gives the same image whichever way it is asked for.

A renderer says what it can draw beyond a plain image in `capabilities` (FrameRenderer):
Renderer (one device) everything, MultiDeviceRenderer (engine/multi_device.py) opaque meshes,
SortLastRenderer (engine/sort_last.py) nothing more. render_frame refuses, with one line, what
the renderer cannot do (UnsupportedFrame) rather than drop it; a segment cache is the exception:
it only saves work, so a renderer that keeps none renders the frame plainly.

What render_frame does with a frame, in order:
- opaque meshes (engine/opaque.py) are cast first: the volume is rendered up to each pixel's
  first hit over black and composited over the hit's shading (or left transparent there:
  holdout);
- isosurfaces and cut planes (contract §7) go to the kernels with the volume; an isosurface that
  meets no ray of the whole image is said so in stats["warnings"] (Surfaces.unseen);
- with a segment cache (SegmentSlot), the view is shaded from the slot's cache where it holds
  this view's segments (Renderer.cache_fits), else traced anew and kept in the slot; where the
  memory limit or the device refuses the cache the frame renders plainly and
  stats["segment_cache"]["refused"] says why. stats["segment_cache"]["use"] says what was done
  ("traced": its stats count the trace's work too; "shaded": no field was evaluated).

Warp is imported only when a frame is rendered (by the renderers), so the UI's bpy-free parts
import this module without it.
"""
from __future__ import annotations

import dataclasses
import enum
from dataclasses import dataclass
from typing import ClassVar, Protocol

import numpy as np

from . import limits
from .isosurfaces import Surfaces
from .opaque import MODES, OpaqueError, OpaqueScene, composite_hits
from .render_result import RenderError, RenderResult, SegmentCacheError
from .view import RenderOptions


class Capability(enum.Enum):
    """What a renderer can do beyond a plain image of the whole camera (in words: the errors say them)."""

    ROWS = "a band of rows"
    OPAQUE = "opaque meshes"
    SURFACES = "isosurfaces and planes"
    SEGMENT_CACHE = "a segment cache"
    PROFILE = "kernel timings"
    RAY_COUNTS = "every ray's work counts"


class UnsupportedFrame(RenderError, ValueError):
    """A frame asks for something its renderer cannot do (Capability); the message says what."""


class FrameRenderer(Protocol):
    """What render_frame needs of a renderer. One with Capability.SEGMENT_CACHE also has
    trace_key, cache_fits, trace and shade (engine/renderer.py)."""

    capabilities: ClassVar[frozenset]
    kind: ClassVar[str]  # how it renders, in words ("over several devices")
    device: str
    mesh: object  # engine/mesh.VolumeMesh
    kernel_variant: object  # what its kernels are specialised to (engine/kernel_loading.KernelVariant)

    def render(self, camera, tf, background, options, progress=None, tile_pixels=None, **how) -> RenderResult: ...

    def close(self) -> None: ...


@dataclass(eq=False)
class SegmentSlot:
    """Where a frame keeps its segment cache between renders (Frame.cache): render_frame shades
    from `cache` where it holds the view, else traces the view and puts the new cache here (None
    where it was refused or the renderer keeps none). `held_bytes`: what the caller holds in other
    caches of the same view, counted against the memory limit with this one's."""

    cache: object = None  # engine/segment_cache.SegmentCache
    held_bytes: int = 0


@dataclass(frozen=True, eq=False)
class Frame:
    """Everything a picture needs besides the mesh and the camera."""

    transfer_function: object  # a TransferFunction, or one per volume (VolumeMesh.volume)
    background: object  # linear RGB behind the volume
    options: RenderOptions
    opaque: OpaqueScene | None = None  # meshes that stop the rays (engine/opaque.py)
    opaque_mode: str = "SHADED"  # SHADED, or HOLDOUT: every opaque mesh leaves the film transparent
    surfaces: Surfaces | None = None  # isosurfaces and cut planes (contract §7)
    cache: SegmentSlot | None = None  # an optional segment cache (SegmentSlot)

    def __post_init__(self):
        if self.opaque_mode not in MODES:
            raise OpaqueError(f"opaque mode must be one of {MODES}, got {self.opaque_mode!r}")

    @classmethod
    def from_view(cls, view, **changes) -> "Frame":
        """A view file's frame (engine/view.View): its transfer functions, background, options,
        isosurfaces and planes; `changes` replace fields (options=..., cache=...)."""
        return cls(view.transfer_function, view.background, view.options, surfaces=view.surfaces or None).with_(
            **changes)

    def with_(self, **changes) -> "Frame":
        return dataclasses.replace(self, **changes) if changes else self

    @property
    def opaque_meshes(self) -> OpaqueScene | None:
        """The opaque meshes, None where there are no triangles."""
        return self.opaque if self.opaque is not None and not self.opaque.empty else None

    def needs(self) -> frozenset:
        """The capabilities the frame's content needs (a segment cache is optional: not here)."""
        return frozenset(c for c, wanted in ((Capability.OPAQUE, self.opaque_meshes is not None),
                                             (Capability.SURFACES, bool(self.surfaces))) if wanted)


def check_capabilities(renderer, wanted) -> None:
    """UnsupportedFrame where `renderer` (an instance or its class) lacks a capability in `wanted`."""
    missing = [c for c in Capability if c in wanted and c not in renderer.capabilities]
    if missing:
        what = " and ".join(c.value for c in missing)
        raise UnsupportedFrame(f"{what}: not drawn when rendering {renderer.kind}; render on one device")


def check_frame(renderer, frame: Frame) -> None:
    """UnsupportedFrame where `renderer` cannot draw what `frame` holds (before any work is done)."""
    check_capabilities(renderer, frame.needs())


def render_frame(renderer, frame: Frame, camera, rows: tuple[int, int] | None = None, progress=None,
                 tile_pixels: int | None = None, profile: bool = False, ray_counts: bool = False) -> RenderResult:
    """The frame's image through `camera` (engine/camera.RayCamera) by `renderer` (the module's
    docstring). `rows` = (first, end): only those image rows, each pixel as in the whole image;
    progress(fraction) after each launch tile of `tile_pixels` pixels, False cancels (the result
    has cancelled=True); `profile`: stats["kernel_seconds"]; `ray_counts`: result.ray_counts."""
    wanted = set(frame.needs())
    for capability, asked in ((Capability.ROWS, rows is not None), (Capability.PROFILE, profile),
                              (Capability.RAY_COUNTS, ray_counts)):
        if asked:
            wanted.add(capability)
    check_capabilities(renderer, wanted)
    how = {"progress": progress, "tile_pixels": tile_pixels}
    if rows is not None:
        how["rows"] = rows
    if profile:
        how["profile"] = True
    if ray_counts:
        how["ray_counts"] = True
    if frame.surfaces:
        how["surfaces"] = frame.surfaces
    result = _render(renderer, frame, camera, rows, how)
    if frame.surfaces and rows is None and not result.cancelled:  # said of the whole image only
        result.stats["warnings"] = list(result.stats.get("warnings", [])) + renderer.surface_misses(camera,
                                                                                                    frame.surfaces)
    return result


def _render(renderer, frame: Frame, camera, rows, how: dict) -> RenderResult:
    opaque = frame.opaque_meshes
    slot = frame.cache
    if slot is not None and Capability.SEGMENT_CACHE in renderer.capabilities:
        return _render_cached(renderer, frame, camera, slot, opaque, how)
    if slot is not None:
        slot.cache = None  # this renderer keeps no segments
    if opaque is None:
        return renderer.render(camera, frame.transfer_function, frame.background, frame.options, **how)
    hits = opaque.cast(camera)
    res = renderer.render(camera, frame.transfer_function, np.zeros(3), frame.options, surface_t=hits.t, **how)
    return composite_hits(res, hits, frame.background, frame.opaque_mode, rows)


# the work a trace does and a shade does not (both count the segments: the shade's are the trace's)
TRACE_COUNTS = ("field_evaluations", "restriction_evaluations", "curved_locates", "walks", "bvh_candidates",
                "newton_iterations")


def _add_trace(stats: dict, trace: dict):
    """A traced and shaded frame's stats: the trace's time and work added to the shade's (the trace
    evaluated the field, the shade integrated what it kept), and stats["segment_cache"]["use"]."""
    stats["render_seconds"] += trace["trace_seconds"]
    for k in TRACE_COUNTS:
        if k in trace and k in stats:
            stats[k] += trace[k]
    r0, r1 = stats.get("rows", (0, int(stats["height"])))
    pixels = int(stats["width"]) * (r1 - r0)
    stats["samples_per_ray"] = (stats["field_evaluations"] + stats["restriction_evaluations"]) / max(pixels, 1)
    stats["segment_cache"] = {**stats.get("segment_cache", {}), "use": "traced"}


TRACE_SHARE = 0.95  # of a traced frame's progress: its shading after the trace takes about a twentieth


def _part_of(progress, lo: float, hi: float):
    """progress(fraction) for one stage of a frame: the stage's fraction mapped onto [lo, hi] of
    the frame's, so a frame traced then shaded reports one rising fraction (None stays None)."""
    if progress is None:
        return None
    return lambda fraction: progress(lo + (hi - lo) * fraction)


def _render_cached(renderer, frame: Frame, camera, slot: SegmentSlot, opaque, how: dict) -> RenderResult:
    """render_frame through the slot's segment cache (the module's docstring). The cache keeps
    the opaque meshes' hits beside the segments (they stopped its rays), so an image shaded from
    it casts nothing; its key names the OpaqueScene (the same object, the same triangles)."""
    tf, options, rows = frame.transfer_function, frame.options, how.get("rows")
    progress, tile_pixels, surfaces = how["progress"], how["tile_pixels"], how.get("surfaces")
    old = slot.cache
    fits = old is not None and (opaque is None or old.opaque_hits is not None) and \
        renderer.cache_fits(old, camera, tf, options, rows, surface_key=opaque)
    if not fits:
        old = slot.cache = None  # another view or field frame: freed before the new trace allocates
    hits = None if opaque is None else (old.opaque_hits if fits else opaque.cast(camera))
    background = frame.background if opaque is None else np.zeros(3)
    if fits:
        res = renderer.shade(old, tf, background, options, progress=progress, tile_pixels=tile_pixels,
                             surfaces=surfaces)
        res.stats["segment_cache"] = {**res.stats.get("segment_cache", {}), "use": "shaded"}
    else:
        surface_t = None if hits is None else hits.t
        try:
            cache = renderer.trace(camera, tf, options, rows=rows, surface_t=surface_t, surface_key=opaque,
                                   progress=_part_of(progress, 0.0, TRACE_SHARE), tile_pixels=tile_pixels,
                                   held_bytes=slot.held_bytes)
        except (limits.ResourceLimitError, SegmentCacheError) as exc:
            res = renderer.render(camera, tf, background, options, progress=progress, tile_pixels=tile_pixels,
                                  rows=rows, surface_t=surface_t, surfaces=surfaces)
            res.stats["segment_cache"] = {"refused": str(exc)}
            return res if hits is None else composite_hits(res, hits, frame.background, frame.opaque_mode, rows)
        if not cache.complete:  # cancelled part way
            W = int(camera.width)
            r0, r1 = (0, int(camera.height)) if rows is None else rows
            dtype = np.float64 if options.precision == "float64" else np.float32
            return RenderResult(rgba=np.zeros((r1 - r0, W, 4), dtype), stats={"segment_cache": cache.describe()},
                                depth=np.zeros((r1 - r0, W), dtype), error=np.zeros((r1 - r0, W), dtype),
                                cancelled=True)
        cache.opaque_hits = hits
        slot.cache = cache
        res = renderer.shade(cache, tf, background, options, progress=_part_of(progress, TRACE_SHARE, 1.0),
                             tile_pixels=tile_pixels, surfaces=surfaces)
        _add_trace(res.stats, cache.stats)
    if hits is None or res.cancelled:
        return res
    return composite_hits(res, hits, frame.background, frame.opaque_mode, rows)
