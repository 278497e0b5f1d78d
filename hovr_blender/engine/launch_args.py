"""What the ray kernels are launched with: the structs of kernels/args.py filled from the mesh, the
camera, the transfer function, the quadrature settings and the look's isosurfaces and planes
(mesh_args, camera_args, transfer_args, quad_args, surface_args, derived_args), a launch tile's
buffers (tile_buffers), one precision's upload (Upload), and the Launcher that launches a kernel
handle (timed with `profile`). The arrays go to the current Warp device (the caller's
wp.ScopedDevice)."""
from __future__ import annotations

import time
from dataclasses import dataclass

import numpy as np
import warp as wp

from . import limits, shapes
from .camera import RayCamera
from .kernels import quadrature_tables
from .kernels.args import MAX_SAMPLES
from .kernels.precision import Precision
from .mesh import VolumeMesh
from .methods import METHOD_IDS
from .render_result import RenderError, check_float32_range
from .tensor_geometry import mesh_tensor_geometry
from .transfer_function import TransferFunction
from .view import AUTO_STEP_ERROR, RenderOptions

INNER_IDS = {"spectral": 0, "trapezoid": 1}
EVAL_ERROR_FACTOR = 64.0  # mesh field_err: eps * sum |c_m| max|phi_m| times this (Renderer._set_field)
GEO_ERROR_FACTOR = 64.0  # the same for the geometry's x(xi) (geometry_rounding)


@dataclass
class Upload:
    """One precision's mesh on the device and the kernels specialised for it (Renderer._upload)."""

    precision: Precision
    mesh_args: object  # kernels.MeshArgs
    gk: list  # Gauss-Kronrod nodes, Kronrod and Gauss weights
    gk_s: object  # the spectral integration matrix on the nodes
    kernels: object  # the KernelTable, the walk's kernels specialised for the mesh (kernel_loading.kernel_table)
    sample_stride: int = 1  # threads per slot in the sample kernel (sample_stride of the geometry uploaded)
    field_key: tuple | None = None  # the FieldFrame.key of the field on the device (Renderer._set_field)
    field: tuple | None = None  # its (lo, hi, rounding) per element, in frame units
    gradient: tuple | None = None  # (field_key, the reference gradient on the device in that frame)


@dataclass
class TileBuffers:
    """A launch tile's per-ray state and round buffers (tile_buffers)."""

    rays: object  # kernels.RayState
    segs: object  # kernels.Segments
    again: list  # per refine pass: the slots whose degree it doubled (their odd points to sample)
    again_count: list
    sort_keys: object  # the next round's list and its keys while they are sorted (Renderer._regroup)
    sort_values: object
    nbytes: int


class Launcher:
    """wp.launch of a kernel handle (a KernelTable's field: the call site names the kernel); with
    `profile`, each launch is waited for and timed under its field name (stats["kernel_seconds"])."""

    def __init__(self, device: str, profile: bool, table):
        self.device = device
        self.profile = profile
        self.table = table  # the kernels launched (KernelTable)
        named = table.named()
        self.names = {id(k): name for name, k in named.items()}
        self.seconds = {name: 0.0 for name in named}

    def __call__(self, kernel, dim: int, inputs: list):
        t_launch = time.perf_counter()
        wp.launch(kernel, dim=dim, inputs=inputs)
        if self.profile:
            wp.synchronize_device(self.device)
            self.seconds[self.names[id(kernel)]] += time.perf_counter() - t_launch


def outward(lo, hi, dtype):
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


def mesh_args(prec: Precision, mesh: VolumeMesh, faces, bvh_id, neighbour, face_maps, affine_guess, box_lo,
              box_hi) -> tuple:
    """(MeshArgs, geometry degree per element): the mesh on the current device in `prec`, its
    field to be set in a frame (Renderer._set_field); `faces` (engine/faces.py) with the BVH of
    their boxes `bvh_id`, the face neighbours and the maps of their shared faces' points
    (adjacency.face_maps), the straight-sided guess of each element's map and the elements'
    padded boxes."""
    fdt, v3, m33, scalar = prec.dtype, prec.vec3, prec.mat33, prec.scalar
    m = prec.kernels.MeshArgs()
    m.bvh = bvh_id
    m.face_points = wp.array(faces.points.astype(fdt), dtype=v3)
    m.face_xi = wp.array(faces.xi.astype(fdt), dtype=v3)
    m.face_tris = wp.array(faces.triangles.astype(np.int32), dtype=wp.vec3i)
    m.face_owner = wp.array(faces.owner.astype(np.int32), dtype=wp.int32)
    m.face_bound = float(faces.bound)
    m.has_affine = int(mesh.affine is None or bool(mesh.affine.any()))
    m.shape = wp.array(mesh.shape.astype(np.int32), dtype=wp.int32)
    # affine elements: the exact map; curved ones: Newton's straight-sided start
    m.ref_a = wp.array(affine_guess[:, :, :3].astype(fdt), dtype=m33)
    m.ref_b = wp.array(affine_guess[:, :, 3].astype(fdt), dtype=v3)
    m.neighbour = neighbour
    m.face_map_a = wp.array(face_maps[:, :, :3].astype(fdt), dtype=m33)
    m.face_map_b = wp.array(face_maps[:, :, 3].astype(fdt), dtype=v3)
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
    m.box_lo = wp.array(box_lo.astype(fdt), dtype=v3)
    m.box_hi = wp.array(box_hi.astype(fdt), dtype=v3)
    return m, gdeg


def gauss_kronrod(prec: Precision) -> tuple:
    """([nodes, Kronrod weights, Gauss weights], the spectral integration matrix on the nodes) on
    the current device in `prec` (QuadArgs' gk_*)."""
    x, wk, wg = quadrature_tables.gauss_kronrod_15()
    S = quadrature_tables.integration_matrix(x)
    return [wp.array(a.astype(prec.dtype), dtype=prec.scalar) for a in (x, wk, wg)], \
        wp.array(S.astype(prec.dtype), dtype=prec.scalar)


def surface_args(prec: Precision, arrays: dict, colour: dict, grad, grad_stride: int):
    """The kernels' SurfaceArgs on the current device: isosurfaces.Surfaces' device_arrays and
    color_ramp, the field's reference gradient on the device and its stride (coefficients)."""
    surf = prec.kernels.SurfaceArgs()
    surf.n_iso = len(arrays["iso_s"])
    surf.n_planes = len(arrays["plane"])
    surf.iso_s = wp.array(arrays["iso_s"].astype(prec.dtype), dtype=prec.scalar)
    surf.iso_rgba = wp.array(arrays["iso_rgba"].astype(prec.dtype), dtype=prec.vec4)
    surf.plane = wp.array(arrays["plane"].astype(prec.dtype), dtype=prec.vec4)
    surf.plane_style = wp.array(arrays["plane_style"].astype(prec.dtype), dtype=prec.vec4)
    surf.keep = wp.array(arrays["keep"], dtype=wp.int32)
    surf.iso_color_by = wp.array(np.array([-1 if by is None else prec.kernels.OPERATION_IDS[by]
                                           for by in colour["by"]], np.int32), dtype=wp.int32)
    surf.ramp_s = wp.array(colour["s"].astype(prec.dtype), dtype=prec.scalar)
    surf.ramp_rgb = wp.array(colour["rgb"].astype(prec.dtype), dtype=prec.vec3)
    surf.grad_stride = int(grad_stride)
    surf.grad = grad
    return surf


def tile_buffers(prec: Precision, tile: int, stats) -> TileBuffers:
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
    return TileBuffers(rays, segs, again, again_count, sort_keys, sort_values, sum(a.capacity for a in allocated))


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


def surface_limit(prec: Precision, surface_t, width: int, height: int) -> tuple:
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


def derived_args(prec: Precision, field, scale, shift):
    """The kernels' DerivedArgs of a mesh's DerivedField (engine/derived_fields.py), its
    samples mapped into the frame f' = scale f + shift (per element)."""
    dk = prec.kernels  # the derived fields' operation ids (kernels/derived.py, through raycast)
    kind = dk.OPERATION_IDS[field.spec.operation] + (dk.PER_DENSITY if field.components == 4 else 0)
    if field.coeffs.size >= 2**31:
        raise RenderError("derived field too large for 32-bit coefficient offsets")
    if prec.name == "float32":
        check_float32_range("derived field components", field.coeffs, field.offset)
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


def transfer_args(prec: Precision, tf: TransferFunction):
    transfer = prec.kernels.TransferArgs()
    transfer.color_s = wp.array(tf.color_s.astype(prec.dtype), dtype=prec.scalar)
    transfer.color_rgb = wp.array(tf.color_rgb.astype(prec.dtype), dtype=prec.vec3)
    transfer.density_s = wp.array(tf.density_s.astype(prec.dtype), dtype=prec.scalar)
    transfer.density_tau = wp.array(tf.density_tau.astype(prec.dtype), dtype=prec.scalar)
    return transfer


def quad_args(prec: Precision, options: RenderOptions, background, upload: Upload, diagonal: float):
    quad = prec.kernels.QuadArgs()
    quad.method = METHOD_IDS[options.method]
    quad.inner = INNER_IDS[options.inner]
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
