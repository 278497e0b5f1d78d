"""Host side of a render, the frame loop: upload a VolumeMesh once per device (BVH included), map
its field into the transfer functions' frame, launch the ray kernels in rounds over launch tiles
and gather the image and its stats. Its neighbours each hold one job of it: render_result.py (the
result and the errors), devices.py, kernel_loading.py (what a mesh's render compiles and loads),
launch_args.py (what the kernels are launched with), segment_cache.py (trace and shade: the
segments kept for transfer-function edits) and work_counts.py (the counters' summaries). The CLI
and the add-on import this module only when they render (engine/frame.render_frame, the door),
so it imports Warp (and the kernels) at the top."""
from __future__ import annotations

import itertools
import queue
import time

import numpy as np
import warp as wp

from . import field_frame, limits, shapes
from .adjacency import face_maps, face_neighbours, vertex_affine_guess
from .camera import RayCamera
from .devices import resolve_device
from .faces import element_faces, face_mesh
from .frame import Capability
from .isosurfaces import Surfaces, reference_gradient
from .kernel_loading import kernel_table, kernel_variant, load_kernels
from .kernels.args import MAX_SAMPLES
from .kernels.precision import Precision
from .looks import sampled_ranges
from .launch_args import (EVAL_ERROR_FACTOR, Launcher, TileBuffers, Upload, camera_args, derived_args, gauss_kronrod,
                          mesh_args, outward, quad_args, sample_stride, surface_args, surface_limit, tile_buffers,
                          transfer_args)
from .mesh import (AFFINE_RTOL_FLOAT32, MeshError, VolumeMesh, affine_twin, boxes_diagonal, element_coefficient_scale,
                   element_field_ranges, element_volumes, mapped_coefficients, padded_element_boxes)
from .methods import SAMPLING_METHODS, chooses_own_step, samples_segments
from .render_result import RenderError, RenderResult, check_float32_range
from .segment_cache import SegmentCaching
from .threads import MIN_THREAD_RAYS, TILES_PER_THREAD, in_threads
from .transfer_function import TransferFunction
from .view import RenderOptions, resolving_step
from .work_counts import WARP_SIZE, LaneCounts, counter_stats, ray_cost

MAX_ROUNDS_PER_TILE = 100000  # every round takes each ray a step further; far more than any mesh needs
# launch tiles (Renderer._tile_limit): a GPU tile may take this share of the free device memory.
# H100, paper-scale 1920x1080: 8 tiles of 2^18 rays ran 49 rounds (curved), most of them the
# few-ray tails of each tile, where a round costs the latency of its slowest ray
TILE_MEMORY_FRACTION = 0.25
TILE_LIMIT_SHARE = 0.5  # of the memory limit (engine/limits.py) a CPU launch tile's buffers may take
MIN_TILE_RAYS = 1 << 16
MAX_TILE_RAYS = 1 << 22
CPU_TILE_RAYS = 1 << 18
_RENDERER_IDS = itertools.count()  # a renderer's identity in its caches' keys (id() is reused)


class Renderer(SegmentCaching):
    """Holds one mesh uploaded to one Warp device (BVH included); render() many views with it
    (engine/frame.render_frame: everything a Frame can hold; SegmentCaching: trace and shade)."""

    capabilities = frozenset(Capability)
    kind = "on one device"

    def __init__(self, mesh: VolumeMesh, device: str = "cpu", max_tile_rays: int | None = None,
                 regroup: bool = True):
        # bounds the per-render buffers (about 4 kB a ray in float32); None: from the device's memory
        self.max_tile_rays = None if max_tile_rays is None else int(max_tile_rays)
        # the rays regrouped between rounds (_regroup); False: in the order the last round left them
        self.regroup = bool(regroup)
        self.device = resolve_device(device)
        # threads a CPU render's tiles run on (limits.cpu_threads); 1 where the caller already runs
        # one renderer a core (All CPU Cores' processes, a Dask worker's frames)
        self.cpu_threads = limits.cpu_threads()
        self.mesh = mesh
        self._id = next(_RENDERER_IDS)
        self._field_version = 0  # replace_field counts up: segment caches of an older field are stale
        self.kernel_variant = kernel_variant([mesh])
        # curved segments and a derived field's are interpolants, refined where their tails say
        self._interpolants = self.kernel_variant.curved or self.kernel_variant.derived
        self._uploads = {}  # precision name -> Upload
        # the field's frame (engine/field_frame.py) follows the transfer functions: the float64
        # data stays here, the device holds it mapped into the last frame rendered
        self._volume = element_volumes(mesh)
        self.volumes = int(self._volume.max()) + 1
        self._field_lo, self._field_hi = element_field_ranges(mesh)
        self._coeff_scale = element_coefficient_scale(mesh)
        self._gradient = None  # the field's reference gradient (isosurfaces.reference_gradient), on first use
        self.data_ranges = self.volume_ranges(mesh, self._field_lo, self._field_hi)
        self._sampled_ranges = None  # sampled_ranges, on first use
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
            neighbours = face_neighbours(mesh)
            self._neighbour = wp.array(neighbours, dtype=wp.int32)
            self._face_maps = face_maps(mesh, neighbours)
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
        self._sampled_ranges = None
        for upload in self._uploads.values():
            upload.field_key = None  # _set_field maps and uploads the new coefficients
            upload.gradient = None

    def close(self):
        """Release the device arrays of the uploads (the renderer uploads again if used after)."""
        self._uploads.clear()

    def __enter__(self):
        return self

    def __exit__(self, *exc):
        self.close()

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
            policy = limits.current().max_memory * TILE_LIMIT_SHARE / self.tile_bytes_per_ray(prec)
            return int(max(1024, min(CPU_TILE_RAYS, policy)))
        return int(np.clip(dev.free_memory * TILE_MEMORY_FRACTION / self.tile_bytes_per_ray(prec), MIN_TILE_RAYS,
                           MAX_TILE_RAYS))

    def tile_bytes_per_ray(self, prec) -> float:
        """Bytes of launch-tile buffers per ray, measured once per precision on a small tile."""
        if prec.name not in self._bytes_per_ray:
            probe = 1024
            with wp.ScopedDevice(self.device):
                stats = wp.zeros((1, prec.kernels.NUM_STATS), dtype=wp.int32)
                self._bytes_per_ray[prec.name] = tile_buffers(prec, probe, stats).nbytes / probe
        return self._bytes_per_ray[prec.name]

    def device_bytes(self, precision: str = "float32") -> int:
        """Bytes of the mesh on the device in `precision`: its MeshArgs arrays and the BVH's boxes."""
        m = self._upload(precision).mesh_args
        arrays = [getattr(m, name, None) for name in dir(m)]
        return sum(a.capacity for a in arrays if isinstance(a, wp.array)) + self._lowers.capacity + self._uppers.capacity

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
                                  + rays * self.tile_bytes_per_ray(prec), f"a {width}x{height} image in {options.precision}")

    def _check_steps(self, options: RenderOptions):
        """A derived field only with a method that samples it, and a fixed step against the
        samples-per-ray limit across the data (RenderOptions.check_steps)."""
        if self.mesh.derived is not None and not samples_segments(options.method):
            raise RenderError(f"{self.mesh.field_name} is sampled exactly at each point and integrated on its "
                              f"series: method classified or split, not {options.method}")
        options.check_steps(self.data_diagonal)

    def mesh_args(self, precision: str = "float32"):
        """The uploaded MeshArgs struct with the field in its own units (for kernels that
        evaluate the mesh, e.g. tests)."""
        upload = self._upload(precision)
        self._set_field(upload, self.identity_frame())
        return upload.mesh_args

    def _upload(self, name: str) -> Upload:
        """Mesh arrays and kernels for the precision called `name` (float64 on first use)."""
        if name in self._uploads:
            return self._uploads[name]
        prec = Precision.named(name)
        if name == "float32":
            check_float32_range("geometry", self.mesh.geom_coeffs, self.mesh.geom_offset)
        # float32 walks an element whose map is affine to its own rounding of the coordinates as
        # affine (mesh.AFFINE_RTOL_FLOAT32); the faces, BVH and neighbours stay the mesh's (a
        # curved element's triangles enclose it either way)
        geometry = affine_twin(self.mesh, AFFINE_RTOL_FLOAT32) if name == "float32" else self.mesh
        guess = self._affine_guess if geometry is self.mesh else vertex_affine_guess(geometry)
        with wp.ScopedDevice(self.device):
            m, geo_degree = mesh_args(prec, geometry, self.faces, self._bvh.id, self._neighbour, self._face_maps,
                                      guess, self._box_lo, self._box_hi)
            gk, gk_s = gauss_kronrod(prec)
            # affine-only meshes get search, traverse and sample kernels without the curved machinery
            table = kernel_table(self.kernel_variant, name)
            stride = sample_stride(geometry, geo_degree)
        self._uploads[name] = Upload(prec, m, gk, gk_s, table, sample_stride=stride)
        return self._uploads[name]

    def _kernels(self, upload: Upload, isosurfaces: bool):
        """The upload's KernelTable, integrate and shade in their variant for isosurfaces and
        planes where the look has them."""
        if not isosurfaces:
            return upload.kernels
        return kernel_table(self.kernel_variant, upload.precision.name, isosurfaces=True)

    def _surface_args(self, upload: Upload, fr: field_frame.FieldFrame, surfaces: Surfaces | None,
                      options: RenderOptions):
        """The kernels' SurfaceArgs of `surfaces` with the field in frame `fr` (none: the default
        struct, which changes nothing); the reference gradient is uploaded once per frame."""
        prec = upload.precision
        if not surfaces:
            return prec.kernels.SurfaceArgs()
        if not samples_segments(options.method):
            raise RenderError(f"isosurfaces and planes are found on the segments' series: method "
                              f"{' or '.join(SAMPLING_METHODS)}, not {options.method}")
        colour = surfaces.color_ramp(self.mesh.derived.spec if self.mesh.derived is not None else None)
        surfaces.check(self.sampled_ranges, self._box_lo.min(axis=0), self._box_hi.max(axis=0))
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
            return surface_args(prec, arrays, colour, upload.gradient[1], self.mesh.coeffs.shape[0])

    @property
    def sampled_ranges(self) -> list[tuple[float, float]]:
        """The field's range over the data per volume (looks.sampled_ranges), which isosurface levels
        are checked against (the certified data_ranges are wider: coefficient bounds)."""
        if self._sampled_ranges is None:
            self._sampled_ranges = sampled_ranges(self.mesh)
        return self._sampled_ranges

    def surface_misses(self, camera: RayCamera, surfaces: Surfaces) -> list[str]:
        """Words for each isosurface no ray of `camera` meets (Surfaces.unseen)."""
        return surfaces.unseen(camera, self._box_lo, self._box_hi, self._field_lo, self._field_hi, self._volume)

    def identity_frame(self) -> field_frame.FieldFrame:
        return field_frame.FieldFrame(np.ones(self.volumes), np.zeros(self.volumes))

    def _set_field(self, upload: Upload, fr: field_frame.FieldFrame):
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
            check_float32_range("field coefficients", coeffs, mesh.coeff_offset)
        # the map of a certified range, widened by the map's rounding, then cast outward
        eps64 = float(np.finfo(np.float64).eps)
        lo, hi = a * self._field_lo + b, a * self._field_hi + b
        pad = 2 * eps64 * (a * np.maximum(np.abs(self._field_lo), np.abs(self._field_hi)) + np.abs(b))
        flo, fhi = outward(lo - pad, hi + pad, prec.dtype)
        # a sample is a sum of terms of this size: its rounding error, and the interpolant's
        # (Lebesgue constant of <= 48 Chebyshev-Lobatto points < 4) times a few ulps per term;
        # plus the map's own rounding of the coefficients (b on each of at most 8 vertex modes)
        rounding = prec.eps * element_coefficient_scale(mesh, coeffs) + eps64 * (a * self._coeff_scale + 8 * np.abs(b))
        with wp.ScopedDevice(self.device):
            m.coeffs = wp.array(coeffs.astype(prec.dtype), dtype=prec.scalar)
            if mesh.derived is not None:
                m.derived = derived_args(prec, mesh.derived, a, b)
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
        surface: engine/opaque.py; +inf where none); the depth output is then that t where the
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
            limit = surface_limit(prec, surface_t, W, H)
            transfer = transfer_args(prec, tf_frame)
            transfer.surf = self._surface_args(upload, fr, surfaces, options)
            quad = quad_args(prec, options, background, upload, self.data_diagonal)
            tile = self._launch_tile(prec, end - first, progress, tile_pixels)
            threads = 1 if profile or ray_counts else self._threads_for(end - first)
            if threads > 1:  # each thread its own tile buffers, within the one tile's memory
                limit_rays = self._tile_limit(prec)
                threads = min(threads, max(1, limit_rays // MIN_THREAD_RAYS))
                balanced = max(MIN_THREAD_RAYS, -(-(end - first) // (TILES_PER_THREAD * threads)))
                tile = min(tile, balanced, limit_rays // threads)
                threads = min(threads, -(-(end - first) // tile))
            self.check_limits(W, H, options, tile * threads)
            try:
                rgba = wp.zeros(total, dtype=prec.vec4)
                aux = wp.zeros(total, dtype=prec.vec2)
                stats = wp.zeros((total, kernels.NUM_STATS), dtype=wp.int32)
                buffers = tile_buffers(prec, tile, stats)
                spare = [tile_buffers(prec, tile, stats) for _ in range(threads - 1)]  # the other threads'
            except RuntimeError as exc:  # allocation failure on the device
                raise RenderError(f"cannot allocate a {W}x{H} image on {self.device}: {exc}") from exc
            load_kernels(self.kernel_variant, self.device, options.precision,  # compiled outside the timed region
                         isosurfaces=bool(surfaces))
            wp.synchronize_device(self.device)
            table = self._kernels(upload, bool(surfaces))
            launch = Launcher(self.device, profile, table)
            t0 = time.perf_counter()
            cancelled = False
            rounds = 0
            lanes = LaneCounts(kernels) if ray_counts else None
            own_step = chooses_own_step(options.method, options.h)

            def tile_at(start, bufs):
                n = min(tile, end - start)
                r = self._trace_tile(launch, upload, cam, transfer, quad, bufs, start, n, limit, lanes=lanes,
                                     own_step=own_step)
                launch(table.finalize, n, [quad, start, bufs.rays, rgba, aux])
                return r, n

            if threads > 1:
                rounds, cancelled = self._threaded_tiles(tile_at, range(first, end, tile), [buffers, *spare], progress,
                                                         end - first)
            else:
                for start in range(first, end, tile):
                    r, n = tile_at(start, buffers)
                    rounds += r
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
                "parameters": options.as_dict(), **counter_stats(kernels, counts, end - first), "rounds": rounds,
                **({"rows": [row0, row1]} if rows is not None else {}),
                **({"kernel_seconds": launch.seconds} if profile else {}),
                **({"lane_occupancy": lanes.occupancy()} if lanes is not None else {}),
                "elements": self.mesh.num_elements, "precision": options.precision, "warnings": warnings}
        return RenderResult(depth=depth_err[..., 0], error=depth_err[..., 1], cancelled=cancelled, rgba=img,
                            stats=info, row_cost=row_cost, ray_counts=per_ray)

    def _threads_for(self, rays: int) -> int:
        """Threads a render of `rays` rays runs its tiles on: cpu_threads on the CPU, as many as
        have MIN_THREAD_RAYS rays each; 1 on a GPU."""
        if wp.get_device(self.device).is_cuda:
            return 1
        return max(1, min(int(self.cpu_threads), rays // MIN_THREAD_RAYS))

    @staticmethod
    def _threaded_tiles(tile_at, starts, buffer_sets: list, progress, rays: int) -> tuple[int, bool]:
        """tile_at(start, buffers) for every tile start over a thread a set of launch buffers
        (threads.in_threads; a tile takes a free set and gives it back); every ray writes only its
        own pixel, so the image is the one thread's bit for bit. progress(fraction) as tiles
        finish; False stops those not started. Returns (rounds, cancelled)."""
        free = queue.SimpleQueue()
        for b in buffer_sets:
            free.put(b)

        def run(start):
            b = free.get()
            try:
                return tile_at(start, b)
            finally:
                free.put(b)

        done = [0]

        def finished(result):
            done[0] += result[1]
            return None if progress is None else progress(done[0] / rays)

        results, cancelled = in_threads(run, starts, len(buffer_sets), finished, name="hovr-tile")
        return sum(r[0] for r in results if r is not None), cancelled

    def _trace_tile(self, launch: Launcher, upload: Upload, cam, transfer, quad, buffers: TileBuffers, start: int,
                    n: int, limit: tuple, record=None, lanes: LaneCounts | None = None, own_step: bool = False) -> int:
        """Rays start .. start + n of the image, in rounds until none is left: search, traverse,
        sample, integrate (or record(active rays): a trace keeps the segments instead), the next
        round's rays regrouped (_regroup). With `lanes`, the lanes of each search and traverse
        launch that have work are counted; `own_step` (methods.chooses_own_step): step_terms
        before integrate. Returns the rounds."""
        rays, segs, table = buffers.rays, buffers.segs, launch.table
        launch(table.init_rays, n, [cam, start, rays, *limit])
        active = n  # rounds run over the rays still going (rays.active, compacted by integrate)
        rounds = 0
        while active > 0:
            rays.active_count.zero_()
            segs.list_count.zero_()
            if lanes is not None:
                lanes.count("search", rays, active, start)
            launch(table.search, active, [upload.mesh_args, cam, start, rays])
            if self.regroup and active > WARP_SIZE:  # the rays that walk on by element, those done last
                self._regroup(launch, buffers, active)
            if lanes is not None:
                lanes.count("traverse", rays, active, start)
            launch(table.traverse, active, [upload.mesh_args, cam, transfer, quad, start, rays, segs])
            if lanes is not None:
                lanes.walked(rays)
            listed = self._sample_segments(launch, upload, cam, start, buffers)
            if record is None:
                if listed and own_step:
                    launch(table.step_terms, listed,
                           [upload.mesh_args, transfer, quad, segs, segs.list])
                launch(table.integrate, active,
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

    def _regroup(self, launch: Launcher, buffers: TileBuffers, active: int):
        """The list of rays (rays.active) sorted by kernels.regroup_keys: the rays that search first,
        then by the element each walks into, then those whose walk is over, each group in pixel
        order, so the lanes of a warp search together or walk the same element (the atomic
        compaction that builds each round's list leaves the rays in any order on a GPU). Run before
        each round's search and before its traverse. Each ray's work is its own: no image or count
        changes."""
        rays, table = buffers.rays, launch.table
        launch(table.regroup_keys, active, [rays, buffers.sort_keys, buffers.sort_values])
        wp.utils.radix_sort_pairs(buffers.sort_keys, buffers.sort_values, active)
        wp.copy(rays.active, buffers.sort_values, count=active)

    def _sample_segments(self, launch: Launcher, upload: Upload, cam, start: int, buffers: TileBuffers) -> int:
        """The samples of the segments traverse listed, then their Chebyshev coefficients; curved
        interpolants whose tail is too large get their degree doubled (twice at most). Returns how
        many segments were listed."""
        rays, segs, again, again_count = buffers.rays, buffers.segs, buffers.again, buffers.again_count
        table = launch.table
        listed = int(segs.list_count.numpy()[0])
        if listed == 0:
            return 0
        stride = upload.sample_stride
        odd_stride = (MAX_SAMPLES - 5) // 2 + 1  # the odd points of a doubled degree, at most
        launch(table.sample, listed * stride,
               [upload.mesh_args, cam, start, segs, segs.list, stride, 0, rays.stats])
        if self._interpolants:
            slots, count, n_slots = segs.list, segs.list_count, listed
            for p in range(2):
                again_count[p].zero_()
                launch(table.refine, n_slots, [start, rays, segs, slots, count, again[p], again_count[p], 1])
                n_slots = int(again_count[p].numpy()[0])
                if n_slots == 0:
                    break
                launch(table.sample, n_slots * odd_stride,
                       [upload.mesh_args, cam, start, segs, again[p], odd_stride, 1, rays.stats])
                slots, count = again[p], again_count[p]
            if n_slots > 0:  # the last refined slots: their tails, no more doubling
                launch(table.refine, n_slots, [start, rays, segs, slots, count, again[0], again_count[0], 0])
        launch(table.coefficients, listed * stride, [segs, segs.list, stride])
        return listed
