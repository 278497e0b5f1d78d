"""What every ray kernel shares (kernels/raycast.py: the rounds): the pixel's ray, the start of a
tile's rays (init_rays), the keys that regroup the rays between rounds (regroup_keys), an affine
element's exact clip, and the register caps and unrolling the walk's kernels compile with."""
from __future__ import annotations

import warp as wp

from . import element
from .args import NO_SURFACE_END, CameraArgs, MeshArgs, RayState
from .tolerances import CLIP_TOL, UNIT_ROUNDOFF

wp.set_module_options({"enable_backward": False})

# Register caps (CUDA __maxnreg__; ignored on the CPU). Uncapped, search, traverse and integrate
# take 255 registers and run few threads per SM; at 128 the spills are cheaper than the lost
# occupancy: H100, paper-scale curved 1920x1080 split-1e-3, 767 -> 636 ms (search 248 -> 200,
# traverse 159 -> 120, integrate 190 -> 139); 96 measured the same, 168 no better.
# The curved sample kernel (one point per thread) is held to 64 (160 -> 154 ms).
MAX_REGISTERS = 128
SAMPLE_MAX_REGISTERS = 64


@wp.func
def camera_ray(cam: CameraArgs, pixel: int):
    """Origin and unit direction of the pixel's ray (contract §4)."""
    px = pixel % cam.width
    py = pixel // cam.width
    fw = float(cam.width)
    fh = float(cam.height)
    u = (2.0 * (float(px) + 0.5) / fw - 1.0) * (fw / fh)
    v = 1.0 - 2.0 * (float(py) + 0.5) / fh
    return cam.o0 + u * cam.ou + v * cam.ov, wp.normalize(cam.d0 + u * cam.du + v * cam.dv)


@wp.func
def camera_span(cam: CameraArgs, d: wp.vec3) -> wp.vec2:
    """(t_lo, t_hi) of the unit ray d: the camera's t range within its clip planes."""
    t_lo = cam.t_min
    t_hi = cam.t_max
    cax = wp.dot(d, cam.clip_axis)
    if cax > 0.0:
        t_lo = wp.max(t_lo, cam.clip_near / cax)
        t_hi = wp.min(t_hi, cam.clip_far / cax)
    return wp.vec2(t_lo, t_hi)


@wp.kernel
def init_rays(cam: CameraArgs, pixel_offset: wp.int32, rays: RayState, t_limit: wp.array(dtype=wp.float32),
              use_limit: wp.int32):
    """Each ray's span [t_lo, t_hi]: the camera's t range and clip planes and, with use_limit,
    the pixel's own far limit t_limit[pixel] (the first opaque surface's t along the same unit
    ray, +inf where none: engine/surfaces.py); without it t_limit is a one-element dummy."""
    i = wp.tid()
    o, d = camera_ray(cam, i + pixel_offset)
    span = camera_span(cam, d)
    t_lo = span[0]
    t_hi = span[1]
    if use_limit != 0:
        t_hi = wp.min(t_hi, t_limit[i + pixel_offset])
    rays.color_t[i] = wp.vec4(0.0, 0.0, 0.0, 1.0)
    rays.depth_err[i] = wp.vec2(-1.0, 0.0)
    rays.surface_end[i] = wp.vec2(NO_SURFACE_END, 0.0)
    rays.t_cur[i] = t_lo
    rays.t_end[i] = t_hi
    rays.t_search[i] = -1.0e30
    rays.next_element[i] = -1
    rays.left_element[i] = -1
    rays.entry_r[i] = wp.vec4(0.0, 0.0, 0.0, -1.0)
    rays.phase[i] = 0
    if t_hi <= t_lo:
        rays.phase[i] = 2
    rays.active[i] = i


@wp.func
def affine_stretch(mesh: MeshArgs, e: int, o: wp.vec3, d: wp.vec3) -> wp.vec4:
    """(hit, t0, t1, exit face) of the ray in affine element e: the clip in reference space."""
    A = mesh.ref_a[e]
    return element.reference_clip(mesh.shape[e], A * o + mesh.ref_b[e], A * d)


# unit roundoffs in an affine clip's end: A o + b and A d (a few each), the plane's dot products,
# the quotient, and A and b's own rounding to the precision
CLIP_ROUNDING = 8.0


@wp.func
def affine_clip_rounding(mesh: MeshArgs, e: int, o: wp.vec3, d: wp.vec3, t: float, side: float) -> float:
    """How far rounding may move affine element e's clip end at t along the ray: for the face the
    clip ends on (side -1: the entry, among the faces the ray enters by; 1: the exit), the rounding
    of n . (A o + b) and of the rate n . A d (CLIP_ROUNDING unit roundoffs of their terms'
    magnitudes) over that rate. It grows as the ray grazes the face, where the two elements that
    share it see the crossing far apart."""
    sh = mesh.shape[e]
    A = mesh.ref_a[e]
    b = mesh.ref_b[e]
    xo = A * o + b
    xd = A * d
    size = wp.vec3(0.0, 0.0, 0.0)  # |A| (|o| + |t| |d|) + |b|, by component
    for j in range(3):
        s = wp.abs(b[j])
        for k in range(3):
            s += wp.abs(A[j, k]) * (wp.abs(o[k]) + wp.abs(t) * wp.abs(d[k]))
        size[j] = s
    best = side * 1.0e30  # the clip's end: the least exit, the greatest entry
    out = float(0.0)
    for f in range(element.num_faces(sh)):
        pl = element.face_plane(sh, f)
        n = wp.vec3(pl[0], pl[1], pl[2])
        den = wp.dot(n, xd)
        if den * side > 0.0:
            tf = (pl[3] + CLIP_TOL - wp.dot(n, xo)) / den
            if side * (best - tf) > 0.0:
                best = tf
                mag = wp.abs(n[0]) * size[0] + wp.abs(n[1]) * size[1] + wp.abs(n[2]) * size[2]
                out = CLIP_ROUNDING * UNIT_ROUNDOFF * mag / wp.abs(den)
    return out


def walk_options(CURVED: bool) -> dict:
    # The curved kernels inline Newton solves at several call sites: unrolling their fixed
    # loops costs NVRTC time, not speed (bench/results/h100/compile_unroll.json).
    return {"max_unroll": 4} if CURVED else {}


@wp.kernel(enable_backward=False)
def regroup_keys(rays: RayState, keys: wp.array(dtype=wp.int64), values: wp.array(dtype=wp.int32)):
    """Sort keys for the list of rays (rays.active), one thread per ray on it: the rays that search
    first (next element -1), then the rays of each element they walk into, then the rays whose
    walk is over (phase not 0), each group in pixel order; sorted by them a warp's lanes take one
    path (Renderer._regroup)."""
    k = wp.tid()
    i = rays.active[k]
    group = rays.next_element[i] + 1
    if rays.phase[i] != 0:
        group = 2147483646
    keys[k] = wp.int64(group) * wp.int64(2147483647) + wp.int64(i)  # i < 2^31 - 1
    values[k] = i
