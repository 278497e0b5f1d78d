"""Host side of a render: upload a VolumeMesh once per device, launch the ray kernels in rounds
over launch tiles, gather stats. The CLI and the add-on import this module only when they
render, so it imports Warp (and the kernels) at the top."""
from __future__ import annotations

import hashlib
import itertools
import os
import sys
import threading
import time
from dataclasses import dataclass, field

import numpy as np
import warp as wp

from . import field_frame, limits, shapes
from .isosurfaces import Surfaces, reference_gradient
from .adjacency import face_neighbours, vertex_affine_guess
from .faces import element_faces, face_mesh
from .camera import RayCamera
from .kernels import quadrature_tables
from .kernels.args import MAX_SAMPLES, SEGMENTS_PER_ROUND
from .kernels.element import static_modes
from .kernels.precision import Precision
from .limits import cpu_cores
from .mesh import (MeshError, VolumeMesh, boxes_diagonal, element_coefficient_scale, element_field_ranges,
                   element_volumes, mapped_coefficients, padded_element_boxes)
from .methods import METHOD_IDS
from .shipped_kernels import CPU_COMPILER_FLAGS, LoadReport, load_shipped
from .tensor_geometry import mesh_tensor_geometry
from .transfer_function import TransferFunction
from .view import AUTO_STEP_ERROR, RenderOptions, resolving_step

_INNER_IDS = {"spectral": 0, "trapezoid": 1}


class RenderError(RuntimeError):
    """A render that could not run (device unavailable, out of memory); the message says why."""


class SegmentCacheError(RenderError):
    """A segment cache that cannot be built (out of device memory, beyond 32-bit offsets) or
    that does not hold this view's segments (traced for another camera, field or frame)."""


@dataclass
class RenderResult:
    rgba: np.ndarray  # (H, W, 4) float32, RGB = C + T*background, A = 1 - T; row 0 at the top
    stats: dict
    depth: np.ndarray | None = None  # (H, W) t where 1 - T first reaches 0.5, else the far value
    error: np.ndarray | None = None  # (H, W) sum of the Gauss-Kronrod panel error estimates
    cancelled: bool = False
    # (H,) the work each row took (ray_cost of its pixels' counters): what a render split over
    # several devices balances its rows by (engine/multi_device.py)
    row_cost: np.ndarray | None = None
    # (rows, W, NUM_STATS) int32: every ray's counters, with render(ray_counts=True) (work_counts)
    ray_counts: np.ndarray | None = None


_WARP_READY = False
_WARP_LOCK = threading.Lock()  # Warp starts once, whichever thread asks first


def _init_warp():
    """Initialise Warp once, on the first device look-up (device probing deferred until a render
    needs it). Warp's greeting, module-load lines and its native "no CUDA driver" line are shown
    only with HOVR_DEBUG=1: on a machine without a GPU they are noise on every render."""
    global _WARP_READY
    with _WARP_LOCK:
        if not _WARP_READY:
            _start_warp()
            _WARP_READY = True


def _start_warp():
    # portable CPU objects: the add-on's shipped kernels (shipped_kernels.py) match on any CPU
    wp.config.cpu_compiler_flags = CPU_COMPILER_FLAGS
    debug = bool(os.environ.get("HOVR_DEBUG"))
    wp.config.log_level = wp.LOG_INFO if debug else wp.LOG_ERROR
    if debug:
        wp.init()
        return
    # the driver probe prints from C to the process's stderr: hold fd 2 on /dev/null meanwhile
    sys.stderr.flush()
    saved = os.dup(2)
    try:
        with open(os.devnull, "w") as null:
            os.dup2(null.fileno(), 2)
            wp.init()
    finally:
        os.dup2(saved, 2)
        os.close(saved)


def resolve_device(device: str) -> str:
    _init_warp()
    try:
        return str(wp.get_device(device))
    except (RuntimeError, ValueError) as exc:
        avail = ", ".join(str(d) for d in wp.get_devices())
        raise RenderError(f"Warp device {device!r} is not available here (available: {avail})") from exc


def cuda_devices() -> list[str]:
    """The names of the CUDA devices here ("cuda:0", ...); empty without a GPU."""
    _init_warp()
    return [str(d) for d in wp.get_devices() if d.is_cuda]


def expand_devices(devices) -> list[str]:
    """A device list: "cpu", "cuda:1", "cuda:0,cuda:1" (or a list of names), "cuda:all" / "all"
    for every CUDA device here, or "cpu:all" for one CPU device a core (Warp runs a CPU launch
    on one thread, so the cores are used by one process each); each name resolved (RenderError
    for one that is not here)."""
    names = [d.strip() for d in (devices.split(",") if isinstance(devices, str) else devices) if d.strip()]
    if not names:
        raise RenderError("no device named")
    out = []
    for name in names:
        if name in ("all", "cuda:all"):
            cuda = cuda_devices()
            if not cuda:
                raise RenderError(f"{name!r}: there is no CUDA device here")
            out.extend(cuda)
        elif name == "cpu:all":
            out.extend(["cpu"] * cpu_cores())
        else:
            out.append(resolve_device(name))
    return out


FLOAT32_LIMIT = 1.0e30  # beyond this, products in the kernel overflow float32 (max 3.4e38)
MAX_ROUNDS_PER_TILE = 100000  # every round takes each ray a step further; far more than any mesh needs
EVAL_ERROR_FACTOR = 64.0  # mesh field_err: eps * sum |c_m| max|phi_m| times this (see _upload)
GEO_ERROR_FACTOR = 64.0  # the same for the geometry's x(xi) (geometry_rounding)
# launch tiles (Renderer._tile_limit): a GPU tile may take this share of the free device memory.
# H100, paper-scale 1920x1080: 8 tiles of 2^18 rays ran 49 rounds (curved), most of them the
# few-ray tails of each tile, where a round costs the latency of its slowest ray
TILE_MEMORY_FRACTION = 0.25
TILE_LIMIT_SHARE = 0.5  # of the memory limit (engine/limits.py) a CPU launch tile's buffers may take
MIN_TILE_RAYS = 1 << 16
MAX_TILE_RAYS = 1 << 22
CPU_TILE_RAYS = 1 << 18
WARP_SIZE = 32  # the rays a GPU warp runs together: the work counts' divergence blocks, lane occupancy
# a ray's work in the units of one field evaluation, from its counters (kernels/args.py STAT_*):
# each element segment costs about a Newton solve's evaluations, each face crossing the search
# polishes a few (2-4 map evaluations), and a ray a few for its search and finalize. A
# load-balancing estimate, not a timing model.
RAY_COST_BASE = 8.0
RAY_COST_SEGMENT = 16.0
RAY_COST_LOCATE = 4.0
# threads compiling kernel modules at once on first use (Warp's NVRTC / LLVM compile one module
# per thread); HOVR_COMPILE_WORKERS=1 compiles them one after another
COMPILE_WORKERS = max(1, int(os.environ.get("HOVR_COMPILE_WORKERS", "0") or 0) or min(8, os.cpu_count() or 1))
# a segment cache grows by this factor when a round needs more room (then shrinks to fit)
CACHE_GROWTH = 1.5
CACHE_MIN_SEGMENTS = 1 << 12
SUM_THREADS = 1 << 14  # threads summing a shade's per-ray counters on the device
INT32_MAX = 2**31 - 1
_RENDERER_IDS = itertools.count()  # a renderer's identity in its caches' keys (id() is reused)

def kernel_variant(meshes) -> tuple[bool, int, bool]:
    """(curved, modes, derived): what the walk kernels of a render of `meshes` (one mesh, or
    several merged by mesh.concatenate) are specialised to (kernels/raycast.walk_kernels)."""
    meshes = list(meshes)
    curved = any(m.affine is not None and not m.affine.all() for m in meshes)
    derived = any(m.derived is not None for m in meshes)
    modes = 0 if derived else static_modes(np.concatenate([m.shape for m in meshes]),
                                           np.concatenate([m.modes for m in meshes]))
    return bool(curved), int(modes), derived


def render_kernels(variant: tuple[bool, int], precision: str = "float32", isosurfaces: bool = False) -> list:
    """Every kernel Renderer.render launches for a mesh of kernel_variant `variant` (with
    `isosurfaces`: a look with isosurfaces or planes, contract §7)."""
    kernels = Precision.named(precision).kernels
    table = kernels.kernel_table(*variant, isosurfaces=isosurfaces)
    return [table[name] for name in kernels.RENDER_KERNELS]


def session_kernels(variant: tuple[bool, int], precision: str = "float32", surfaces: bool = False,
                    isosurfaces: bool = False) -> list:
    """The kernels of render_kernels, the re-shade of a transfer-function edit, and the surface
    cast with `surfaces`: what an interactive session (Blender) loads before its first render, and
    what the add-on ships compiled (scripts/build_extension.py); with `isosurfaces`, integrate and
    shade in their variant for isosurfaces and planes."""
    kernels = render_kernels(variant, precision, isosurfaces)
    kernels.append(Precision.named(precision).kernels.kernel_table(*variant, isosurfaces=isosurfaces)["shade"])
    if surfaces:
        from .kernels import surfaces as surface_kernels

        kernels.append(surface_kernels.cast_surfaces)
    return kernels


def load_kernels(variant: tuple[bool, int], device: str = "cpu", precision: str = "float32",
                 surfaces: bool = False, isosurfaces: bool = False) -> LoadReport:
    """Load the session_kernels of `variant` in `precision` on `device`: from the add-on's
    shipped binaries where they were built from this source, else compiled on first use (tens of
    seconds on a CPU) or read from Warp's kernel cache on disk. The modules compile side by side
    in worker threads joined before it returns."""
    return load_modules(session_kernels(variant, precision, surfaces, isosurfaces), resolve_device(device))


def load_modules(kernels, device: str) -> LoadReport:
    """Load the modules of `kernels` on `device`: the shipped binaries of their source where the
    add-on has them (shipped_kernels.py), the rest compiled (first use) or read from Warp's disk
    cache, side by side (on first use the largest module's compile is the wait)."""
    report = load_shipped(kernels, device)
    modules = list({id(k.module): k.module for k in kernels}.values())
    workers = min(len(modules), COMPILE_WORKERS) if COMPILE_WORKERS > 1 else 0
    wp.force_load(device=device, modules=modules, max_workers=workers)
    return report


def _check_float32_range(what: str, values, offsets):
    """float32 kernels need data well inside float32's range: name the first element that is not."""
    if values is None or values.size == 0:
        return
    big = np.abs(values.reshape(len(values), -1)).max(axis=1) > FLOAT32_LIMIT
    if big.any():
        e = int(np.searchsorted(offsets, int(np.argmax(big)), side="right") - 1)
        raise RenderError(f"element {e}: {what} exceed the float32 kernels' range (|value| > {FLOAT32_LIMIT:.0e}); "
                          f"render with precision float64 or rescale the data")


def _outward(lo, hi, dtype):
    """lo, hi cast to dtype, rounded outward (a certified range stays one)."""
    lo_c, hi_c = lo.astype(dtype), hi.astype(dtype)
    lo_c = np.where(lo_c > lo, np.nextafter(lo_c, dtype.type(-np.inf)), lo_c)
    hi_c = np.where(hi_c < hi, np.nextafter(hi_c, dtype.type(np.inf)), hi_c)
    return lo_c, hi_c


def polynomial_degree(shape, modes):
    """Degree along a straight line of an element's (weighted) expansion: kernels/element.py's."""
    d = np.maximum(np.asarray(modes) - 1, 1)
    return np.select([shape == shapes.TET, shape == shapes.PRISM, shape == shapes.PYR],
                     [d.max(axis=1), np.maximum(d[:, 0], d[:, 2]) + d[:, 1], d.sum(axis=1) + 2], d.sum(axis=1))


def geometry_rounding(geo_offset, geo_coeffs, geo_centre, eps: float) -> np.ndarray:
    """Per element, how far x(xi) can be off by rounding (machine epsilon `eps`; kernels/args.py geo_err):
    the Legendre values are at most 1 on the reference box, so each coordinate is a sum of terms
    no larger than its coefficients, plus the centre added back (tensor_geometry's layout:
    element e's coefficients run from its offset to the next element's)."""
    offset = np.asarray(geo_offset, dtype=np.int64)
    ends = np.append(offset[1:], len(geo_coeffs))
    cs = np.concatenate([np.zeros((1, 3)), np.cumsum(np.abs(geo_coeffs), axis=0)])
    absum = (cs[ends] - cs[offset]).max(axis=1) + np.abs(np.asarray(geo_centre)).max(axis=1)
    return GEO_ERROR_FACTOR * eps * absum


def sample_stride(mesh: VolumeMesh, geo_degree) -> int:
    """Threads per slot in the sample kernel: the most sample points a first pass needs
    (restriction.restriction_degree + 1, curved: curved_base_degree + 1). Not rounded up to a
    power of two: a warp may then hold parts of two slots, but no lane idles (order 6, 19 points:
    a stride of 32 left 13 of 32 lanes idle, H100 profile of the sample kernel)."""
    deg = polynomial_degree(mesh.shape, mesh.modes)
    if mesh.affine is not None:
        curved = ~mesh.affine
        full = np.minimum(deg + geo_degree, MAX_SAMPLES - 5)  # restriction.curved_base_degree
        half = (full + 1) // 2
        deg = np.where(curved, np.maximum(np.where(2 * half > MAX_SAMPLES - 5, full, half), 2), deg)
    return int(deg.max()) + 1


class Renderer:
    """Holds one mesh uploaded to one Warp device (BVH included); render() many views with it."""

    def __init__(self, mesh: VolumeMesh, device: str = "cpu", max_tile_rays: int | None = None,
                 regroup: bool = True):
        # bounds the per-render buffers (about 4 kB a ray in float32); None: from the device's memory
        self.max_tile_rays = None if max_tile_rays is None else int(max_tile_rays)
        # the rays regrouped between rounds (_regroup); False: in the order the last round left them
        self.regroup = bool(regroup)
        self.device = resolve_device(device)
        self.mesh = mesh
        self._id = next(_RENDERER_IDS)
        self._field_version = 0  # replace_field counts up: segment caches of an older field are stale
        self.kernel_variant = kernel_variant([mesh])
        # curved segments and a derived field's are interpolants, refined where their tails say
        self._interpolants = self.kernel_variant[0] or self.kernel_variant[2]
        self._uploads = {}  # precision name -> _Upload
        # the field's frame (engine/field_frame.py) follows the transfer functions: the float64
        # data stays here, the device holds it mapped into the last frame rendered
        self._volume = element_volumes(mesh)
        self.volumes = int(self._volume.max()) + 1
        self._field_lo, self._field_hi = element_field_ranges(mesh)
        self._coeff_scale = element_coefficient_scale(mesh)
        self._gradient = None  # the field's reference gradient (isosurfaces.reference_gradient), on first use
        self.data_ranges = self.volume_ranges(mesh, self._field_lo, self._field_hi)
        self._bytes_per_ray = {}  # precision name -> launch-tile bytes per ray (_tile_limit)
        t0 = time.perf_counter()
        with wp.ScopedDevice(self.device):
            self._box_lo, self._box_hi = padded_element_boxes(mesh)
            # no ray is longer inside the data than this (the fixed-step methods' samples per ray)
            self.data_diagonal = boxes_diagonal(self._box_lo, self._box_hi)
            # every element's faces as triangles, their boxes grown by the bound in a BVH grouped by
            # element (kernels/crossing.py); Warp's BVH is float32 in both precisions (padded boxes:
            # conservative either way)
            self.faces = face_mesh(mesh, element_faces(mesh))
            scale = float(np.abs(self.faces.points).max(initial=1.0))
            t_lo, t_hi = self.faces.boxes(1e-5 * scale)
            self._lowers = wp.array(t_lo.astype(np.float32), dtype=wp.vec3)
            self._uppers = wp.array(t_hi.astype(np.float32), dtype=wp.vec3)
            self._groups = wp.array((self.faces.owner // shapes.MAX_FACES).astype(np.int32), dtype=wp.int32)
            self._bvh = wp.Bvh(self._lowers, self._uppers, groups=self._groups)
            self._neighbour = wp.array(face_neighbours(mesh), dtype=wp.int32)
            self._affine_guess = vertex_affine_guess(mesh)
        try:
            self._upload("float32")  # the default precision, uploaded up front
        except RenderError:
            pass  # data float32 cannot hold: render() says so, unless asked for float64
        self.upload_seconds = time.perf_counter() - t0

    @staticmethod
    def volume_ranges(mesh: VolumeMesh, lo=None, hi=None) -> list[tuple[float, float]]:
        """(min, max) of the field per volume: what the field's frame is chosen from
        (engine/field_frame.py; a part of a mesh rendered apart takes the whole mesh's, so that
        every part rounds alike: engine/sort_last.py)."""
        if lo is None:
            lo, hi = element_field_ranges(mesh)
        volume = element_volumes(mesh)
        return [(float(lo[volume == k].min()), float(hi[volume == k].max())) for k in range(int(volume.max()) + 1)]

    def same_geometry(self, mesh: VolumeMesh) -> bool:
        """Whether `mesh` has this renderer's elements, geometry and field layout (shapes, modes,
        bases, coefficient offsets, volumes): then replace_field takes its field without a new
        upload of the geometry and BVH (a series of snapshots on one mesh)."""
        old = self.mesh
        if mesh is old:
            return True

        def same(a, b):
            return (a is None and b is None) or (a is not None and b is not None and np.array_equal(a, b))

        return kernel_variant([mesh]) == self.kernel_variant and all(same(getattr(mesh, k), getattr(old, k)) for k in (
            "shape", "modes", "basis", "coeff_offset", "geom_modes", "geom_offset", "geom_coeffs", "affine", "volume"))

    def replace_field(self, mesh: VolumeMesh):
        """Render `mesh`'s field from now on; its geometry must be this renderer's (same_geometry).
        Only the field goes to the device, on the next render (the BVH, geometry and compiled
        kernels stay)."""
        if not self.same_geometry(mesh):
            raise RenderError("replace_field needs the same elements and geometry; make a new Renderer")
        self.mesh = mesh
        self._field_version += 1
        self._field_lo, self._field_hi = element_field_ranges(mesh)
        self._coeff_scale = element_coefficient_scale(mesh)
        self._gradient = None  # the field's reference gradient (isosurfaces.reference_gradient), on first use
        self.data_ranges = self.volume_ranges(mesh, self._field_lo, self._field_hi)
        for upload in self._uploads.values():
            upload.field_key = None  # _set_field maps and uploads the new coefficients
            upload.gradient = None

    def _tile_buffers(self, prec, tile, stats):
        """Per-ray state and the round's segment buffer for `tile` rays (allocated per render:
        a few hundred bytes per ray, plus SEGMENTS_PER_ROUND * MAX_SAMPLES samples)."""
        allocated = []

        def zeros(n, dtype):
            a = wp.zeros(n, dtype=dtype)
            allocated.append(a)
            return a

        kernels = prec.kernels
        rays = kernels.RayState()
        rays.color_t = zeros(tile, prec.vec4)
        rays.depth_err = zeros(tile, prec.vec2)
        rays.surface_end = zeros(tile, prec.vec2)
        rays.t_cur = zeros(tile, prec.scalar)
        rays.t_end = zeros(tile, prec.scalar)
        rays.t_search = zeros(tile, prec.scalar)
        rays.next_element = zeros(tile, wp.int32)
        rays.left_element = zeros(tile, wp.int32)
        rays.entry_r = zeros(tile, prec.vec4)
        rays.entry_dv = zeros(tile, prec.vec4)
        rays.phase = zeros(tile, wp.int32)
        rays.stats = stats
        rays.active = zeros(tile, wp.int32)
        rays.active_next = zeros(tile, wp.int32)
        rays.active_count = zeros(1, wp.int32)
        segs = kernels.Segments()
        slots = tile * kernels.SEGMENTS_PER_ROUND
        segs.count = zeros(tile, wp.int32)
        segs.element = zeros(slots, wp.int32)
        segs.t0 = zeros(slots, prec.scalar)
        segs.t1 = zeros(slots, prec.scalar)
        segs.degree = zeros(slots, wp.int32)
        segs.flags = zeros(slots, wp.int32)
        segs.tail = zeros(slots, prec.scalar)
        segs.xi0 = zeros(slots, prec.vec3)
        segs.v0 = zeros(slots, prec.vec3)
        segs.xi1 = zeros(slots, prec.vec3)
        segs.v1 = zeros(slots, prec.vec3)
        segs.samples = zeros(slots * MAX_SAMPLES, prec.scalar)
        segs.coeffs = zeros(slots * MAX_SAMPLES, prec.scalar)
        segs.step_terms = zeros(slots, prec.vec3)
        segs.list = zeros(slots, wp.int32)
        segs.list_count = zeros(1, wp.int32)
        # a curved slot refined (degree doubled) goes on one of these for its odd points
        again = [zeros(slots, wp.int32) for _ in range(2)]
        again_count = [zeros(1, wp.int32) for _ in range(2)]
        # the next round's list sorted by regroup_keys (radix sort: room for twice the rays)
        sort_keys = zeros(2 * tile, wp.int64)
        sort_values = zeros(2 * tile, wp.int32)
        return _TileBuffers(rays, segs, again, again_count, sort_keys, sort_values, sum(a.capacity for a in allocated))

    def _launch_tile(self, prec, rays: int, progress, tile_pixels) -> int:
        """Rays per launch tile of a render of `rays` rays: the progress/cancel unit (tile_pixels,
        65,536 by default, when progress is reported), within what the buffers may take."""
        tile = rays if progress is None else max(1, int(tile_pixels or 65536))
        return min(tile, self._tile_limit(prec), rays)

    def _tile_limit(self, prec) -> int:
        """Rays per launch tile: max_tile_rays if given; on a GPU, what TILE_MEMORY_FRACTION of
        its free memory holds (one tile per frame where it fits: every tile ends in rounds of
        few rays, which leave the GPU idle; a 1920x1080 frame is one launch on a card with
        about 32 GB free); on the CPU, CPU_TILE_RAYS within TILE_LIMIT_SHARE of the memory limit,
        which guards host memory (a GPU tile's buffers are the device's: check_limits)."""
        if self.max_tile_rays is not None:
            return self.max_tile_rays
        dev = wp.get_device(self.device)
        if not dev.is_cuda:
            policy = limits.current().max_memory * TILE_LIMIT_SHARE / self._ray_bytes(prec)
            return int(max(1024, min(CPU_TILE_RAYS, policy)))
        return int(np.clip(dev.free_memory * TILE_MEMORY_FRACTION / self._ray_bytes(prec), MIN_TILE_RAYS,
                           MAX_TILE_RAYS))

    def _ray_bytes(self, prec) -> float:
        """Bytes of launch-tile buffers per ray, measured once per precision on a small tile."""
        if prec.name not in self._bytes_per_ray:
            probe = 1024
            with wp.ScopedDevice(self.device):
                stats = wp.zeros((1, prec.kernels.NUM_STATS), dtype=wp.int32)
                self._bytes_per_ray[prec.name] = self._tile_buffers(prec, probe, stats).nbytes / probe
        return self._bytes_per_ray[prec.name]

    def check_limits(self, width: int, height: int, options: RenderOptions, tile: int | None = None) -> int:
        """Refuse a render the resource policy does not allow (engine/limits.py), before
        anything is allocated: the image's buffers against the memory limit, and for the
        fixed-step methods the samples a ray may take across the data (its box diagonal / h;
        classified without h never steps below the diagonal / that limit). The launch tile's
        buffers count where they are host memory (the CPU device); on a GPU the tile follows the
        device's free memory (_tile_limit). Returns the bytes counted."""
        self._check_steps(options)
        prec = self._upload(options.precision).precision
        rays = min(int(width) * int(height), tile if tile is not None else CPU_TILE_RAYS)
        if wp.get_device(self.device).is_cuda:
            rays = 0
        return limits.check_bytes(options.image_bytes(width, height, prec.kernels.NUM_STATS)
                                  + rays * self._ray_bytes(prec), f"a {width}x{height} image in {options.precision}")

    def _check_steps(self, options: RenderOptions):
        """A derived field only with a method that samples it, and a fixed step against the
        samples-per-ray limit across the data (RenderOptions.check_steps)."""
        if self.mesh.derived is not None and options.method not in _SAMPLING_METHODS:
            raise RenderError(f"{self.mesh.field_name} is sampled exactly at each point and integrated on its "
                              f"series: method classified or split, not {options.method}")
        options.check_steps(self.data_diagonal)

    def mesh_args(self, precision: str = "float32"):
        """The uploaded MeshArgs struct with the field in its own units (for kernels that
        evaluate the mesh, e.g. tests)."""
        upload = self._upload(precision)
        self._set_field(upload, self.identity_frame())
        return upload.mesh_args

    def _upload(self, name: str) -> _Upload:
        """Mesh arrays and kernels for the precision called `name` (float64 on first use)."""
        if name in self._uploads:
            return self._uploads[name]
        prec = Precision.named(name)
        raycast = prec.kernels
        mesh = self.mesh
        if name == "float32":
            _check_float32_range("geometry", mesh.geom_coeffs, mesh.geom_offset)
        fdt, v3, m33, scalar = prec.dtype, prec.vec3, prec.mat33, prec.scalar
        with wp.ScopedDevice(self.device):
            m = raycast.MeshArgs()
            m.bvh = self._bvh.id
            faces = self.faces
            m.face_points = wp.array(faces.points.astype(fdt), dtype=v3)
            m.face_xi = wp.array(faces.xi.astype(fdt), dtype=v3)
            m.face_tris = wp.array(faces.triangles.astype(np.int32), dtype=wp.vec3i)
            m.face_owner = wp.array(faces.owner.astype(np.int32), dtype=wp.int32)
            m.face_bound = float(faces.bound)
            m.has_affine = int(mesh.affine is None or bool(mesh.affine.any()))
            m.shape = wp.array(mesh.shape.astype(np.int32), dtype=wp.int32)
            # affine elements: the exact map; curved ones: Newton's straight-sided start
            guess = self._affine_guess
            m.ref_a = wp.array(guess[:, :, :3].astype(fdt), dtype=m33)
            m.ref_b = wp.array(guess[:, :, 3].astype(fdt), dtype=v3)
            m.neighbour = self._neighbour
            m.modes = wp.array(mesh.modes.astype(np.int32), dtype=wp.vec3i)
            m.basis = wp.array(mesh.basis.astype(np.int32), dtype=wp.int32)
            if mesh.coeffs.size >= 2**31:
                raise RenderError("field too large for 32-bit coefficient offsets")
            m.coeff_offset = wp.array(mesh.coeff_offset.astype(np.int32), dtype=wp.int32)
            n = mesh.num_elements
            affine = np.ones(n, np.int32) if mesh.affine is None else mesh.affine.astype(np.int32)
            m.affine = wp.array(affine, dtype=wp.int32)
            gdeg, goff, gco, gcen = mesh_tensor_geometry(mesh)
            if gco.shape[0] >= 2**31:
                raise RenderError("curved geometry too large for 32-bit offsets")
            m.geo_degree = wp.array(gdeg.astype(np.int32), dtype=wp.int32)
            m.geo_offset = wp.array(goff.astype(np.int32), dtype=wp.int32)
            m.geo_coeffs = wp.array(gco.astype(fdt), dtype=v3)
            m.geo_centre = wp.array(gcen.astype(fdt), dtype=v3)
            m.geo_err = wp.array(geometry_rounding(goff, gco, gcen, prec.eps).astype(fdt), dtype=scalar)
            m.box_lo = wp.array(self._box_lo.astype(fdt), dtype=v3)
            m.box_hi = wp.array(self._box_hi.astype(fdt), dtype=v3)
            x, wk, wg = quadrature_tables.gauss_kronrod_15()
            S = quadrature_tables.integration_matrix(x)
            gk = [wp.array(a.astype(fdt), dtype=scalar) for a in (x, wk, wg)]
            gk_s = wp.array(S.astype(fdt), dtype=scalar)
            # affine-only meshes get search, traverse and sample kernels without the curved machinery
            table = raycast.kernel_table(*self.kernel_variant)
            self._sample_stride = sample_stride(mesh, gdeg)
        self._uploads[name] = _Upload(prec, m, gk, gk_s, table)
        return self._uploads[name]

    def _kernels(self, upload: _Upload, isosurfaces: bool) -> dict:
        """The upload's kernel table, integrate and shade in their variant for isosurfaces and
        planes where the look has them (kernels.kernel_table)."""
        if not isosurfaces:
            return upload.kernels
        return upload.precision.kernels.kernel_table(*self.kernel_variant, isosurfaces=True)

    def _surface_args(self, upload: _Upload, fr: field_frame.FieldFrame, surfaces: Surfaces | None,
                      options: RenderOptions):
        """The kernels' SurfaceArgs of `surfaces` with the field in frame `fr` (none: the default
        struct, which changes nothing); the reference gradient is uploaded once per frame."""
        prec = upload.precision
        surf = prec.kernels.SurfaceArgs()
        if not surfaces:
            return surf
        if options.method not in _SAMPLING_METHODS:
            raise RenderError(f"isosurfaces and planes are found on the segments' series: method classified or "
                              f"split, not {options.method}")
        colour = surfaces.color_ramp(self.mesh.derived.spec if self.mesh.derived is not None else None)
        surfaces.check(self.data_ranges, self._box_lo.min(axis=0), self._box_hi.max(axis=0))
        lo, hi, _ = upload.field
        arrays = surfaces.device_arrays(fr.scale, fr.shift, self._volume, lo, hi, self._box_lo, self._box_hi)
        if upload.gradient is None or upload.gradient[0] != fr.key:
            if self._gradient is None:
                self._gradient = reference_gradient(self.mesh)
            counts = np.diff(np.append(self.mesh.coeff_offset, self.mesh.coeffs.shape[0]))
            scale = np.repeat(fr.scale[self._volume], counts)  # f' = a f + b: its gradient is a grad f
            with wp.ScopedDevice(self.device):
                upload.gradient = (fr.key, wp.array((self._gradient * scale).ravel().astype(prec.dtype), dtype=prec.scalar))
        with wp.ScopedDevice(self.device):
            surf.n_iso = len(arrays["iso_s"])
            surf.n_planes = len(arrays["plane"])
            surf.iso_s = wp.array(arrays["iso_s"].astype(prec.dtype), dtype=prec.scalar)
            surf.iso_rgba = wp.array(arrays["iso_rgba"].astype(prec.dtype), dtype=prec.vec4)
            surf.plane = wp.array(arrays["plane"].astype(prec.dtype), dtype=prec.vec4)
            surf.plane_style = wp.array(arrays["plane_style"].astype(prec.dtype), dtype=prec.vec4)
            surf.keep = wp.array(arrays["keep"], dtype=wp.int32)
            surf.iso_color_by = wp.array(np.array([-1 if by is None else _derived_kernels(prec).OPERATION_IDS[by]
                                                   for by in colour["by"]], np.int32), dtype=wp.int32)
            surf.ramp_s = wp.array(colour["s"].astype(prec.dtype), dtype=prec.scalar)
            surf.ramp_rgb = wp.array(colour["rgb"].astype(prec.dtype), dtype=prec.vec3)
        surf.grad_stride = int(self.mesh.coeffs.shape[0])
        surf.grad = upload.gradient[1]
        return surf

    def identity_frame(self) -> field_frame.FieldFrame:
        return field_frame.FieldFrame(np.ones(self.volumes), np.zeros(self.volumes))

    def _set_field(self, upload: _Upload, fr: field_frame.FieldFrame):
        """The field on the device mapped into frame `fr`: coefficients, certified ranges and
        rounding sizes (kept while the frame stays the same)."""
        if upload.field_key == fr.key:
            return
        prec, m, mesh = upload.precision, upload.mesh_args, self.mesh
        a, b = fr.scale[self._volume], fr.shift[self._volume]
        try:
            coeffs = mapped_coefficients(mesh, a, b)
        except MeshError as exc:
            raise RenderError(str(exc)) from exc
        if prec.name == "float32":
            _check_float32_range("field coefficients", coeffs, mesh.coeff_offset)
        # the map of a certified range, widened by the map's rounding, then cast outward
        eps64 = float(np.finfo(np.float64).eps)
        lo, hi = a * self._field_lo + b, a * self._field_hi + b
        pad = 2 * eps64 * (a * np.maximum(np.abs(self._field_lo), np.abs(self._field_hi)) + np.abs(b))
        flo, fhi = _outward(lo - pad, hi + pad, prec.dtype)
        # a sample is a sum of terms of this size: its rounding error, and the interpolant's
        # (Lebesgue constant of <= 48 Chebyshev-Lobatto points < 4) times a few ulps per term;
        # plus the map's own rounding of the coefficients (b on each of at most 8 vertex modes)
        rounding = prec.eps * element_coefficient_scale(mesh, coeffs) + eps64 * (a * self._coeff_scale + 8 * np.abs(b))
        with wp.ScopedDevice(self.device):
            m.coeffs = wp.array(coeffs.astype(prec.dtype), dtype=prec.scalar)
            if mesh.derived is not None:
                m.derived = _derived_args(prec, mesh.derived, a, b)
            m.field_lo = wp.array(flo, dtype=prec.scalar)
            m.field_hi = wp.array(fhi, dtype=prec.scalar)
            m.field_err = wp.array((EVAL_ERROR_FACTOR * rounding).astype(prec.dtype), dtype=prec.scalar)
        upload.field_key = fr.key
        upload.field = (lo, hi, rounding)

    def field_frame(self, tfs, precision: str = "float32"):
        """(frame, transfer function in frame units, warnings) for transfer functions `tfs` (one
        per volume), with the field on the device mapped into that frame."""
        tfs = [tfs] if isinstance(tfs, TransferFunction) else list(tfs)
        if len(tfs) != self.volumes:
            raise RenderError(f"{len(tfs)} transfer functions for {self.volumes} volumes")
        upload = self._upload(precision)
        fr, tf = field_frame.frame(tfs, self.data_ranges)
        self._set_field(upload, fr)
        lo, hi, rounding = upload.field
        warnings = field_frame.resolution_warnings(tfs, fr, self._volume, lo, hi, rounding, precision)
        return fr, tf, warnings

    def render(self, camera: RayCamera, tf, background, options: RenderOptions,
               progress=None, tile_pixels: int | None = None, profile: bool = False,
               rows: tuple[int, int] | None = None, out: tuple[np.ndarray, np.ndarray] | None = None,
               surface_t=None, ray_counts: bool = False, surfaces: Surfaces | None = None) -> RenderResult:
        """Render one image through `tf`, a TransferFunction or a list of one per volume
        (VolumeMesh.volume). stats["warnings"] says where the precision cannot resolve a
        transfer function. With `progress`, the image is launched in tiles of `tile_pixels`
        pixels and progress(fraction_done) is called after each; returning False cancels
        (the result then has cancelled=True and only the finished tiles filled in). With `profile`,
        every launch is waited for and stats["kernel_seconds"] gives the time per kernel (the
        waits add a little to render_seconds). With `rows` = (first, end), only the image rows
        first .. end - 1 are traced and the result holds those rows (each pixel exactly as in the
        whole image: a ray is the same ray whichever launch traces it). With `out` = (rgba, aux),
        host arrays of the whole image, (H, W, 4) and (H, W, 2) in the precision's dtype, the rows
        are written into them (aux: depth, error) and the result's arrays are views of those rows
        (engine/multi_device.py: the devices' processes write into one shared image). With
        `surface_t`, an (H, W) array of the whole image (rows from the top), each pixel's ray
        integrates the volume only up to t = surface_t[j, i] along its unit ray (the first opaque
        surface: engine/surfaces.py; +inf where none); the depth output is then that t where the
        volume's opacity stays under 0.5. With `ray_counts`, the result's ray_counts holds every
        ray's work counters (kernels/args.py STAT_*; work_counts summarises them). `surfaces`:
        isosurfaces and cut planes (contract §7), composited with the volume in depth order."""
        upload = self._upload(options.precision)
        prec = upload.precision
        kernels = prec.kernels
        W, H = int(camera.width), int(camera.height)
        total = W * H
        row0, row1 = (0, H) if rows is None else (int(rows[0]), int(rows[1]))
        if not 0 <= row0 < row1 <= H:
            raise RenderError(f"rows {row0}..{row1} are not inside a {W}x{H} image")
        first, end = row0 * W, row1 * W
        fr, tf_frame, warnings = self.field_frame(tf, options.precision)
        options, step_warnings = resolving_step(options, tf, self.data_ranges)
        warnings = warnings + step_warnings
        with wp.ScopedDevice(self.device):
            cam = camera_args(prec, camera)
            limit = _surface_limit(prec, surface_t, W, H)
            transfer = _transfer_args(prec, tf_frame)
            transfer.surf = self._surface_args(upload, fr, surfaces, options)
            quad = _quad_args(prec, options, background, upload, self.data_diagonal)
            tile = self._launch_tile(prec, end - first, progress, tile_pixels)
            self.check_limits(W, H, options, tile)
            try:
                rgba = wp.zeros(total, dtype=prec.vec4)
                aux = wp.zeros(total, dtype=prec.vec2)
                stats = wp.zeros((total, kernels.NUM_STATS), dtype=wp.int32)
                buffers = self._tile_buffers(prec, tile, stats)
            except RuntimeError as exc:  # allocation failure on the device
                raise RenderError(f"cannot allocate a {W}x{H} image on {self.device}: {exc}") from exc
            load_kernels(self.kernel_variant, self.device, options.precision,  # compiled outside the timed region
                         isosurfaces=bool(surfaces))
            wp.synchronize_device(self.device)
            launch = _Launcher(self.device, profile, self._kernels(upload, bool(surfaces)))
            t0 = time.perf_counter()
            cancelled = False
            rounds = 0
            lanes = _LaneCounts(kernels) if ray_counts else None
            for start in range(first, end, tile):
                n = min(tile, end - start)
                rounds += self._trace_tile(launch, upload, cam, transfer, quad, buffers, start, n, limit, lanes=lanes)
                launch("finalize", n, [quad, start, buffers.rays, rgba, aux])
                if progress is not None:
                    wp.synchronize_device(self.device)
                    if progress((start + n - first) / (end - first)) is False:
                        cancelled = True
                        break
            wp.synchronize_device(self.device)
            seconds = time.perf_counter() - t0
            # only the rows traced come back from the device; the counters summed per row in int64
            # without an int64 copy of them (the same integers: what the row costs and stats need)
            img = rgba[first:end].numpy().reshape(row1 - row0, W, 4)
            depth_err = aux[first:end].numpy().reshape(row1 - row0, W, 2)
            ray_array = stats[first:end].numpy().reshape(row1 - row0, W, -1)
            row_counts = ray_array.sum(axis=1, dtype=np.int64)
            per_ray = ray_array.copy() if ray_counts else None
            counts = row_counts.sum(axis=0)
            row_cost = ray_cost(kernels, row_counts, W)
        if out is not None:
            out_rgba, out_aux = out
            np.copyto(out_rgba[row0:row1], img)
            np.copyto(out_aux[row0:row1], depth_err)
            img, depth_err = out_rgba[row0:row1], out_aux[row0:row1]
        elif not wp.get_device(self.device).is_cuda:
            img, depth_err = img.copy(), depth_err.copy()  # not views of Warp's arrays on the CPU
        if not np.all(np.isfinite(img)):
            raise RenderError("the render produced non-finite pixels (NaN/Inf in the data or transfer function?)")
        info = {"device": self.device, "render_seconds": seconds, "width": W, "height": H, "method": options.method,
                "parameters": options.as_dict(), **_counter_stats(kernels, counts, end - first), "rounds": rounds,
                **({"rows": [row0, row1]} if rows is not None else {}),
                **({"kernel_seconds": launch.seconds} if profile else {}),
                **({"lane_occupancy": lanes.occupancy()} if lanes is not None else {}),
                "elements": self.mesh.num_elements, "precision": options.precision, "warnings": warnings}
        return RenderResult(depth=depth_err[..., 0], error=depth_err[..., 1], cancelled=cancelled, rgba=img,
                            stats=info, row_cost=row_cost, ray_counts=per_ray)

    def _trace_tile(self, launch: _Launcher, upload: _Upload, cam, transfer, quad, buffers: _TileBuffers, start: int,
                    n: int, limit: tuple, record=None, lanes: _LaneCounts | None = None) -> int:
        """Rays start .. start + n of the image, in rounds until none is left: search, traverse,
        sample, integrate (or record(active rays): a trace keeps the segments instead), the next
        round's rays regrouped (_regroup). With `lanes`, the lanes of each search and traverse
        launch that have work are counted. Returns the rounds."""
        rays, segs = buffers.rays, buffers.segs
        launch("init_rays", n, [cam, start, rays, *limit])
        active = n  # rounds run over the rays still going (rays.active, compacted by integrate)
        rounds = 0
        while active > 0:
            rays.active_count.zero_()
            segs.list_count.zero_()
            if lanes is not None:
                lanes.count("search", rays, active, start)
            launch("search", active, [upload.mesh_args, cam, start, rays])
            if self.regroup and active > WARP_SIZE:  # the rays that walk on by element, those done last
                self._regroup(launch, buffers, active)
            if lanes is not None:
                lanes.count("traverse", rays, active, start)
            launch("traverse", active, [upload.mesh_args, cam, transfer, quad, start, rays, segs])
            if lanes is not None:
                lanes.walked(rays)
            listed = self._sample_segments(launch, upload, cam, start, buffers)
            if record is None:
                if listed and quad.method == METHOD_IDS["classified"] and quad.h == 0.0:  # its own steps
                    launch("step_terms", listed,
                           [upload.mesh_args, transfer, quad, segs, segs.list])
                launch("integrate", active,
                       [upload.mesh_args, cam, transfer, quad, start, rays, segs])
            else:
                record(active)
            rounds += 1
            active = int(rays.active_count.numpy()[0])
            rays.active, rays.active_next = rays.active_next, rays.active
            if self.regroup and active > WARP_SIZE:  # the rays that search first
                self._regroup(launch, buffers, active)
            if rounds > MAX_ROUNDS_PER_TILE:
                raise RenderError(f"the traversal did not finish after {rounds} rounds ({active} rays "
                                  f"still going): a bug, please report it with the data")
        return rounds

    def _regroup(self, launch: _Launcher, buffers: _TileBuffers, active: int):
        """The list of rays (rays.active) sorted by kernels.regroup_keys: the rays that search first,
        then by the element each walks into, then those whose walk is over, each group in pixel
        order, so the lanes of a warp search together or walk the same element (the atomic
        compaction that builds each round's list leaves the rays in any order on a GPU). Run before
        each round's search and before its traverse. Each ray's work is its own: no image or count
        changes."""
        rays = buffers.rays
        launch("regroup_keys", active, [rays, buffers.sort_keys, buffers.sort_values])
        wp.utils.radix_sort_pairs(buffers.sort_keys, buffers.sort_values, active)
        wp.copy(rays.active, buffers.sort_values, count=active)

    def _sample_segments(self, launch: _Launcher, upload: _Upload, cam, start: int, buffers: _TileBuffers) -> int:
        """The samples of the segments traverse listed, then their Chebyshev coefficients; curved
        interpolants whose tail is too large get their degree doubled (twice at most). Returns how
        many segments were listed."""
        rays, segs, again, again_count = buffers.rays, buffers.segs, buffers.again, buffers.again_count
        listed = int(segs.list_count.numpy()[0])
        if listed == 0:
            return 0
        stride = self._sample_stride
        odd_stride = (MAX_SAMPLES - 5) // 2 + 1  # the odd points of a doubled degree, at most
        launch("sample", listed * stride,
               [upload.mesh_args, cam, start, segs, segs.list, stride, 0, rays.stats])
        if self._interpolants:
            slots, count, n_slots = segs.list, segs.list_count, listed
            for p in range(2):
                again_count[p].zero_()
                launch("refine", n_slots, [start, rays, segs, slots, count, again[p], again_count[p], 1])
                n_slots = int(again_count[p].numpy()[0])
                if n_slots == 0:
                    break
                launch("sample", n_slots * odd_stride,
                       [upload.mesh_args, cam, start, segs, again[p], odd_stride, 1, rays.stats])
                slots, count = again[p], again_count[p]
            if n_slots > 0:  # the last refined slots: their tails, no more doubling
                launch("refine", n_slots, [start, rays, segs, slots, count, again[0], again_count[0], 0])
        launch("coefficients", listed * stride, [segs, segs.list, stride])
        return listed

    # ------------------------------------------------------------------ the segment cache

    def trace_key(self, camera: RayCamera, options: RenderOptions, rows: tuple[int, int] | None = None,
                  surface_key=None) -> TraceKey:
        """What a trace's segments depend on, besides the field's frame (TraceKey). The transfer
        function, density, colours, background, tolerance, h, the inner rule and
        min_transmittance are not in it: the shade kernel takes those."""
        H = int(camera.height)
        row0, row1 = (0, H) if rows is None else (int(rows[0]), int(rows[1]))
        return TraceKey(self._id, self._field_version, options.precision, options.method in _SAMPLING_METHODS,
                        _camera_key(camera), (row0, row1), surface_key)

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
              held_bytes: int = 0, profile: bool = False) -> SegmentCache:
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
            limit = _surface_limit(prec, surface_t, W, H)
            transfer = _transfer_args(prec, _DENSE_EVERYWHERE)
            quad = _quad_args(prec, options, np.zeros(3), upload, self.data_diagonal)
            tile = self._launch_tile(prec, end - first, progress, tile_pixels)
            what = f"the segment cache of a {W}x{H} image in {options.precision}"
            # the render's buffers, the caller's other caches, and per tile ray its reservation
            # (vec3i) and last chunk (int32)
            base_bytes = self.check_limits(W, H, options, tile) + int(held_bytes) + tile * 16
            try:
                stats = wp.zeros((W * H, kernels.NUM_STATS), dtype=wp.int32)
                buffers = self._tile_buffers(prec, tile, stats)
                reserved = wp.zeros(tile, dtype=wp.vec3i)
                last_chunk = wp.zeros(tile, dtype=wp.int32)
                store = _CacheStore(prec, end - first, base_bytes, what)
            except RuntimeError as exc:
                raise SegmentCacheError(f"cannot allocate {what} on {self.device}: {exc}") from exc
            load_modules([upload.kernels[name] for name in kernels.TRACE_KERNELS], self.device)
            wp.synchronize_device(self.device)
            launch = _Launcher(self.device, profile, upload.kernels)
            t0 = time.perf_counter()
            complete = True
            rounds = 0
            for start in range(first, end, tile):
                n = min(tile, end - start)
                last_chunk.fill_(-1)

                def record(active, ray_offset=start - first):
                    rays, segs = buffers.rays, buffers.segs
                    store.check_offsets(active)
                    launch("trace_reserve", active, [rays, segs, store.args(), reserved])
                    store.ensure(*(int(v) for v in store.counts.numpy()))
                    launch("trace_write", active * SEGMENTS_PER_ROUND,
                           [rays, segs, store.args(), reserved, last_chunk, ray_offset])

                rounds += self._trace_tile(launch, upload, cam, transfer, quad, buffers, start, n, limit, record)
                launch("trace_ends", n, [buffers.rays, store.args(), start - first])
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
                **_counter_stats(kernels, counts, end - first),
                **({"kernel_seconds": launch.seconds} if profile else {})}
        return SegmentCache(key=key, frame_key=fr.key, camera=camera, rows=(row0, row1), arrays=store.arrays,
                            counts=store.used(), complete=complete, stats=info, warnings=warnings)

    def shade(self, cache: SegmentCache, tf, background, options: RenderOptions, progress=None,
              tile_pixels: int | None = None, profile: bool = False, surfaces: Surfaces | None = None) -> RenderResult:
        """The render of the cache's view through `tf` (a TransferFunction or one per volume), with
        this background and these options, from the cached segments alone: one kernel, a thread per
        ray, integrating as the render's integrate kernel does (kernels/cache.py shade), so the
        image equals render(camera, tf, background, options) of the same view. SegmentCacheError
        where the cache does not fit: another renderer or field, a precision or a method family
        (riemann/trapezoid against classified/split) other than the trace's, a transfer function
        whose frame differs from the trace's (trace again), or an unfinished trace. progress,
        tile_pixels and profile as in render; stats["segment_cache"] describes the cache."""
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
            transfer = _transfer_args(prec, tf_frame)
            transfer.surf = self._surface_args(upload, fr, surfaces, options)
            quad = _quad_args(prec, options, background, upload, self.data_diagonal)
            try:
                rgba = wp.zeros(n, dtype=prec.vec4)
                aux = wp.zeros(n, dtype=prec.vec2)
                counters = wp.zeros((n, num_stats), dtype=wp.int32)
                sums = wp.zeros(num_stats, dtype=wp.int64)
                nonfinite = wp.zeros(1, dtype=wp.int32)
            except RuntimeError as exc:
                raise RenderError(f"cannot allocate a {W}x{row1 - row0} image on {self.device}: {exc}") from exc
            table = self._kernels(upload, bool(surfaces))
            load_modules([table[name] for name in kernels.SHADE_KERNELS], self.device)
            wp.synchronize_device(self.device)
            launch = _Launcher(self.device, profile, table)
            args = cache.args(kernels)
            t0 = time.perf_counter()
            tile = n if progress is None else max(1, int(tile_pixels or 65536))
            cancelled = False
            for start in range(0, n, tile):
                k = min(tile, n - start)
                launch("shade", k, [upload.mesh_args, cam, transfer, quad, row0 * W, start, args, rgba,
                                                   aux, counters, nonfinite])
                if progress is not None:
                    wp.synchronize_device(self.device)
                    if progress((start + k) / n) is False:
                        cancelled = True
                        break
            threads = min(n, SUM_THREADS)
            launch("sum_counts", threads, [counters, threads, sums])
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
                "method": options.method, "parameters": options.as_dict(), **_counter_stats(kernels, counts, n),
                **({"rows": [row0, row1]} if cache.rows != (0, int(camera.height)) else {}),
                **({"kernel_seconds": launch.seconds} if profile else {}),
                "elements": self.mesh.num_elements, "precision": options.precision, "warnings": warnings,
                "segment_cache": cache.describe()}
        return RenderResult(depth=depth_err[..., 0], error=depth_err[..., 1], cancelled=cancelled, rgba=img, stats=info)


@dataclass
class _Upload:
    """One precision's mesh on the device and the kernels specialised for it (Renderer._upload)."""

    precision: Precision
    mesh_args: object  # kernels.MeshArgs
    gk: list  # Gauss-Kronrod nodes, Kronrod and Gauss weights
    gk_s: object  # the spectral integration matrix on the nodes
    kernels: dict  # every kernel by name, the walk's specialised for the mesh (kernels.kernel_table)
    field_key: tuple | None = None  # the FieldFrame.key of the field on the device (Renderer._set_field)
    field: tuple | None = None  # its (lo, hi, rounding) per element, in frame units
    gradient: tuple | None = None  # (field_key, the reference gradient on the device in that frame)


@dataclass
class _TileBuffers:
    """A launch tile's per-ray state and round buffers (Renderer._tile_buffers)."""

    rays: object  # kernels.RayState
    segs: object  # kernels.Segments
    again: list  # per refine pass: the slots whose degree it doubled (their odd points to sample)
    again_count: list
    sort_keys: object  # the next round's list and its keys while they are sorted (Renderer._regroup)
    sort_values: object
    nbytes: int


class _LaneCounts:
    """For render(ray_counts=True): per kernel, the lanes of its launches' 32-lane groups (the
    round's list in order, as a GPU's warps take it) that have work, over the lanes of the groups
    that have any (occupancy 1: a warp's lanes all work; 1/32: one works while 31 wait); and the
    traverse launches' divergence: over the groups with work, the mean of each group's largest
    lane's walk work (Newton iterations and steps) over its lanes' mean. Read on the host around
    the launches (a measurement: it waits for the device)."""

    def __init__(self, kernels):
        self.kernels = kernels
        self.busy = {"search": 0, "traverse": 0}
        self.lanes = {"search": 0, "traverse": 0}
        self.walk_ratio, self.walk_groups = 0.0, 0
        self._walking = None

    def count(self, kernel: str, rays, active: int, pixel_offset: int):
        ids = rays.active.numpy()[:active]
        nxt, phase = rays.next_element.numpy()[ids], rays.phase.numpy()[ids]
        work = (phase == 0) & ((nxt < 0) if kernel == "search" else (nxt >= 0))
        groups = np.pad(work, (0, -active % WARP_SIZE)).reshape(-1, WARP_SIZE)
        self.busy[kernel] += int(groups.sum())
        self.lanes[kernel] += WARP_SIZE * int(groups.any(axis=1).sum())
        if kernel == "traverse":
            self._walking = (ids + pixel_offset, self._walk_work(rays, ids + pixel_offset))

    def _walk_work(self, rays, pixels):
        c = rays.stats.numpy()[pixels]
        return c[:, self.kernels.STAT_NEWTON_WALK].astype(np.int64) + c[:, self.kernels.STAT_WALKS]

    def walked(self, rays):
        """After a traverse launch: its lanes' work (counted since count("traverse", ...))."""
        pixels, before = self._walking
        work = np.pad(self._walk_work(rays, pixels) - before, (0, -len(pixels) % WARP_SIZE)).reshape(-1, WARP_SIZE)
        busy = work.max(axis=1) > 0
        self.walk_ratio += float((work[busy].max(axis=1) / work[busy].mean(axis=1)).sum())
        self.walk_groups += int(busy.sum())

    def occupancy(self) -> dict:
        out = {k: self.busy[k] / self.lanes[k] if self.lanes[k] else 1.0 for k in self.busy}
        out["traverse_divergence"] = self.walk_ratio / self.walk_groups if self.walk_groups else 1.0
        return out


class _Launcher:
    """wp.launch by kernel name (a name kernels.kernel_table lacks is a KeyError on any device);
    with `profile`, each launch is waited for and timed."""

    def __init__(self, device: str, profile: bool, kernels: dict):
        self.device = device
        self.profile = profile
        self.kernels = kernels
        self.seconds = {name: 0.0 for name in kernels}

    def __call__(self, name: str, dim: int, inputs: list):
        kernel = self.kernels[name]
        t_launch = time.perf_counter()
        wp.launch(kernel, dim=dim, inputs=inputs)
        if self.profile:
            wp.synchronize_device(self.device)
            self.seconds[name] += time.perf_counter() - t_launch


def camera_args(prec: Precision, camera: RayCamera):
    cam = prec.kernels.CameraArgs()
    for name in ("o0", "ou", "ov", "d0", "du", "dv"):
        setattr(cam, name, prec.vec3(*map(float, getattr(camera, name))))
    cam.width, cam.height = int(camera.width), int(camera.height)
    cam.t_min = float(camera.t_min)
    cam.t_max = float(min(camera.t_max, 1e30))
    cam.clip_axis = prec.vec3(*map(float, camera.clip_axis))
    cam.clip_near = float(camera.clip_near)
    cam.clip_far = float(min(camera.clip_far, 1e30))
    return cam


def _surface_limit(prec: Precision, surface_t, width: int, height: int) -> tuple:
    """init_rays' (t_limit, use_limit): the per-pixel far limit on the device, or a one-element
    dummy and 0 (no surfaces: nothing is uploaded and the kernel reads nothing)."""
    if surface_t is None:
        return wp.zeros(1, dtype=prec.scalar), 0
    t = np.asarray(surface_t, dtype=np.float64)
    if t.shape != (height, width):
        raise RenderError(f"surface_t has shape {t.shape}, the image is {height}x{width}")
    if np.isnan(t).any() or (t < 0).any():
        raise RenderError("surface_t must be >= 0 (+inf where no surface), without NaN")
    return wp.array(np.minimum(t, 1e30).astype(prec.dtype).ravel(), dtype=prec.scalar), 1


def _derived_kernels(prec: Precision):
    """kernels/derived.py of this precision (its operation ids)."""
    return sys.modules[prec.kernels.__name__.rpartition(".")[0] + ".derived"]


def _derived_args(prec: Precision, field, scale, shift):
    """The kernels' DerivedArgs of a mesh's DerivedField (engine/derived_fields.py), its
    samples mapped into the frame f' = scale f + shift (per element)."""
    dk = _derived_kernels(prec)
    kind = dk.OPERATION_IDS[field.spec.operation] + (dk.PER_DENSITY if field.components == 4 else 0)
    if field.coeffs.size >= 2**31:
        raise RenderError("derived field too large for 32-bit coefficient offsets")
    if prec.name == "float32":
        _check_float32_range("derived field components", field.coeffs, field.offset)
    d = prec.kernels.DerivedArgs()
    d.active = 1
    d.kind = wp.array(np.where(field.derived, kind, dk.FIELD).astype(np.int32), dtype=wp.int32)
    d.offset = wp.array(field.offset.astype(np.int32), dtype=wp.int32)
    d.size = wp.array(field.size.astype(np.int32), dtype=wp.int32)
    d.modes = wp.array(field.modes.astype(np.int32), dtype=wp.vec3i)
    d.coeffs = wp.array(field.coeffs.astype(prec.dtype), dtype=prec.scalar)
    d.axes = wp.array(field.axes.astype(prec.dtype), dtype=prec.mat33)
    d.frame = wp.array(np.stack([scale, shift], axis=1).astype(prec.dtype), dtype=prec.vec2)
    return d


def _transfer_args(prec: Precision, tf: TransferFunction):
    transfer = prec.kernels.TransferArgs()
    transfer.color_s = wp.array(tf.color_s.astype(prec.dtype), dtype=prec.scalar)
    transfer.color_rgb = wp.array(tf.color_rgb.astype(prec.dtype), dtype=prec.vec3)
    transfer.density_s = wp.array(tf.density_s.astype(prec.dtype), dtype=prec.scalar)
    transfer.density_tau = wp.array(tf.density_tau.astype(prec.dtype), dtype=prec.scalar)
    return transfer


def _quad_args(prec: Precision, options: RenderOptions, background, upload: _Upload, diagonal: float):
    quad = prec.kernels.QuadArgs()
    quad.method = METHOD_IDS[options.method]
    quad.inner = _INNER_IDS[options.inner]
    quad.h = 0.0 if options.h is None else float(options.h)  # 0: classified's own step per segment
    max_samples = int(limits.current().max_samples_per_ray)
    quad.max_steps = max_samples + 1
    quad.h_min = diagonal / max_samples  # so a ray takes no more samples than with the smallest fixed h allowed
    quad.step_error = AUTO_STEP_ERROR
    quad.tol = float(options.tolerance)
    quad.min_transmittance = float(options.min_transmittance)
    quad.background = prec.vec3(*map(float, np.asarray(background, dtype=np.float64).reshape(3)))
    quad.gk_x, quad.gk_wk, quad.gk_wg = upload.gk
    quad.gk_s = upload.gk_s
    return quad


_SAMPLING_METHODS = ("classified", "split")  # their segments carry series; riemann and trapezoid evaluate
# what a trace traverses with: density 1 at every value, so no element is skipped as transparent
_DENSE_EVERYWHERE = TransferFunction(np.zeros(1), np.zeros((1, 3)), np.zeros(1), np.ones(1))


def _camera_key(camera: RayCamera) -> tuple:
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
    surface_hits: object = None  # engine/surfaces.py keeps the hits that stopped the rays here

    @property
    def rays(self) -> int:
        return (self.rows[1] - self.rows[0]) * int(self.camera.width)

    @property
    def nbytes(self) -> int:
        return int(sum(a.capacity for a in self.arrays.values()))

    def args(self, kernels):
        """The kernels' SegmentCache struct of these arrays (kernels of the cache's precision)."""
        return _cache_struct(kernels, self.arrays)

    def describe(self) -> dict:
        """Its size: bytes in all, per ray and per segment (a segment's record, its series and its
        share of the chunks), segments and coefficients, and the trace's time."""
        segments, chunks, coefficients = self.counts
        per_ray_arrays = sum(self.arrays[k].capacity for k in ("head", "t_end"))
        return {"bytes": self.nbytes, "bytes_per_ray": self.nbytes / max(self.rays, 1),
                "bytes_per_segment": (self.nbytes - per_ray_arrays) / max(segments, 1), "segments": segments,
                "segments_per_ray": segments / max(self.rays, 1), "chunks": chunks,
                "coefficients_per_segment": coefficients / max(segments, 1),
                "trace_seconds": self.stats.get("trace_seconds")}


class _CacheStore:
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
        return _cache_struct(self.prec.kernels, self.arrays)


def _cache_struct(kernels, arrays: dict):
    """The kernels' SegmentCache struct of a cache's device arrays."""
    s = kernels.SegmentCache()
    for name, a in arrays.items():
        setattr(s, name, a)
    return s


def render_cached(renderer, camera: RayCamera, tf, background, options: RenderOptions,
                  cache: SegmentCache | None = None, rows: tuple[int, int] | None = None, surface_t=None,
                  surface_key=None, held_bytes: int = 0, progress=None,
                  tile_pixels: int | None = None, surfaces: Surfaces | None = None) -> tuple[RenderResult, SegmentCache | None]:
    """(RenderResult, SegmentCache or None): the view shaded from `cache` where it holds this
    view's segments (Renderer.cache_fits), else traced anew (Renderer.trace) and shaded, the new
    cache returned for the next call; the image is renderer.render's either way. A renderer that
    keeps no segments (several devices: engine/multi_device.py) renders plainly, and so does a view
    whose cache the memory limit or the device refuses (stats["segment_cache"] says why); None
    comes back then. A cancelled trace (progress returned False) gives a cancelled result."""
    if not isinstance(renderer, Renderer):
        kw = {k: v for k, v in (("rows", rows), ("surface_t", surface_t), ("surfaces", surfaces)) if v is not None}
        return renderer.render(camera, tf, background, options, progress=progress, tile_pixels=tile_pixels, **kw), None
    if surface_t is not None and surface_key is None:
        surface_key = surface_digest(surface_t)
    if renderer.cache_fits(cache, camera, tf, options, rows, surface_key):
        return renderer.shade(cache, tf, background, options, progress=progress, tile_pixels=tile_pixels,
                              surfaces=surfaces), cache
    try:
        cache = renderer.trace(camera, tf, options, rows=rows, surface_t=surface_t, surface_key=surface_key,
                               progress=progress, tile_pixels=tile_pixels, held_bytes=held_bytes)
    except (limits.ResourceLimitError, SegmentCacheError) as exc:
        res = renderer.render(camera, tf, background, options, progress=progress, tile_pixels=tile_pixels, rows=rows,
                              surface_t=surface_t, surfaces=surfaces)
        res.stats["segment_cache"] = {"refused": str(exc)}
        return res, None
    if not cache.complete:
        W = int(camera.width)
        r0, r1 = (0, int(camera.height)) if rows is None else rows
        dtype = Precision.named(options.precision).dtype
        return RenderResult(rgba=np.zeros((r1 - r0, W, 4), dtype), stats={"segment_cache": cache.describe()},
                            depth=np.zeros((r1 - r0, W), dtype), error=np.zeros((r1 - r0, W), dtype),
                            cancelled=True), None
    res = renderer.shade(cache, tf, background, options, progress=progress, tile_pixels=tile_pixels, surfaces=surfaces)
    res.stats["render_seconds"] += cache.stats["trace_seconds"]  # this call traced and shaded
    return res, cache


def ray_cost(kernels, counts: np.ndarray, rays: int | np.ndarray = 1) -> np.ndarray:
    """The work of `rays` rays whose counters summed to `counts` (..., NUM_STATS), in field
    evaluations (RAY_COST_*)."""
    counts = np.asarray(counts, dtype=np.float64)
    return (counts[..., kernels.STAT_FIELD_EVALS] + counts[..., kernels.STAT_RESTRICTION_EVALS]
            + RAY_COST_SEGMENT * counts[..., kernels.STAT_SEGMENTS] + RAY_COST_LOCATE * counts[..., kernels.STAT_LOCATES]
            + RAY_COST_BASE * np.asarray(rays, dtype=np.float64))


def work_counts(kernels, ray_counts: np.ndarray) -> dict:
    """The work counts of a render (RenderResult.ray_counts): per counter, its mean per ray and its
    divergence, the mean over blocks of WARP_SIZE consecutive rays (a warp's rays in the first
    round: pixels in row order) of the block's largest count over its mean (1: every ray of a
    block works alike; blocks with no work are left out). Samples are field plus restriction
    evaluations; `work` is ray_cost's estimate."""
    c = np.asarray(ray_counts, dtype=np.int64).reshape(-1, kernels.NUM_STATS)
    series = {"bvh_candidates": c[:, kernels.STAT_BVH_CANDIDATES],
              "newton_search": c[:, kernels.STAT_NEWTON_SEARCH], "newton_walk": c[:, kernels.STAT_NEWTON_WALK],
              "newton_sample": c[:, kernels.STAT_NEWTON_SAMPLE],
              "element_locations": c[:, kernels.STAT_LOCATES], "segments": c[:, kernels.STAT_SEGMENTS],
              "samples": c[:, kernels.STAT_FIELD_EVALS] + c[:, kernels.STAT_RESTRICTION_EVALS],
              "walks": c[:, kernels.STAT_WALKS], "rounds": c[:, kernels.STAT_ROUNDS],
              "work": ray_cost(kernels, c)}
    rays = len(c)
    out = {"rays": rays}
    for name, v in series.items():
        v = np.asarray(v, dtype=np.float64)
        blocks = np.pad(v, (0, -rays % WARP_SIZE)).reshape(-1, WARP_SIZE)
        fill = np.minimum(WARP_SIZE, rays - WARP_SIZE * np.arange(len(blocks)))  # the last block's rays
        mean = blocks.sum(axis=1) / fill
        busy = mean > 0
        out[name] = {"per_ray": float(v.sum() / max(rays, 1)),
                     "divergence": float((blocks.max(axis=1)[busy] / mean[busy]).mean()) if busy.any() else 1.0}
    return out


def _counter_stats(kernels, counts: np.ndarray, pixels: int) -> dict:
    """The render's stats from the per-ray counters summed over the image (kernels/args.py STAT_*)."""
    return {
        "field_evaluations": int(counts[kernels.STAT_FIELD_EVALS]),
        "restriction_evaluations": int(counts[kernels.STAT_RESTRICTION_EVALS]),
        "samples_per_ray": float((counts[kernels.STAT_FIELD_EVALS] + counts[kernels.STAT_RESTRICTION_EVALS]) / pixels),
        "segments": int(counts[kernels.STAT_SEGMENTS]),
        "segments_empty": int(counts[kernels.STAT_EMPTY]),
        "segments_smooth": int(counts[kernels.STAT_SMOOTH]),
        "segments_piecewise_smooth": int(counts[kernels.STAT_PIECEWISE]),
        "curved_locates": int(counts[kernels.STAT_LOCATES]),
        "walks": int(counts[kernels.STAT_WALKS]),
        "bvh_candidates": int(counts[kernels.STAT_BVH_CANDIDATES]),
        "newton_iterations": int(counts[kernels.STAT_NEWTON_SEARCH] + counts[kernels.STAT_NEWTON_WALK]
                                 + counts[kernels.STAT_NEWTON_SAMPLE]),
        "ray_rounds": int(counts[kernels.STAT_ROUNDS]),
    }
