"""Progressive viewport rendering, without bpy.

The viewport must answer any change (view, transfer function, object, settings) with a
picture quickly and never block Blender's UI, yet end at the quality of F12. The
scheduler does bounded work per call (one call per view_draw):

1. a *preview*: the whole region at 1/scale resolution with looser quadrature, the scale
   chosen from the measured cost so it takes about `first_frame_seconds`; shown
   magnified (nearest neighbour) at once;
2. *refinement*: the region at full resolution and final settings, in bands of rows
   (sub-cameras of the region's camera, so each band's pixels are those of a full
   render), each band sized from the measured cost to fit the call's time budget and
   cancelled through the renderer's progress callback if it overruns.

A change of the request's signature restarts at 1; the learned costs are kept. The
display buffer is the region's (H, W, 4) scene-linear premultiplied RGBA with row 0 at the
bottom, ready for a GPU texture.

Every picture is the request's Frame through engine/frame.render_frame. Each refinement band keeps
its rays' element segments and their series on the device (the Frame's SegmentSlot: a trace,
then a shade). While the view stays (camera, data,
surfaces, precision, device), a change of the look alone (transfer function, density,
colours, background, quadrature tolerance) restarts with the bands shaded from their caches:
when they cover the region and the measured shading cost fits the first frame's time, the
whole region at full resolution is the first frame (no preview); otherwise the preview
comes first and the bands follow, each shaded from its cache. Caches that the memory limit
refuses (with the other bands' caches counted) are not kept: those bands render as before.
"""
from __future__ import annotations

import math
import time
from dataclasses import dataclass, field, replace

import numpy as np

from .blender_camera import sub_camera
from ..engine.camera import RayCamera
from ..engine.frame import Capability, Frame, SegmentSlot, render_frame
from ..engine.view import RenderOptions

# Seconds per pixel assumed before anything was measured (a CPU on a small scene).
_DEFAULT_COST = 2e-5
MAX_PREVIEW_SCALE = 16


@dataclass(frozen=True)
class ViewportRequest:
    """Everything that determines the viewport image."""

    camera: RayCamera  # full region resolution
    frame: Frame  # the look, background, settings, opaque meshes, isosurfaces and planes (engine/frame.py)
    film_transparent: bool
    data_key: tuple = ()  # identifies the uploaded mesh (source, frame file, object transform, device) and opaque meshes

    @property
    def options(self) -> RenderOptions:
        return self.frame.options

    def signature(self) -> tuple:
        c, f = self.camera, self.frame
        cam = tuple(np.concatenate([c.o0, c.ou, c.ov, c.d0, c.du, c.dv]).tolist())
        tf_list = f.transfer_function if isinstance(f.transfer_function, (list, tuple)) else [f.transfer_function]
        tfs = tuple(tuple(np.concatenate([tf.color_s, tf.color_rgb.ravel(), tf.density_s, tf.density_tau]).tolist())
                    for tf in tf_list)
        return (cam, c.width, c.height, c.t_min, c.t_max, c.projection, tfs,
                tuple(np.asarray(f.background, dtype=np.float64).tolist()),
                tuple(sorted(f.options.as_dict().items())), self.film_transparent, self.data_key, f.surfaces,
                f.opaque_mode)

    def cache_view(self) -> tuple:
        """What the bands' cached segments depend on besides the look: the camera, the data, the
        opaque meshes, precision and device (the renderer's key checks the rest: Renderer.trace_key)."""
        c = self.camera
        cam = tuple(np.concatenate([c.o0, c.ou, c.ov, c.d0, c.du, c.dv, c.clip_axis]).tolist())
        return (cam, c.width, c.height, c.t_min, c.t_max, c.clip_near, c.clip_far, c.projection, self.data_key,
                self.frame.opaque, self.options.precision, self.options.device)


def preview_options(options: RenderOptions) -> RenderOptions:
    """Looser quadrature for the preview: 100x the tolerance (at most 1e-3), twice a fixed step (without
    one, classified's own step per segment stays)."""
    return options.with_(tolerance=max(options.tolerance, min(100.0 * options.tolerance, 1e-3)),
                         h=None if options.h is None else 2.0 * options.h)


def preview_camera(camera: RayCamera, scale: int) -> RayCamera:
    """The same view at 1/scale resolution (ceil), covering the same image rectangle.

    The region is padded to a multiple of `scale` so every low-resolution pixel maps onto
    a scale x scale block; the extra columns (right) and rows (bottom) are cropped on display."""
    W, H = camera.width, camera.height
    w, h = math.ceil(W / scale), math.ceil(H / scale)
    # Full image: u = (2x + 1)/H - W/H at column x. Preview pixel i stands for the block
    # x in [i s, (i+1) s), centre x = i s + (s-1)/2, so u = a u' + (s w - W)/H with
    # a = s h / H and u' = (2i + 1)/h - w/h; rows from the top likewise give v = a v' + 1 - a.
    a = scale * h / H
    cu = (scale * w - W) / H
    cv = 1.0 - a
    return replace(
        camera, width=w, height=h,
        o0=camera.o0 + cu * camera.ou + cv * camera.ov, ou=a * camera.ou, ov=a * camera.ov,
        d0=camera.d0 + cu * camera.du + cv * camera.dv, du=a * camera.du, dv=a * camera.dv,
    )


@dataclass
class StepRecord:
    kind: str  # "preview" | "band" | "reshade" (every band shaded from its cache) | "preview-overrun" | "band-overrun"
    scale: int
    rows: tuple  # (first row from the top, number of rows) of the region, or the preview size
    seconds: float


@dataclass(eq=False)  # identity semantics: the engine keeps it in a WeakSet
class ProgressiveViewport:
    """Bounded-work progressive renderer for one viewport (one per engine instance)."""

    first_frame_seconds: float = 0.1
    clock: object = time.perf_counter
    signature: tuple | None = None
    display: np.ndarray | None = None  # (H, W, 4) float32, row 0 at the bottom
    version: int = 0  # bumps whenever display changes
    converged: bool = False
    restarts: int = 0
    log: list = field(default_factory=list)
    _cost: dict = field(default_factory=dict)  # "preview"/"final" -> seconds per pixel
    _scale: int = 0
    _next_row: int = 0  # refinement progress, rows from the top
    _request: ViewportRequest | None = None
    _renderer: object = None
    # the bands' segment caches of the current view: first row -> (rows, core SegmentCache)
    _caches: dict = field(default_factory=dict)
    _cache_view: tuple | None = None
    _cache_refused: bool = False  # a band's cache did not fit the memory limit: the view's later bands keep none

    def sync(self, renderer, request: ViewportRequest) -> bool:
        """Adopt the current request; restart (True) when it differs from the last one. The
        bands' caches stay while the view does (ViewportRequest.cache_view)."""
        sig = request.signature()
        self._renderer, self._request = renderer, request
        if sig == self.signature:
            return False
        view = request.cache_view()
        if view != self._cache_view:
            self._caches = {}
            self._cache_view = view
            self._cache_refused = False
        self.signature = sig
        self.display = None
        self.converged = False
        self._scale = 0
        self._next_row = 0
        self.restarts += 1
        return True

    @property
    def stage(self) -> str:
        if self.display is None:
            return "preview"
        return "converged" if self.converged else "refining"

    def status_text(self) -> str:
        """The viewport's progress in words (the engine's stats, shown in the viewport's corner)."""
        if self.stage == "preview":
            return "HOVR | preview (the first one in a session compiles the kernels)"
        if self.stage == "refining":
            return f"HOVR | refining {100 * self.progress():.0f}%"
        return "HOVR | done"

    def progress(self) -> float:
        req = self._request
        return 1.0 if self.converged else (0.0 if req is None else self._next_row / req.camera.height)

    def _render(self, camera, options, deadline):
        """(RenderResult, wall seconds); the result is cancelled when the deadline passed."""
        req = self._request
        t0 = self.clock()

        def progress(_fraction):
            return deadline is None or self.clock() < deadline

        tile = max(camera.width, 256)
        res = render_frame(self._renderer, req.frame.with_(options=options), camera, progress=progress,
                           tile_pixels=tile)
        return res, self.clock() - t0

    def _render_band(self, y0, rows, deadline):
        """(RenderResult, wall seconds, shaded from its cache) of the region's rows y0 .. y0 + rows,
        rendered with the band's cache (if it has one of these rows) in the frame's SegmentSlot; the
        cache the slot holds afterwards is kept for the band."""
        req = self._request
        cam = sub_camera(req.camera, 0, y0, req.camera.width, rows)
        old = self._caches.pop(y0, None)
        cache = old[1] if old is not None and old[0] == rows else None
        held = sum(c.nbytes for _, c in self._caches.values())
        t0 = self.clock()

        def progress(_fraction):
            return deadline is None or self.clock() < deadline

        tile = max(req.camera.width, 256)
        if self._cache_refused and cache is None:
            res = render_frame(self._renderer, req.frame, cam, progress=progress, tile_pixels=tile)
            return res, self.clock() - t0, False
        slot = SegmentSlot(cache, held_bytes=held)
        res = render_frame(self._renderer, req.frame.with_(cache=slot), cam, progress=progress, tile_pixels=tile)
        kept = slot.cache
        self._cache_refused |= "refused" in res.stats.get("segment_cache", {})
        if kept is not None:
            self._caches[y0] = (rows, kept)
        return res, self.clock() - t0, kept is not None and kept is cache

    def _cached_bands(self):
        """The caches' bands in order when they tile the whole region and hold its view, else None."""
        req = self._request
        W, H = req.camera.width, req.camera.height
        if Capability.SEGMENT_CACHE not in self._renderer.capabilities:
            return None
        bands, y = [], 0
        while y < H:
            if y not in self._caches:
                return None
            rows, cache = self._caches[y]
            surface_key = req.frame.opaque if cache.opaque_hits is not None else None
            if not self._renderer.cache_fits(cache, sub_camera(req.camera, 0, y, W, rows),
                                             req.frame.transfer_function, req.options, surface_key=surface_key):
                return None
            bands.append((y, rows))
            y += rows
        return bands

    def _reshade(self, W, H, now) -> bool:
        """The whole region shaded from the bands' caches as the first frame, where they cover it
        and the measured shading cost fits first_frame_seconds (unmeasured: tried against a
        deadline). True when the display holds it."""
        bands = self._cached_bands()
        cost = self._cost.get("shade")
        if not bands or (cost is not None and cost * W * H > self.first_frame_seconds):
            return False
        deadline = now + 2.0 * self.first_frame_seconds
        img = np.empty((H, W, 4), dtype=np.float32)
        spent = 0.0
        for y0, rows in bands:
            res, sec, shaded = self._render_band(y0, rows, deadline)
            spent += sec
            if res.cancelled or not shaded:
                self._learn("shade", 4.0 * spent, W * (y0 + rows))  # at least this expensive
                return False
            img[y0:y0 + rows] = self._finish(res.rgba)
        self._learn("shade", spent, W * H)
        self.log.append(StepRecord("reshade", 1, (0, H), spent))
        self.display = np.ascontiguousarray(img[::-1])
        self._next_row = H
        self.converged = True
        self.version += 1
        return True

    def _learn(self, kind, seconds, pixels):
        c = seconds / max(pixels, 1)
        old = self._cost.get(kind)
        self._cost[kind] = c if old is None else 0.5 * (old + c)

    def step(self, budget_seconds: float = 0.05) -> bool:
        """Do about `budget_seconds` of work (at least one unit when nothing is shown yet);
        True when the display changed."""
        req = self._request
        if req is None or self.converged:
            return False
        start = self.clock()
        changed = False
        W, H = req.camera.width, req.camera.height
        while not self.converged:
            now = self.clock()
            left = budget_seconds - (now - start)
            if self.display is None:
                changed |= self._preview(W, H, now)
                if self.display is None:
                    return changed  # overran: a coarser preview comes with the next call
            else:
                if left <= 0.0:
                    break
                changed |= self._band(W, H, left)
            if self.clock() - start >= budget_seconds:
                break
        return changed

    def _preview(self, W, H, now) -> bool:
        req = self._request
        if self._scale == 0 and self._reshade(W, H, now):
            return True
        if self._scale == 0:
            cost = self._cost.get("preview", _DEFAULT_COST)
            s = math.ceil(math.sqrt(W * H * cost / self.first_frame_seconds))
            self._scale = int(np.clip(s, 1, MAX_PREVIEW_SCALE))
        cam = preview_camera(req.camera, self._scale)
        last = self._scale >= MAX_PREVIEW_SCALE
        deadline = None if last else now + 2.0 * self.first_frame_seconds
        res, sec = self._render(cam, preview_options(req.options), deadline)
        if res.cancelled:
            self.log.append(StepRecord("preview-overrun", self._scale, (cam.width, cam.height), sec))
            self._learn("preview", 4.0 * sec, cam.width * cam.height)  # at least this expensive
            self._scale = min(2 * self._scale, MAX_PREVIEW_SCALE)
            return False
        self._learn("preview", sec, cam.width * cam.height)
        self.log.append(StepRecord("preview", self._scale, (cam.width, cam.height), sec))
        img = self._finish(res.rgba)
        s = self._scale
        big = np.repeat(np.repeat(img, s, axis=0), s, axis=1)[:H, :W]  # rows from the top
        self.display = np.ascontiguousarray(big[::-1], dtype=np.float32)
        self.version += 1
        return True

    def _band(self, W, H, left) -> bool:
        y0 = self._next_row
        if y0 in self._caches:  # a band of this view's last pass: its rows again, shaded from its cache
            rows, deadline = self._caches[y0][0], None
        else:
            cost = self._cost.get("final", self._cost.get("preview", _DEFAULT_COST) * 2.0)
            rows = int(np.clip((0.5 * left) / (cost * W), 1, H - y0))
            rows = min(rows, min((y for y in self._caches if y > y0), default=H) - y0)  # up to the next cached band
            deadline = None if rows == 1 else self.clock() + max(left, 0.01)
        res, sec, shaded = self._render_band(y0, rows, deadline)
        kind = "shade" if shaded else "final"
        if res.cancelled:
            self.log.append(StepRecord("band-overrun", 1, (y0, rows), sec))
            self._learn(kind, 2.0 * sec, W * rows)  # at least this expensive: smaller bands
            return False
        self._learn(kind, sec, W * rows)
        self.log.append(StepRecord("band", 1, (y0, rows), sec))
        img = self._finish(res.rgba)
        # display rows are bottom-up: region rows [y0, y0+rows) from the top
        self.display[H - y0 - rows: H - y0] = img[::-1]
        self._next_row += rows
        self.converged = self._next_row >= H
        self.version += 1
        return True

    def _finish(self, rgba) -> np.ndarray:
        img = np.array(rgba, dtype=np.float32)
        if not self._request.film_transparent:
            img[..., 3] = 1.0  # as F12: an opaque film has the background composited in
        return img
