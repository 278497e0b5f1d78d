"""One frame over several Warp devices of one host: the image's rows split in contiguous bands,
one band a device, balanced by the cost each row took in the previous frame (a first frame, or
one of another height: by a pre-pass of its view at 1/8 of the size, about 1/64 of its rays) and
by each device's measured speed; the bands stacked into the one image a single device renders
(each pixel is the same ray whichever device traces it: Renderer.render's `rows`).

Each device is served by its own process (Warp's default device is one per process, so threads
would race on it), which holds a Renderer: the mesh is uploaded once to each device and the
kernels are loaded when the process starts (no frame waits for them) and stay across frames.
The processes are started with the "spawn" method (CUDA does not survive a fork), each running
bootstrap.py first: it never re-runs the parent's script (a bpy script, with or without a main
guard), and imports the package under the parent's name
(`bl_ext.<repo>.hovr_blender` in an installed extension). Every process gets its request before any
reply is waited for; each writes its rows into one shared-memory image (SharedImage, made once per
image size, its name unlinked as soon as every process has it open, so a killed run leaves no
segment behind) and answers with its stats and row costs only, and the parent copies each band out
as it is answered. The processes end with the parent (engine/processes.py: each watches its
parent, and Ctrl-C reaches only the parent), and how many a run may start is capped
(limits.check_processes). The renderer
module is imported at the top: the CLI and the add-on import
this module only when they render, as they do the renderer.
"""
from __future__ import annotations

import contextlib
import dataclasses
import multiprocessing
import multiprocessing.connection
import os
import pickle
import runpy
import sys
import threading
import time
import types

import numpy as np

import itertools
import weakref
from dataclasses import dataclass

from . import field_frame, limits
from .frame import Capability, Frame, check_frame
from .processes import sigint_blocked, watch_parent
from .devices import expand_devices
from .kernel_loading import kernel_variant, load_kernels
from .methods import samples_segments
from .render_result import RenderError, RenderResult, SegmentCacheError
from .renderer import Renderer
from .segment_cache import TraceKey, camera_key
from .transfer_function import TransferFunction
from .work_counts import banded_stats


def balanced_rows(row_cost, speeds) -> list[tuple[int, int]]:
    """Contiguous bands (first, end) of len(row_cost) rows, one per device, each device's share of
    the summed cost proportional to its speed; every band has at least one row (so at most
    len(row_cost) devices get one)."""
    cost = np.maximum(np.asarray(row_cost, dtype=np.float64), 1e-12)
    speeds = np.asarray(speeds, dtype=np.float64)[: len(cost)]
    H, n = len(cost), len(speeds)
    cum = np.concatenate([[0.0], np.cumsum(cost)])
    targets = cum[-1] * np.cumsum(speeds)[:-1] / speeds.sum()
    cuts = np.searchsorted(cum, targets, side="left")
    # round each cut to the nearer row boundary, keep them strictly increasing inside 1..H-1
    cuts = [int(c - 1) if c > 0 and (cum[c] - t) > (t - cum[c - 1]) else int(c) for c, t in zip(cuts, targets)]
    edges = [0]
    for k, c in enumerate(cuts):
        edges.append(int(np.clip(c, edges[-1] + 1, H - (n - 1 - k))))
    edges.append(H)
    return [(edges[k], edges[k + 1]) for k in range(n)]


PREPASS_SCALE = 8  # a first frame's pre-pass: 1/8 of the rows and of the columns, 1/64 of the rays


def prepass_camera(camera, scale: int = PREPASS_SCALE):
    """The camera's view at 1/scale of its width and height (at least a pixel each way), its
    horizontal extent kept where the rounded size changes the aspect ratio (RayCamera.uv's u spans
    width/height)."""
    W, H = int(camera.width), int(camera.height)
    w, h = max(1, -(-W // int(scale))), max(1, -(-H // int(scale)))
    k = (W / H) / (w / h)
    return dataclasses.replace(camera, width=w, height=h, ou=camera.ou * k, du=camera.du * k)


def upsampled_rows(low, height: int) -> np.ndarray:
    """Per row of a `height`-row image, the value of the pre-pass row (of len(low)) its centre
    falls in: the pre-pass's row costs as the frame's, or its surface_t's rows."""
    low = np.asarray(low)
    j = ((np.arange(height) + 0.5) * len(low) / height).astype(np.int64)
    return low[np.minimum(j, len(low) - 1)]


def device_spread(seconds) -> dict:
    """How evenly the devices' render times of one frame came out: `device_spread`, how much longer
    the slowest took than the fastest, as a fraction of the fastest ((max - min) / min: the issue's
    "per-device times differ by <= 10 %"), and `device_balance`, the mean over the slowest (the
    share of the devices' time spent rendering while the frame lasted)."""
    s = np.asarray(seconds, dtype=np.float64)
    return {"device_spread": float((s.max() - s.min()) / max(s.min(), 1e-12)),
            "device_balance": float(s.mean() / max(s.max(), 1e-12))}


def merge_results(parts, width: int, height: int, seconds: float, image=None) -> RenderResult:
    """The image of row bands rendered apart: (band (first, end), RenderResult) in row order; with
    `image` = (rgba, aux), the whole image already assembled (the bands' results carry no pixels)."""
    results = [r for _, r in parts]
    if image is None:
        rgba = np.concatenate([r.rgba for r in results], axis=0)
        depth = np.concatenate([r.depth for r in results], axis=0)
        error = np.concatenate([r.error for r in results], axis=0)
    else:
        rgba, aux = image
        depth, error = aux[..., 0], aux[..., 1]
    row_cost = np.concatenate([r.row_cost for r in results], axis=0)
    stats = banded_stats([r.stats for r in results], width * height)
    stats.update(width=width, height=height, render_seconds=seconds,
                 device=",".join(r.stats["device"] for r in results),
                 rounds=max(r.stats["rounds"] for r in results),
                 devices=[{"device": r.stats["device"], "rows": list(band), "render_seconds": r.stats["render_seconds"],
                           **({"wall_seconds": r.stats["wall_seconds"]} if "wall_seconds" in r.stats else {}),
                           "cost": float(r.row_cost.sum())} for band, r in parts],
                 **device_spread([r.stats["render_seconds"] for r in results]))
    return RenderResult(rgba=rgba, stats=stats, depth=depth, error=error, row_cost=row_cost)


class SharedImage:
    """A whole image's rgba (H, W, 4) and aux (H, W, 2: depth, error) in one shared memory block:
    the devices' processes write their rows into it (Renderer.render's `out`), so only small
    messages go through the pipes. The parent creates it (create=True) and unlinks its name as soon as
    every process has attached (unlink(); the mappings stay), so nothing is left in /dev/shm even if
    the whole process group is killed; a process that attaches (by spec) only closes it."""

    def __init__(self, width: int, height: int, dtype, name: str | None = None):
        from multiprocessing import shared_memory

        self.width, self.height, self.dtype = int(width), int(height), np.dtype(dtype)
        n = self.width * self.height * self.dtype.itemsize
        self._owner = name is None
        self._shm = shared_memory.SharedMemory(name=name, create=self._owner, size=6 * n if self._owner else 0)
        self.rgba = np.ndarray((self.height, self.width, 4), self.dtype, self._shm.buf, 0)
        self.aux = np.ndarray((self.height, self.width, 2), self.dtype, self._shm.buf, 4 * n)

    @property
    def name(self) -> str:
        return self._shm.name

    @property
    def spec(self) -> tuple:
        """What a process attaches with: SharedImage(*spec)."""
        return (self.width, self.height, self.dtype.str, self._shm.name)

    def unlink(self):
        """Remove the block's name (the owner, once every process has it open): the memory lives
        until the last mapping closes."""
        if self._owner and self._shm is not None and not getattr(self, "_unlinked", False):
            self._unlinked = True
            try:
                self._shm.unlink()
            except FileNotFoundError:
                pass

    def close(self):
        if self._shm is None:
            return
        self.rgba = self.aux = None  # the views go first: a mapping with views cannot close
        self.unlink()
        shm, self._shm = self._shm, None
        shm.close()


def _attach(shared, spec):
    """The SharedImage of `spec`: the one attached already, or a new one (the old one closed)."""
    if shared is not None and shared.spec == spec:
        return shared
    if shared is not None:
        shared.close()
    return SharedImage(*spec)


def _render_into(renderer, shared, msg) -> RenderResult:
    """A "render_shared" request: the rows rendered into the shared image; the result without pixels."""
    _, camera, tf, background, options, rows, surface_t, surfaces, _ = msg
    t0 = time.perf_counter()
    res = renderer.render(camera, tf, background, options.with_(device=renderer.device), rows=rows,
                          out=(shared.rgba, shared.aux), surface_t=surface_t, surfaces=surfaces)
    res.stats["wall_seconds"] = time.perf_counter() - t0
    res.rgba = res.depth = res.error = None
    return res


def _set_up(mesh, device, max_tile_rays, precision) -> tuple[Renderer, dict]:
    """A device's set-up, done once and kept out of every frame: the mesh uploaded (Renderer) and
    the kernels of `precision` loaded on the device. (Renderer, what it cost)."""
    renderer = Renderer(mesh, device, max_tile_rays=max_tile_rays)
    renderer.cpu_threads = 1  # one process a device: All CPU Cores' are one a core
    t0 = time.perf_counter()
    report = load_kernels(renderer.kernel_variant, renderer.device, precision)
    return renderer, {"device": renderer.device, "upload_seconds": renderer.upload_seconds,
                      "kernel_seconds": time.perf_counter() - t0,
                      "kernel_modules": sorted(report.shipped + report.cached + report.compiled)}


def _trace_band(renderer, caches, msg) -> dict:
    """A "trace" request: the band's segments traced and kept here under the parent's cache id;
    the answer is their size and the trace's counters."""
    _, cache_id, camera, tf, options, band, surface_t, held_bytes = msg
    cache = renderer.trace(camera, tf, options.with_(device=renderer.device), rows=band, surface_t=surface_t,
                           surface_key="parent" if surface_t is not None else None, held_bytes=held_bytes)
    caches[cache_id] = cache
    return {"complete": cache.complete, "counts": cache.counts, "nbytes": cache.nbytes, "stats": cache.stats}


def _shade_band(renderer, caches, shared, msg) -> RenderResult:
    """A "shade" request: the kept band shaded through the look into the shared image's rows."""
    _, cache_id, tf, background, options, surfaces, _ = msg
    cache = caches.get(cache_id)
    if cache is None:
        raise SegmentCacheError("this device no longer keeps the segments; trace again")
    t0 = time.perf_counter()
    res = renderer.shade(cache, tf, background, options.with_(device=renderer.device), surfaces=surfaces)
    r0, r1 = cache.rows
    shared.rgba[r0:r1] = res.rgba
    shared.aux[r0:r1, :, 0], shared.aux[r0:r1, :, 1] = res.depth, res.error
    res.stats["wall_seconds"] = time.perf_counter() - t0
    res.rgba = res.depth = res.error = None
    return res


def _serve(conn, mesh, device, max_tile_rays, parent_pid=None, precision="float32"):
    """A device's process: a Renderer of `mesh` on `device` with the kernels of `precision`
    loaded, rendering what it is sent, and the segments of the bands it traced, by the parent's
    cache ids, until the parent drops them (a request's last item); it ends with its parent
    (engine/processes.watch_parent)."""
    if parent_pid is not None:
        watch_parent(parent_pid)
    try:
        renderer, setup = _set_up(mesh, device, max_tile_rays, precision)
        conn.send(("ok", setup))
    except BaseException as exc:  # noqa: BLE001  (reported to the parent, which raises it)
        conn.send(("error", f"{type(exc).__name__}: {exc}"))
        return
    shared = None  # the SharedImage the last frame was written into
    caches = {}  # the parent's cache id -> this band's SegmentCache
    try:
        while True:
            try:
                # recv unpickles: only the parent's own requests come here, over the anonymous pipe it
                # made for this process (no file or network bytes)
                msg = conn.recv()
            except EOFError:
                return
            if msg[0] == "close":
                return
            if msg[0] in ("trace", "shade", "render_shared"):
                msg, dropped = msg[:-1], msg[-1]
                for cache_id in dropped:
                    caches.pop(cache_id, None)
            try:
                if msg[0] == "field":
                    caches.clear()  # another field: the segments are stale
                    renderer.replace_field(msg[1])
                    conn.send(("ok", None))
                elif msg[0] == "trace":
                    conn.send(("ok", _trace_band(renderer, caches, msg)))
                elif msg[0] == "shade":
                    shared = _attach(shared, msg[-1])
                    conn.send(("ok", _shade_band(renderer, caches, shared, msg)))
                elif msg[0] == "data_ranges":
                    renderer.data_ranges = msg[1]
                    conn.send(("ok", None))
                elif msg[0] == "attach":
                    shared = _attach(shared, msg[1])
                    conn.send(("ok", None))
                elif msg[0] == "render_shared":
                    shared = _attach(shared, msg[-1])
                    conn.send(("ok", _render_into(renderer, shared, msg)))
                elif msg[0] == "surface_misses":
                    conn.send(("ok", renderer.surface_misses(msg[1], msg[2])))
                else:
                    _, camera, tf, background, options, rows, surface_t, surfaces = msg
                    res = renderer.render(camera, tf, background, options.with_(device=renderer.device), rows=rows,
                                          surface_t=surface_t, surfaces=surfaces)
                    conn.send(("ok", res))
            except BaseException as exc:  # noqa: BLE001
                conn.send(("error", f"{type(exc).__name__}: {exc}"))
    finally:
        if shared is not None:
            shared.close()


def serve_spawned(conn, payload: bytes):
    """A device's process once bootstrap.py has imported the package: its mesh, device
    and tile limit unpickled (the package's classes resolve now), then _serve."""
    try:
        # the parent's own objects (a mesh its readers already parsed into arrays), handed over by
        # the anonymous pipe only parent and child hold: no file or network bytes are unpickled
        mesh, device, max_tile_rays, parent_pid, precision = pickle.loads(payload)
    except BaseException as exc:  # noqa: BLE001  (reported to the parent, which raises it)
        conn.send(("error", f"{type(exc).__name__}: {exc}"))
        return
    del payload
    _serve(conn, mesh, device, max_tile_rays, parent_pid, precision)


_STARTING = threading.Lock()


@contextlib.contextmanager
def _main_script_hidden():
    """The spawn method re-runs the parent's __main__ in the child (as __mp_main__) before anything
    else: the user's bpy script, which would import bpy and render again there. The child needs
    nothing from it, so a bare __main__ stands in while a process starts (spawn reads it then)."""
    with _STARTING:
        main = sys.modules.get("__main__")
        sys.modules["__main__"] = types.ModuleType("__main__")
        try:
            yield
        finally:
            sys.modules["__main__"] = main


class DeviceProcess:
    """A process holding a Renderer of one mesh on one device (_serve). send() a request, then
    reply() its answer: requests to several processes run at once."""

    def __init__(self, mesh, device: str, max_tile_rays: int | None = None, precision: str = "float32"):
        ctx = multiprocessing.get_context("spawn")
        self.device = device
        self._conn, child = ctx.Pipe()
        engine_folder = os.path.dirname(os.path.abspath(__file__))
        payload = (mesh, device, max_tile_rays, os.getpid(), precision)
        start = {"conn": child, "package": __name__.rsplit(".", 2)[0], "folder": os.path.dirname(engine_folder),
                 "payload": pickle.dumps(payload, protocol=pickle.HIGHEST_PROTOCOL)}
        bootstrap = os.path.join(engine_folder, "bootstrap.py")
        self._proc = ctx.Process(target=runpy.run_path, args=(bootstrap, {"START": start}, "__hovr_device_process__"),
                                 daemon=True, name=f"hovr-{device}")
        with _main_script_hidden(), sigint_blocked():
            self._proc.start()
        child.close()

    def send(self, *msg):
        try:
            self._conn.send(msg)
        except OSError as exc:  # the process is gone (BrokenPipeError)
            raise RenderError(f"the process rendering on {self.device} ended unexpectedly") from exc

    def fileno(self):
        """The pipe's end (multiprocessing.connection.wait waits on the processes themselves)."""
        return self._conn.fileno()

    def reply(self):
        # the pipe or the process's end, whichever comes first: a process that died without
        # closing its end (a child of its own holding it) is not waited for
        multiprocessing.connection.wait([self._conn, self._proc.sentinel])
        if not self._conn.poll():
            raise RenderError(f"the process rendering on {self.device} ended unexpectedly "
                              f"(exit code {self._proc.exitcode})")
        try:
            kind, value = self._conn.recv()  # this process's own child's answer (recv unpickles)
        except EOFError as exc:
            raise RenderError(f"the process rendering on {self.device} ended unexpectedly") from exc
        if kind == "error":
            raise RenderError(f"{self.device}: {value}")
        return value

    def close(self, timeout: float = 10.0):
        """Ask the process to end, and kill it after `timeout` seconds (0: its render is not
        wanted, e.g. after Ctrl-C)."""
        try:
            self._conn.send(("close",))
            self._conn.close()
        except OSError:
            pass
        self._proc.join(timeout=timeout)
        if self._proc.is_alive():
            self._proc.kill()
            self._proc.join(timeout=10)


def start_processes(meshes, devices, max_tile_rays=None, precision: str = "float32") -> list[DeviceProcess]:
    """A DeviceProcess for each (mesh, device), started together; waits until each has uploaded
    its mesh and loaded the kernels of `precision` (each process's `setup`: _set_up's report)."""
    devices = list(devices)
    limits.check_processes(len(devices), f"rendering on {len(devices)} devices ({','.join(devices)})"[:200])
    procs = []
    try:
        for mesh, dev in zip(meshes, devices):
            procs.append(DeviceProcess(mesh, dev, max_tile_rays, precision))
        for p in procs:
            p.setup = p.reply()
            p.upload_seconds = p.setup["upload_seconds"]
    except BaseException:
        for p in procs:
            p.close(timeout=0)
        raise
    return procs


_CACHE_IDS = itertools.count(1)


@dataclass(eq=False)
class MultiDeviceCache:
    """A view's segments kept over several devices (MultiDeviceRenderer.trace): each device's
    process holds its band's SegmentCache under `id`; this is the parent's record of them, what
    engine/frame.py and the callers read of a SegmentCache (key, frame_key, complete, nbytes, stats,
    describe()). When it is dropped, the devices drop their bands with the next request."""

    id: int
    key: TraceKey
    frame_key: tuple
    camera: object
    bands: list  # (first, end) rows of each device, in the devices' order
    complete: bool
    nbytes: int
    counts: tuple  # (segments, chunks, coefficients), summed
    stats: dict  # the trace's: trace_seconds and its counters, summed over the devices
    opaque_hits: object = None  # engine/frame.py keeps the opaque meshes' hits that stopped the rays here

    def describe(self) -> dict:
        segments, chunks, coefficients = self.counts
        rays = int(self.camera.width) * int(self.camera.height)
        return {"bytes": self.nbytes, "bytes_per_ray": self.nbytes / max(rays, 1), "segments": segments,
                "segments_per_ray": segments / max(rays, 1), "chunks": chunks,
                "coefficients_per_segment": coefficients / max(segments, 1),
                "trace_seconds": self.stats.get("trace_seconds"), "devices": len(self.bands),
                **{k: self.stats.get(k) for k in ("split_by", "prepass_seconds", "device_spread")}}


class MultiDeviceRenderer:
    """Renderer's render() over several devices (e.g. every CUDA device of the host): one process
    a device, each holding the mesh with the kernels of `precision` loaded (`setup` says what that
    cost, once); close() (or `with`) stops them. A frame's rows are split by the previous frame's
    row costs where it had the same height, else by a pre-pass at 1/prepass_scale of the size (0:
    equal rows). Of a Frame it draws opaque meshes (each device reads its band of the whole
    image's hits) and isosurfaces and planes, and it keeps a segment cache of the whole image
    (engine/frame.py): each device traces and keeps its band's segments, and a look-only edit
    shades each band where it is (trace, shade)."""

    capabilities = frozenset({Capability.OPAQUE, Capability.SEGMENT_CACHE, Capability.SURFACES})
    kind = "over several devices"

    def __init__(self, mesh, devices, max_tile_rays: int | None = None, precision: str = "float32",
                 prepass_scale: int = PREPASS_SCALE):
        self.devices = expand_devices(devices)
        self.device = ",".join(self.devices)
        self.mesh = mesh
        self.kernel_variant = kernel_variant([mesh])  # what every device's process compiles
        self.prepass_scale = int(prepass_scale)
        self._row_cost = None  # the last frame's cost per row, for the next split
        self._speeds = np.ones(len(self.devices))  # cost per second, per device
        t0 = time.perf_counter()
        self._shared = None  # the SharedImage the devices write into (one per image size and dtype)
        self._procs = start_processes([mesh] * len(self.devices), self.devices, max_tile_rays, precision)
        self.upload_seconds = time.perf_counter() - t0
        # once, before any frame: the processes' start, each device's upload and kernel load
        self.setup = {"seconds": self.upload_seconds, "precision": precision,
                      "devices": [{k: v for k, v in p.setup.items() if k != "kernel_modules"} for p in self._procs]}
        self._id = next(_CACHE_IDS)  # its identity in its caches' keys
        self._field_version = 0
        self.data_ranges = Renderer.volume_ranges(mesh)  # the field frame's (Renderer's own)
        self._dropped = []  # ids of caches the caller let go of: the devices drop them with the next request

    def replace_field(self, mesh):
        """A new field on the same geometry, sent to every device (Renderer.replace_field)."""
        for p in self._procs:
            p.send("field", mesh)
        for p in self._procs:
            p.reply()
        self.mesh = mesh
        self._field_version += 1
        self.data_ranges = Renderer.volume_ranges(mesh)

    # ---------------------------------------------------------------- the segment cache, over the devices

    def trace_key(self, camera, options, rows=None, surface_key=None) -> TraceKey:
        """What a trace's segments depend on (Renderer.trace_key): the whole image's rows always."""
        if rows is not None:
            raise RenderError("a renderer over several devices traces the whole image, not a band of rows")
        return TraceKey(self._id, self._field_version, options.precision, samples_segments(options.method),
                        camera_key(camera), (0, int(camera.height)), surface_key)

    def frame_key(self, tf) -> tuple:
        tfs = [tf] if isinstance(tf, TransferFunction) else list(tf)
        return field_frame.frame(tfs, self.data_ranges)[0].key

    def cache_fits(self, cache, camera, tf, options, rows=None, surface_key=None) -> bool:
        return (isinstance(cache, MultiDeviceCache) and cache.complete
                and cache.key == self.trace_key(camera, options, rows, surface_key)
                and cache.frame_key == self.frame_key(tf))

    def _forget(self, cache_id: int):
        self._dropped.append(cache_id)

    def _ask(self, requests) -> list:
        """Send each device its request (the dropped caches' ids last), then read every answer (the
        pipes stay in step); the first error is raised once all have answered."""
        dropped, self._dropped = self._dropped, []
        replies, errors = [], []
        for p, msg in zip(self._procs, requests):
            p.send(*msg, dropped)
        for p in self._procs:
            try:
                replies.append(p.reply())
            except RenderError as exc:
                errors.append(exc)
                replies.append(None)
        if errors:
            raise errors[0]
        return replies

    def trace(self, camera, tf, options, rows=None, surface_t=None, surface_key=None, progress=None,
              tile_pixels=None, held_bytes: int = 0) -> MultiDeviceCache:
        """Renderer.trace over the devices: each keeps its band's segments (the bands render()
        would split, a first trace's by the pre-pass, whose row costs then split the next traces
        of this height: a trace measures none), the memory limit shared among them; `progress` is
        called once, at the end."""
        key = self.trace_key(camera, options, rows, surface_key)
        t0 = time.perf_counter()
        bands, split_by, prepass_seconds, cost = self._frame_bands(camera, tf, np.zeros(3), options, surface_t)
        if cost is not None:
            self._row_cost = cost
        n = len(self._procs)
        share = int(limits.current().max_memory * (n - 1) / n)  # each device's band within its share
        cache_id = next(_CACHE_IDS)
        replies = self._ask([("trace", cache_id, camera, tf, options, band, surface_t, int(held_bytes) + share)
                             for band in bands])
        counts = tuple(int(sum(r["counts"][k] for r in replies)) for k in range(3))
        summed = {k: sum(r["stats"].get(k, 0) for r in replies) for k in
                  ("field_evaluations", "restriction_evaluations", "segments", "segments_empty", "segments_smooth",
                   "segments_piecewise_smooth", "curved_locates", "walks", "bvh_candidates", "newton_iterations",
                   "ray_rounds")}
        pixels = int(camera.width) * int(camera.height)
        samples = summed["field_evaluations"] + summed["restriction_evaluations"]
        stats = {**summed, "samples_per_ray": samples / pixels,
                 "trace_seconds": time.perf_counter() - t0, "device": self.device, "split_by": split_by,
                 "prepass_seconds": prepass_seconds,
                 "devices": [{"device": p.device, "rows": list(band), "trace_seconds": r["stats"]["trace_seconds"]}
                             for p, band, r in zip(self._procs, bands, replies)],
                 **device_spread([r["stats"]["trace_seconds"] for r in replies])}
        cache = MultiDeviceCache(cache_id, key, self.frame_key(tf), camera, bands, all(r["complete"] for r in replies),
                                 int(sum(r["nbytes"] for r in replies)), counts, stats)
        weakref.finalize(cache, self._forget, cache_id)
        if progress is not None:
            progress(1.0)
        return cache

    def shade(self, cache: MultiDeviceCache, tf, background, options, progress=None, tile_pixels=None,
              profile=False, surfaces=None) -> RenderResult:
        """Renderer.shade over the devices: each shades its kept band into the shared image (with the
        frame's isosurfaces and planes)."""
        if not isinstance(cache, MultiDeviceCache) or not cache.complete:
            raise SegmentCacheError("the segment cache was not traced to its end on these devices; trace again")
        if cache.frame_key != self.frame_key(tf):
            raise SegmentCacheError("this transfer function maps the field into another frame than the cached "
                                    "segments' (engine/field_frame.py); trace again")
        camera = cache.camera
        W, H = int(camera.width), int(camera.height)
        shared = self._shared_image(W, H, np.float64 if options.precision == "float64" else np.float32)
        t0 = time.perf_counter()
        replies = self._ask([("shade", cache.id, tf, background, options, surfaces, shared.spec) for _ in cache.bands])
        seconds = time.perf_counter() - t0
        stats = banded_stats([r.stats for r in replies], W * H)
        stats.update(width=W, height=H, render_seconds=seconds, device=self.device, segment_cache=cache.describe())
        rgba, aux = shared.rgba.copy(), shared.aux.copy()
        if progress is not None:
            progress(1.0)
        return RenderResult(rgba=rgba, stats=stats, depth=aux[..., 0], error=aux[..., 1])

    def surface_misses(self, camera, surfaces) -> list[str]:
        """Renderer.surface_misses, asked of the first device (which holds the mesh's boxes and ranges)."""
        first = self._procs[0]
        first.send("surface_misses", camera, surfaces)
        return first.reply()

    def split(self, height: int, row_cost=None) -> list[tuple[int, int]]:
        """The row bands of the next frame: by `row_cost` (a pre-pass's), else the last frame's row
        costs if it had this height, else equal rows, over the devices' measured speeds."""
        if row_cost is None:
            row_cost = self._row_cost if self._row_cost is not None and len(self._row_cost) == height else None
        return balanced_rows(np.ones(height) if row_cost is None else row_cost, self._speeds)

    def reset_split(self):
        """Split the next frame as a first one: no previous frame's row costs, equal device speeds."""
        self._row_cost = None
        self._speeds = np.ones(len(self.devices))

    def prepass(self, camera, tf, background, options, surface_t=None, surfaces=None) -> np.ndarray:
        """The frame's cost per row, estimated by rendering its view at 1/prepass_scale of its
        size (prepass_camera), in equal bands over the devices, each full-size row taking the
        cost of the pre-pass row its centre falls in (surface_t sampled alike)."""
        low = prepass_camera(camera, self.prepass_scale)
        w, h = int(low.width), int(low.height)
        if surface_t is not None:
            surface_t = np.asarray(surface_t)
            surface_t = upsampled_rows(upsampled_rows(surface_t, h).T, w).T
        bands = balanced_rows(np.ones(h), np.ones(len(self._procs)))
        procs = self._procs[:len(bands)]
        for p, band in zip(procs, bands):
            p.send("render", low, tf, background, options, band, surface_t, surfaces)
        replies, errors = [], []
        for p in procs:  # every reply read: the pipes stay in step
            try:
                replies.append(p.reply())
            except RenderError as exc:
                errors.append(exc)
        if errors:
            raise errors[0]
        return upsampled_rows(np.concatenate([r.row_cost for r in replies]), int(camera.height))

    def _frame_bands(self, camera, tf, background, options, surface_t=None, surfaces=None):
        """(bands, split_by, pre-pass seconds, the pre-pass's row costs or None) of a frame: split
        by the previous frame's row costs where it had this height, else by a pre-pass (none with
        prepass_scale 0 or one device: equal rows)."""
        H = int(camera.height)
        if self._row_cost is not None and len(self._row_cost) == H:
            return self.split(H), "previous frame", 0.0, None
        if self.prepass_scale <= 0 or len(self._procs) < 2:
            return self.split(H), "equal rows", 0.0, None
        t0 = time.perf_counter()
        cost = self.prepass(camera, tf, background, options, surface_t, surfaces)
        return self.split(H, cost), "pre-pass", time.perf_counter() - t0, cost

    def render(self, camera, tf, background, options, progress=None, tile_pixels=None, profile=False,
               surface_t=None, surfaces=None) -> RenderResult:
        """Renderer.render over the devices (progress is called once, at the end; profile is ignored;
        surface_t, the whole image's, goes to every device, which reads its band's rows; so do the
        isosurfaces and planes, each ray the one device's). A frame
        without a previous frame of its height is split by a pre-pass (prepass), timed in its
        render_seconds and apart in stats["prepass_seconds"]; stats["split_by"] says which."""
        W, H = int(camera.width), int(camera.height)
        t0 = time.perf_counter()
        bands, split_by, prepass_seconds, _ = self._frame_bands(camera, tf, background, options, surface_t, surfaces)
        shared = self._shared_image(W, H, np.float64 if options.precision == "float64" else np.float32)
        # every device gets its request before any reply is waited for; each writes its rows into
        # the shared image and answers with its stats and row costs only
        replies, errors, waiting = [None] * len(bands), [], {}
        dropped, self._dropped = self._dropped, []
        for k, (p, band) in enumerate(zip(self._procs, bands)):
            try:
                p.send("render_shared", camera, tf, background, options, band, surface_t, surfaces, shared.spec,
                       dropped)
                waiting[p.fileno()] = k
            except RenderError as exc:
                errors.append(exc)
        rgba = np.empty_like(shared.rgba)
        aux = np.empty_like(shared.aux)
        while waiting:  # a band's rows are copied out while the others still render
            for conn in multiprocessing.connection.wait([self._procs[k] for k in waiting.values()]):
                k = waiting.pop(conn.fileno())
                try:
                    replies[k] = conn.reply()
                except RenderError as exc:
                    errors.append(exc)
                    continue
                b0, b1 = bands[k]
                rgba[b0:b1] = shared.rgba[b0:b1]
                aux[b0:b1] = shared.aux[b0:b1]
        if errors:  # every device has answered: the pipes stay in step for the next frame
            raise errors[0]
        parts = list(zip(bands, replies))
        seconds = time.perf_counter() - t0
        result = merge_results(parts, W, H, seconds, image=(rgba, aux))
        result.stats.update(split_by=split_by, prepass_seconds=prepass_seconds)
        # each device's speed: the geometric mean of what it had and what this frame measured
        # (one frame's timing is noisy, and a band's fixed costs do not scale with its rows)
        speeds = np.array([max(float(r.row_cost.sum()), 1e-9) / max(r.stats["render_seconds"], 1e-6) for _, r in parts])
        speeds = np.concatenate([speeds, self._speeds[len(speeds):]])
        self._speeds = speeds if self._row_cost is None else np.sqrt(self._speeds * speeds)
        self._speeds /= self._speeds.max()
        self._row_cost = result.row_cost
        if progress is not None:
            progress(1.0)
        return result

    def _shared_image(self, width: int, height: int, dtype) -> SharedImage:
        """The shared image of this size and dtype (the last frame's if it matches, else a new one;
        the old one unlinked: a process still attached to it closes it on its next frame)."""
        spec = (int(width), int(height), np.dtype(dtype).str)
        if self._shared is None or self._shared.spec[:3] != spec:
            if self._shared is not None:
                self._shared.close()
                self._shared = None
            self._shared = SharedImage(width, height, dtype)
            # every process opens it now; then its name goes (nothing can be left in /dev/shm)
            errors = []
            try:
                for p in self._procs:
                    p.send("attach", self._shared.spec)
                for p in self._procs:  # every reply read: the pipes stay in step
                    try:
                        p.reply()
                    except RenderError as exc:
                        errors.append(exc)
            finally:
                self._shared.unlink()
            if errors:
                raise errors[0]
        return self._shared

    def close(self, timeout: float = 10.0):
        for p in getattr(self, "_procs", []):
            p.close(timeout)
        self._procs = []
        shared, self._shared = getattr(self, "_shared", None), None
        if shared is not None:
            shared.close()

    def __enter__(self):
        return self

    def __exit__(self, exc_type, *exc):
        self.close(timeout=0 if exc_type is not None else 10.0)  # an interrupted frame is not waited for

    def __del__(self):
        self.close()


def make_renderer(mesh, device: str = "cpu", max_tile_rays: int | None = None, frame: Frame | None = None):
    """A Renderer for one device, a MultiDeviceRenderer for a list ("cuda:0,cuda:1", "cuda:all");
    with `frame`, UnsupportedFrame before any process starts where that renderer cannot draw it."""
    devices = expand_devices(device)
    cls = Renderer if len(devices) == 1 else MultiDeviceRenderer
    if frame is not None:
        check_frame(cls, frame)
    if cls is Renderer:
        return Renderer(mesh, devices[0], max_tile_rays=max_tile_rays)
    precision = frame.options.precision if frame is not None else "float32"
    return MultiDeviceRenderer(mesh, devices, max_tile_rays=max_tile_rays, precision=precision)
