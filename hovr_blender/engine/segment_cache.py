"""The segment cache: every element segment of every ray of one view, with its Chebyshev series,
kept on the device by a trace (Renderer.trace), so that a transfer-function edit is shaded
(Renderer.shade: one kernel, a thread per ray) without traversing or sampling again
([methods.md](../../docs/methods.md#transfer-function-edits-from-cached-segments)). The view's key
(TraceKey: renderer, field, precision, method family, camera, rows, what stopped the rays) and the
field's frame say whether a cache holds a view; the cache grows round by round under the memory
limit (CacheStore). A Frame's SegmentSlot (engine/frame.py) keeps one between renders."""
from __future__ import annotations

import hashlib
import time
from dataclasses import dataclass, field

import numpy as np
import warp as wp

from . import field_frame, limits
from .camera import RayCamera
from .isosurfaces import Surfaces
from .kernel_loading import load_modules
from .kernels.args import MAX_SAMPLES, SEGMENTS_PER_ROUND
from .kernels.precision import Precision
from .launch_args import Launcher, camera_args, quad_args, surface_limit, tile_buffers, transfer_args
from .methods import samples_segments
from .render_result import RenderError, RenderResult, SegmentCacheError
from .threads import TILES_PER_THREAD, in_threads
from .transfer_function import TransferFunction
from .view import RenderOptions, resolving_step
from .work_counts import banded_stats, counter_stats

# a segment cache grows by this factor when a round needs more room (then shrinks to fit)
CACHE_GROWTH = 1.5
CACHE_MIN_SEGMENTS = 1 << 12
SUM_THREADS = 1 << 14  # threads summing a shade's per-ray counters on the device
INT32_MAX = 2**31 - 1
# what a trace traverses with: density 1 at every value, so no element is skipped as transparent
DENSE_EVERYWHERE = TransferFunction(np.zeros(1), np.zeros((1, 3)), np.zeros(1), np.ones(1))


def camera_key(camera: RayCamera) -> tuple:
    """What the kernels read of a camera (camera_args), as plain numbers."""
    vectors = tuple(tuple(float(x) for x in np.asarray(getattr(camera, k), dtype=np.float64).reshape(3))
                    for k in ("o0", "ou", "ov", "d0", "du", "dv", "clip_axis"))
    return (int(camera.width), int(camera.height), vectors, float(camera.t_min), float(camera.t_max),
            float(camera.clip_near), float(camera.clip_far))


@dataclass(frozen=True)
class TraceKey:
    """What a trace's segments depend on besides the field's frame (Renderer.trace_key)."""

    renderer: int  # the Renderer (its upload and BVH)
    field_version: int  # its field (replace_field counts up)
    precision: str
    sampling: bool  # the method samples the field along segments (classified, split); riemann and
    # trapezoid evaluate affine elements as they march and keep no series for them
    camera: tuple  # the camera's rays (_camera_key)
    rows: tuple  # (first, end) image rows
    surface: object  # what stopped the rays: the caller's name for surface_t, or its digest; None


def surface_digest(surface_t) -> tuple:
    """A name for a per-pixel far limit (render's surface_t) in a trace's key: its digest."""
    t = np.ascontiguousarray(surface_t, dtype=np.float64)
    return ("surface_t", t.shape, hashlib.blake2b(t.tobytes(), digest_size=16).hexdigest())


@dataclass(eq=False)
class SegmentCache:
    """Every element segment of every ray of one view, with its Chebyshev series, on the
    renderer's device (Renderer.trace): what Renderer.shade integrates through a new transfer
    function without traversing or sampling again. Per ray its first chunk and far end; per
    chunk (one ray's segments of one round) its first segment, count and the ray's next chunk;
    per segment its element, t0, t1, degree, flags, tail and where its series starts; the series
    themselves (degree + 3 values each). describe() gives its size."""

    key: TraceKey  # of the view (Renderer.trace_key)
    frame_key: tuple  # the field frame the series are in (engine/field_frame.py)
    camera: RayCamera
    rows: tuple  # (first, end) image rows traced
    arrays: dict  # kernels' SegmentCache field name -> device array (counts included)
    counts: tuple  # (segments, chunks, coefficients)
    complete: bool  # False: the trace was cancelled part way
    stats: dict  # the trace's own: trace_seconds, rounds, its counters
    warnings: list = field(default_factory=list)
    opaque_hits: object = None  # engine/frame.py keeps the opaque meshes' hits that stopped the rays here

    @property
    def rays(self) -> int:
        return (self.rows[1] - self.rows[0]) * int(self.camera.width)

    @property
    def nbytes(self) -> int:
        return int(sum(a.capacity for a in self.arrays.values()))

    def args(self, kernels):
        """The kernels' SegmentCache struct of these arrays (kernels of the cache's precision)."""
        return cache_struct(kernels, self.arrays)

    @property
    def per_ray_bytes(self) -> int:
        """Its arrays of one item a ray (each ray's first chunk and far end)."""
        return int(sum(self.arrays[k].capacity for k in ("head", "t_end")))

    def describe(self) -> dict:
        """Its size: bytes in all, per ray and per segment (a segment's record, its series and its
        share of the chunks), segments and coefficients, and the trace's time."""
        return describe_cache(self)


@dataclass(eq=False)
class BandedCache:
    """One view's segment cache traced in bands of rows side by side (Renderer.trace over a CPU's
    threads): each band's own SegmentCache, in row order; shade shades each into its rows of the
    one image. It answers what a SegmentCache does of the whole view (key, frame, camera, rows,
    completeness, size)."""

    key: TraceKey
    frame_key: tuple
    camera: RayCamera
    rows: tuple
    parts: list  # SegmentCache per band, in row order
    complete: bool
    stats: dict
    warnings: list = field(default_factory=list)
    opaque_hits: object = None

    @property
    def rays(self) -> int:
        return (self.rows[1] - self.rows[0]) * int(self.camera.width)

    @property
    def nbytes(self) -> int:
        return int(sum(p.nbytes for p in self.parts))

    @property
    def counts(self) -> tuple:
        return tuple(int(sum(p.counts[k] for p in self.parts)) for k in range(3))

    @property
    def per_ray_bytes(self) -> int:
        return int(sum(p.per_ray_bytes for p in self.parts))

    def describe(self) -> dict:
        """SegmentCache.describe of the bands together, and how many there are."""
        return {**describe_cache(self), "bands": len(self.parts)}


def describe_cache(cache) -> dict:
    """A cache's size (SegmentCache.describe) from its bytes, rays, counts and trace time."""
    segments, chunks, coefficients = cache.counts
    return {"bytes": cache.nbytes, "bytes_per_ray": cache.nbytes / max(cache.rays, 1),
            "bytes_per_segment": (cache.nbytes - cache.per_ray_bytes) / max(segments, 1), "segments": segments,
            "segments_per_ray": segments / max(cache.rays, 1), "chunks": chunks,
            "coefficients_per_segment": coefficients / max(segments, 1),
            "trace_seconds": cache.stats.get("trace_seconds")}


def row_bands(row0: int, row1: int, count: int) -> list[tuple[int, int]]:
    """Rows row0 .. row1 - 1 in `count` contiguous bands of about equal rows (each at least one)."""
    count = max(1, min(int(count), row1 - row0))
    edges = np.linspace(row0, row1, count + 1).round().astype(int)
    return [(int(a), int(b)) for a, b in zip(edges[:-1], edges[1:])]


class CacheStore:
    """A trace's segment cache while it grows, round by round: the arrays of each group (chunks,
    segments, coefficients) with room to spare, grown by CACHE_GROWTH with the used part copied
    and the memory limit checked first (the render's buffers, the old and the new arrays together),
    shrunk to fit at the end."""

    def __init__(self, prec: Precision, rays: int, base_bytes: int, what: str):
        s, i32 = prec.scalar, wp.int32
        self.prec, self.base_bytes, self.what = prec, int(base_bytes), what
        self.groups = {"segment": (("element", i32), ("t0", s), ("t1", s), ("degree", i32), ("flags", i32),
                                   ("tail", s), ("coeff_offset", i32)),
                       "chunk": (("chunk_start", i32), ("chunk_count", i32), ("chunk_next", i32)),
                       "coefficient": (("coeffs", s),)}
        self.capacity = {g: 0 for g in self.groups}
        self.written = {g: 0 for g in self.groups}
        self.ray_bytes = rays * (4 + prec.dtype.itemsize)
        limits.check_bytes(self.base_bytes + self.ray_bytes, what)
        self.counts = wp.zeros(3, dtype=i32)  # segments, chunks, coefficients (trace_reserve's order)
        self.arrays = {"head": wp.full(rays, -1, dtype=i32), "t_end": wp.zeros(rays, dtype=s), "counts": self.counts}
        for g in self.groups:
            self._resize(g, CACHE_MIN_SEGMENTS)

    def _item_bytes(self, group: str) -> int:
        return sum(wp.types.type_size_in_bytes(dtype) for _, dtype in self.groups[group])

    def _bytes(self, capacity: dict) -> int:
        return self.ray_bytes + sum(capacity[g] * self._item_bytes(g) for g in self.groups)

    def _resize(self, group: str, cap: int):
        """The group's arrays at capacity `cap`, what was written copied over."""
        new_capacity = {**self.capacity, group: cap}
        limits.check_bytes(self.base_bytes + self._bytes(new_capacity) + self.capacity[group] * self._item_bytes(group),
                           self.what)
        try:
            for name, dtype in self.groups[group]:
                new = wp.empty(cap, dtype=dtype)
                if self.written[group] > 0:
                    wp.copy(new, self.arrays[name], count=self.written[group])
                self.arrays[name] = new
        except RuntimeError as exc:  # the device's own memory
            raise SegmentCacheError(f"cannot allocate {self.what} on {wp.get_device()}: {exc}") from exc
        self.capacity[group] = cap

    def check_offsets(self, active: int):
        """A round of `active` rays adds at most SEGMENTS_PER_ROUND segments (and as many series)
        each: refuse where that could pass the kernels' 32-bit offsets."""
        most = {"segment": active * SEGMENTS_PER_ROUND, "chunk": active,
                "coefficient": active * SEGMENTS_PER_ROUND * MAX_SAMPLES}
        for g, extra in most.items():
            if self.written[g] + extra > INT32_MAX:
                raise SegmentCacheError(f"{self.what} would pass 2^31 {g}s (32-bit offsets); render without it, "
                                        f"or fewer rows at a time")

    def ensure(self, segments: int, chunks: int, coefficients: int):
        """Room for the counts trace_reserve has reached (they are written next)."""
        for g, need in zip(("segment", "chunk", "coefficient"), (segments, chunks, coefficients)):
            if need > self.capacity[g]:
                self._resize(g, max(int(need * CACHE_GROWTH), CACHE_MIN_SEGMENTS))
            self.written[g] = need

    def shrink(self):
        """Each group down to what it holds, where the memory limit allows the copy (else as it is)."""
        for g in self.groups:
            if self.capacity[g] > max(self.written[g], 1):
                try:
                    self._resize(g, max(self.written[g], 1))
                except limits.ResourceLimitError:
                    pass

    def used(self) -> tuple:
        return tuple(self.written[g] for g in ("segment", "chunk", "coefficient"))

    def args(self):
        return cache_struct(self.prec.kernels, self.arrays)


def cache_struct(kernels, arrays: dict):
    """The kernels' SegmentCache struct of a cache's device arrays."""
    s = kernels.SegmentCache()
    for name, a in arrays.items():
        setattr(s, name, a)
    return s


class SegmentCaching:
    """The segment cache's side of Renderer (a base class of it: these methods use its upload,
    field frame and rounds): the view's key, trace and shade."""

    def trace_key(self, camera: RayCamera, options: RenderOptions, rows: tuple[int, int] | None = None,
                  surface_key=None) -> TraceKey:
        """What a trace's segments depend on, besides the field's frame (TraceKey). The transfer
        function, density, colours, background, tolerance, h, the inner rule and
        min_transmittance are not in it: the shade kernel takes those."""
        H = int(camera.height)
        row0, row1 = (0, H) if rows is None else (int(rows[0]), int(rows[1]))
        return TraceKey(self._id, self._field_version, options.precision, samples_segments(options.method),
                        camera_key(camera), (row0, row1), surface_key)

    def frame_key(self, tf) -> tuple:
        """The key of the field's frame a render through `tf` uses (engine/field_frame.py), without
        mapping the field into it."""
        tfs = [tf] if isinstance(tf, TransferFunction) else list(tf)
        if len(tfs) != self.volumes:
            raise RenderError(f"{len(tfs)} transfer functions for {self.volumes} volumes")
        return field_frame.frame(tfs, self.data_ranges)[0].key

    def cache_fits(self, cache: SegmentCache | None, camera: RayCamera, tf, options: RenderOptions,
                   rows: tuple[int, int] | None = None, surface_key=None) -> bool:
        """Whether `cache` holds this view's segments, so that shade(cache, tf, ...) is this
        render: the same trace_key and the frame `tf` maps the field into."""
        return (cache is not None and cache.complete and cache.key == self.trace_key(camera, options, rows, surface_key)
                and cache.frame_key == self.frame_key(tf))

    def trace(self, camera: RayCamera, tf, options: RenderOptions, rows: tuple[int, int] | None = None,
              surface_t=None, surface_key=None, progress=None, tile_pixels: int | None = None,
              held_bytes: int = 0, profile: bool = False) -> SegmentCache | BandedCache:
        """_trace_rows over the view's rows, on the CPU in bands over cpu_threads threads (a
        BandedCache: each band a SegmentCache of its own, the same segments), else in one."""
        W, H = int(camera.width), int(camera.height)
        row0, row1 = (0, H) if rows is None else (int(rows[0]), int(rows[1]))
        threads = 1 if profile or not 0 <= row0 < row1 <= H else self._threads_for((row1 - row0) * W)
        if threads > 1:
            return self._banded_trace(camera, tf, options, (row0, row1), surface_t, surface_key, progress, held_bytes,
                                      threads)
        return self._trace_rows(camera, tf, options, rows, surface_t, surface_key, progress, tile_pixels, held_bytes,
                                profile)

    def _banded_trace(self, camera, tf, options, rows, surface_t, surface_key, progress, held_bytes: int,
                      threads: int) -> BandedCache:
        """The view's rows traced in bands (TILES_PER_THREAD a thread) on `threads` threads, each band
        _trace_rows into a cache of its own, their counters into one array (each ray its own row).
        Each band may take its share of the memory the caller does not hold. progress is called
        here as bands finish, and a False leaves the bands not started untraced (complete False)."""
        W, H = int(camera.width), int(camera.height)
        row0, row1 = rows
        bands = row_bands(row0, row1, TILES_PER_THREAD * threads)
        if surface_t is not None and surface_key is None:
            surface_key = surface_digest(surface_t)
        # the upload, its field and the trace's kernels, before the threads (which only read them)
        fr, _, warnings = self.field_frame(tf, options.precision)
        upload = self._upload(options.precision)
        prec = upload.precision
        load_modules(upload.kernels.trace_kernels(), self.device)
        share = max(0, limits.current().max_memory - int(held_bytes)) // len(bands)
        band_held = max(0, limits.current().max_memory - share)
        with wp.ScopedDevice(self.device):
            stats = wp.zeros((W * H, prec.kernels.NUM_STATS), dtype=wp.int32)
            done = [0]

            def finished(_part):
                done[0] += 1
                return None if progress is None else progress(done[0] / len(bands))

            t0 = time.perf_counter()
            parts, _ = in_threads(lambda band: self._trace_rows(camera, tf, options, band, surface_t, surface_key,
                                                                None, None, band_held, False, stats=stats),
                                  bands, threads, finished, name="hovr-trace")
            seconds = time.perf_counter() - t0
            counts = stats[row0 * W:row1 * W].numpy().sum(axis=0, dtype=np.int64)
        traced = [p for p in parts if p is not None]
        complete = len(traced) == len(bands) and all(p.complete for p in traced)
        info = {"device": self.device, "trace_seconds": seconds, "width": W, "height": H,
                "rounds": max((p.stats["rounds"] for p in traced), default=0), "bands": len(bands), "threads": threads,
                **counter_stats(prec.kernels, counts, (row1 - row0) * W)}
        return BandedCache(key=self.trace_key(camera, options, rows, surface_key), frame_key=fr.key, camera=camera,
                           rows=rows, parts=traced, complete=complete, stats=info, warnings=warnings)

    def _trace_rows(self, camera: RayCamera, tf, options: RenderOptions, rows: tuple[int, int] | None = None,
                    surface_t=None, surface_key=None, progress=None, tile_pixels: int | None = None,
                    held_bytes: int = 0, profile: bool = False, stats=None) -> SegmentCache:
        """The rounds of a render, keeping every element segment of every ray with its Chebyshev
        series on the device instead of integrating them: shade(cache, tf2, ...) is then the render
        through any transfer function tf2 whose field frame is tf's (cache_fits). `tf` sets the
        frame only: the trace samples every element (it traverses with a transfer function dense
        everywhere, so no element is skipped as transparent) and follows every ray to its end (no
        early termination), so the cache holds what any transfer function needs. rows, surface_t,
        progress and tile_pixels as in render (cancelled: the cache comes back with complete
        False). The cache's bytes, and `held_bytes` the caller holds in other caches of the same
        view, count against the memory limit with the render's own buffers (limits.check_bytes:
        ResourceLimitError); a device that cannot allocate it raises SegmentCacheError."""
        upload = self._upload(options.precision)
        prec = upload.precision
        kernels = prec.kernels
        W, H = int(camera.width), int(camera.height)
        row0, row1 = (0, H) if rows is None else (int(rows[0]), int(rows[1]))
        if not 0 <= row0 < row1 <= H:
            raise RenderError(f"rows {row0}..{row1} are not inside a {W}x{H} image")
        first, end = row0 * W, row1 * W
        if surface_t is not None and surface_key is None:
            surface_key = surface_digest(surface_t)
        fr, _, warnings = self.field_frame(tf, options.precision)
        key = self.trace_key(camera, options, (row0, row1), surface_key)
        with wp.ScopedDevice(self.device):
            cam = camera_args(prec, camera)
            limit = surface_limit(prec, surface_t, W, H)
            transfer = transfer_args(prec, DENSE_EVERYWHERE)
            quad = quad_args(prec, options, np.zeros(3), upload, self.data_diagonal)
            tile = self._launch_tile(prec, end - first, progress, tile_pixels)
            what = f"the segment cache of a {W}x{H} image in {options.precision}"
            # the render's buffers, the caller's other caches, and per tile ray its reservation
            # (vec3i) and last chunk (int32)
            base_bytes = self.check_limits(W, H, options, tile) + int(held_bytes) + tile * 16
            try:
                if stats is None:  # (a band's trace writes its rows' counters into the view's array)
                    stats = wp.zeros((W * H, kernels.NUM_STATS), dtype=wp.int32)
                buffers = tile_buffers(prec, tile, stats)
                reserved = wp.zeros(tile, dtype=wp.vec3i)
                last_chunk = wp.zeros(tile, dtype=wp.int32)
                store = CacheStore(prec, end - first, base_bytes, what)
            except RuntimeError as exc:
                raise SegmentCacheError(f"cannot allocate {what} on {self.device}: {exc}") from exc
            load_modules(upload.kernels.trace_kernels(), self.device)
            wp.synchronize_device(self.device)
            table = upload.kernels
            launch = Launcher(self.device, profile, table)
            t0 = time.perf_counter()
            complete = True
            rounds = 0
            for start in range(first, end, tile):
                n = min(tile, end - start)
                last_chunk.fill_(-1)

                def record(active, ray_offset=start - first):
                    rays, segs = buffers.rays, buffers.segs
                    store.check_offsets(active)
                    launch(table.trace_reserve, active, [rays, segs, store.args(), reserved])
                    store.ensure(*(int(v) for v in store.counts.numpy()))
                    launch(table.trace_write, active * SEGMENTS_PER_ROUND,
                           [rays, segs, store.args(), reserved, last_chunk, ray_offset])

                rounds += self._trace_tile(launch, upload, cam, transfer, quad, buffers, start, n, limit, record)
                launch(table.trace_ends, n, [buffers.rays, store.args(), start - first])
                if progress is not None:
                    wp.synchronize_device(self.device)
                    if progress((start + n - first) / (end - first)) is False:
                        complete = False
                        break
            store.shrink()
            wp.synchronize_device(self.device)
            seconds = time.perf_counter() - t0
            counts = stats[first:end].numpy().sum(axis=0, dtype=np.int64)
        info = {"device": self.device, "trace_seconds": seconds, "width": W, "height": H, "rounds": rounds,
                **counter_stats(kernels, counts, end - first),
                **({"kernel_seconds": launch.seconds} if profile else {})}
        return SegmentCache(key=key, frame_key=fr.key, camera=camera, rows=(row0, row1), arrays=store.arrays,
                            counts=store.used(), complete=complete, stats=info, warnings=warnings)

    def _shade_bands(self, cache: BandedCache, tf, background, options, progress, profile, surfaces) -> RenderResult:
        """shade of each band's cache, stacked in row order; progress after each band (a False
        stops: the result is cancelled, the bands not shaded left empty)."""
        if not cache.complete:
            raise SegmentCacheError("the segment cache's trace was cancelled before it finished; trace again")
        W, H = int(cache.camera.width), int(cache.camera.height)
        t0 = time.perf_counter()
        results, cancelled = [], False
        for k, part in enumerate(cache.parts):
            if cancelled:
                results.append(None)
                continue
            results.append(self.shade(part, tf, background, options, profile=profile, surfaces=surfaces))
            if progress is not None and progress((k + 1) / len(cache.parts)) is False:
                cancelled = True
        seconds = time.perf_counter() - t0
        first = results[0]
        dtype = first.rgba.dtype
        rgba, depth, error = [], [], []
        for part, res in zip(cache.parts, results):
            r = part.rows[1] - part.rows[0]
            rgba.append(res.rgba if res is not None else np.zeros((r, W, 4), dtype))
            depth.append(res.depth if res is not None else np.zeros((r, W), dtype))
            error.append(res.error if res is not None else np.zeros((r, W), dtype))
        stats = banded_stats([r.stats for r in results if r is not None], cache.rays)
        stats.update(render_seconds=seconds, height=H, segment_cache=cache.describe(),
                     **({"rows": list(cache.rows)} if cache.rows != (0, H) else {}))
        return RenderResult(rgba=np.concatenate(rgba), depth=np.concatenate(depth), error=np.concatenate(error),
                            cancelled=cancelled, stats=stats)

    def shade(self, cache: SegmentCache, tf, background, options: RenderOptions, progress=None,
              tile_pixels: int | None = None, profile: bool = False, surfaces: Surfaces | None = None) -> RenderResult:
        """The render of the cache's view through `tf` (a TransferFunction or one per volume), with
        this background and these options, from the cached segments alone: one kernel, a thread per
        ray, integrating as the render's integrate kernel does (kernels/cache.py shade), so the
        image equals render(camera, tf, background, options) of the same view. SegmentCacheError
        where the cache does not fit: another renderer or field, a precision or a method family
        (riemann/trapezoid against classified/split) other than the trace's, a transfer function
        whose frame differs from the trace's (trace again), or an unfinished trace. progress,
        tile_pixels and profile as in render; stats["segment_cache"] describes the cache. A
        BandedCache is shaded band by band into its rows of the one image."""
        if isinstance(cache, BandedCache):
            return self._shade_bands(cache, tf, background, options, progress, profile, surfaces)
        if not cache.complete:
            raise SegmentCacheError("the segment cache's trace was cancelled before it finished; trace again")
        want = self.trace_key(cache.camera, options, cache.rows, cache.key.surface)
        if (cache.key.renderer, cache.key.field_version, cache.key.precision, cache.key.sampling) != \
                (want.renderer, want.field_version, want.precision, want.sampling):
            raise SegmentCacheError("the segment cache was traced by another renderer, field, precision or method "
                                    "family; trace again")
        if cache.frame_key != self.frame_key(tf):
            raise SegmentCacheError("this transfer function maps the field into another frame than the cached "
                                    "segments' (engine/field_frame.py); trace again")
        options, step_warnings = resolving_step(options, tf, self.data_ranges)
        self._check_steps(options)
        upload = self._upload(options.precision)
        prec = upload.precision
        kernels = prec.kernels
        camera = cache.camera
        W = int(camera.width)
        row0, row1 = cache.rows
        n = cache.rays
        fr, tf_frame, warnings = self.field_frame(tf, options.precision)  # the cache's frame: no new upload
        warnings = warnings + step_warnings
        num_stats = kernels.NUM_STATS
        per_ray = (4 + 2) * prec.dtype.itemsize * 2 + 4 * num_stats
        limits.check_bytes(cache.nbytes + n * per_ray, f"a {W}x{row1 - row0} image shaded in {options.precision}")
        with wp.ScopedDevice(self.device):
            cam = camera_args(prec, camera)
            transfer = transfer_args(prec, tf_frame)
            transfer.surf = self._surface_args(upload, fr, surfaces, options)
            quad = quad_args(prec, options, background, upload, self.data_diagonal)
            try:
                rgba = wp.zeros(n, dtype=prec.vec4)
                aux = wp.zeros(n, dtype=prec.vec2)
                counters = wp.zeros((n, num_stats), dtype=wp.int32)
                sums = wp.zeros(num_stats, dtype=wp.int64)
                nonfinite = wp.zeros(1, dtype=wp.int32)
            except RuntimeError as exc:
                raise RenderError(f"cannot allocate a {W}x{row1 - row0} image on {self.device}: {exc}") from exc
            table = self._kernels(upload, bool(surfaces))
            load_modules(table.shade_kernels(), self.device)
            wp.synchronize_device(self.device)
            launch = Launcher(self.device, profile, table)
            args = cache.args(kernels)
            t0 = time.perf_counter()
            tile = n if progress is None else max(1, int(tile_pixels or 65536))
            cancelled = False
            for start in range(0, n, tile):
                k = min(tile, n - start)
                launch(table.shade, k, [upload.mesh_args, cam, transfer, quad, row0 * W, start, args, rgba, aux,
                                        counters, nonfinite])
                if progress is not None:
                    wp.synchronize_device(self.device)
                    if progress((start + k) / n) is False:
                        cancelled = True
                        break
            threads = min(n, SUM_THREADS)
            launch(table.sum_counts, threads, [counters, threads, sums])
            wp.synchronize_device(self.device)
            seconds = time.perf_counter() - t0
            if int(nonfinite.numpy()[0]) > 0 and not cancelled:
                raise RenderError("the render produced non-finite pixels (NaN/Inf in the data or transfer function?)")
            img = rgba.numpy().reshape(row1 - row0, W, 4)
            depth_err = aux.numpy().reshape(row1 - row0, W, 2)
            counts = sums.numpy()
        if not wp.get_device(self.device).is_cuda:
            img, depth_err = img.copy(), depth_err.copy()  # not views of Warp's arrays on the CPU
        info = {"device": self.device, "render_seconds": seconds, "width": W, "height": int(camera.height),
                "method": options.method, "parameters": options.as_dict(), **counter_stats(kernels, counts, n),
                **({"rows": [row0, row1]} if cache.rows != (0, int(camera.height)) else {}),
                **({"kernel_seconds": launch.seconds} if profile else {}),
                "elements": self.mesh.num_elements, "precision": options.precision, "warnings": warnings,
                "segment_cache": cache.describe()}
        return RenderResult(depth=depth_err[..., 0], error=depth_err[..., 1], cancelled=cancelled, rgba=img, stats=info)
