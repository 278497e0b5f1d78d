"""What the ray kernels read and write: the mesh, the camera, the transfer function, the
quadrature settings, the per-round segment buffer and the per-ray state (one module, so the
float64 twin of every kernel module sees the same struct types; kernels/precision.py).

A render is a loop of rounds over a tile of rays (kernels/raycast.py): the search kernel finds
where rays that need it enter the mesh (kernels/entry.py), the traverse kernel walks each ray
through the mesh and writes up to SEGMENTS_PER_ROUND element segments, the sample kernel fills in
the field's samples along them (kernels/walk.py), and the integrate kernel turns them into colour
and transmittance (kernels/integrate.py).
Per-ray state carries everything from one round to the next. A trace (Renderer.trace) keeps
every segment of every ray in a SegmentCache instead of integrating them, and the shade
kernel integrates them later through any transfer function.
"""
from __future__ import annotations

import warp as wp

from ..shapes import MAX_MODES

wp.set_module_options({"enable_backward": False})

# Samples of the field along one segment: the exact restriction of an affine element has
# degree <= 3 (MAX_MODES - 1) + 2 (pyramids); the last two slots hold the pyramid weights.
MAX_SAMPLES = 48
assert 3 * (MAX_MODES - 1) + 2 + 1 + 2 <= MAX_SAMPLES, "MAX_SAMPLES does not hold shapes.MAX_MODES"
SEGMENTS_PER_ROUND = 8
NO_SURFACE_END = -1.0e30  # RayState.surface_end's t before a ray's first segment

# per-ray counters (stats)
STAT_FIELD_EVALS = 0  # full element field evaluations
STAT_RESTRICTION_EVALS = 1  # O(D) evaluations of the 1-D restriction along a segment
STAT_SEGMENTS = 2  # element segments met
STAT_EMPTY = 3  # segments skipped as empty (classified/split)
STAT_SMOOTH = 4  # segments integrated as smooth
STAT_PIECEWISE = 5  # segments integrated as piecewise-smooth
STAT_LOCATES = 6  # face crossings polished (and curved elements located) by the entry search
STAT_WALKS = 7  # element entries through a shared face (no search)
# the work counts (tests/perf): deterministic on the CPU, what a change of the traversal costs
STAT_BVH_CANDIDATES = 8  # triangles the search's BVH queries returned (Warp exposes no node count)
# Newton iterations (each a map evaluation with its Jacobian) in the search, the walk and the samples
STAT_NEWTON_SEARCH = 9
STAT_NEWTON_WALK = 10
STAT_NEWTON_SAMPLE = 11
STAT_ROUNDS = 12  # rounds the ray took part in (traverse launches it was active in)
NUM_STATS = 13

# segment flags
SEG_CURVED = 1  # samples of a Chebyshev interpolant (not exact): classify by the element's range
SEG_EVALUATE = 2  # no samples: riemann/trapezoid evaluate the element itself (affine baselines)
SEG_INTERPOLANT = 4  # samples of a derived field (kernels/derived.py): an interpolant, as curved


@wp.struct
class DerivedArgs:
    """A derived field's components (kernels/derived.py; engine/derived_fields.py). active 0: the
    mesh's field is its own expansion (a default struct changes nothing)."""

    active: wp.int32
    kind: wp.array(dtype=wp.int32)  # per element: derived.GRADIENT ... (+ PER_DENSITY), FIELD
    # per element: component c's value expansion at offset + 4 c size, its reference derivatives
    # d/dxi_k at offset + (4 c + 1 + k) size, each of `size` coefficients in `modes`
    offset: wp.array(dtype=wp.int32)
    size: wp.array(dtype=wp.int32)
    modes: wp.array(dtype=wp.vec3i)
    coeffs: wp.array(dtype=wp.float32)
    axes: wp.array(dtype=wp.mat33)  # per element: dx/dx_data, the object transform's linear part
    frame: wp.array(dtype=wp.vec2)  # per element: (a, b) of the field's frame f' = a f + b


@wp.struct
class MeshArgs:
    # the BVH over the boxes of every element face's triangles grown by face_bound, grouped by
    # element (kernels/crossing.py; engine/faces.py)
    bvh: wp.uint64
    face_points: wp.array(dtype=wp.vec3)  # triangle vertices, world
    face_xi: wp.array(dtype=wp.vec3)  # ... the same in their element's reference coordinates
    face_tris: wp.array(dtype=wp.vec3i)  # per triangle its vertices, wound outward from its element
    face_owner: wp.array(dtype=wp.int32)  # per triangle: element * MAX_FACES + local face
    face_bound: wp.float32  # every triangle lies within this (world units) of its curved face
    has_affine: wp.int32  # 1: some element is affine (the search offers their exact clips)
    shape: wp.array(dtype=wp.int32)  # element.HEX / PRISM / TET / PYR
    ref_a: wp.array(dtype=wp.mat33)  # xi = ref_a x + ref_b (affine elements)
    ref_b: wp.array(dtype=wp.vec3)
    modes: wp.array(dtype=wp.vec3i)
    basis: wp.array(dtype=wp.int32)
    coeff_offset: wp.array(dtype=wp.int32)
    coeffs: wp.array(dtype=wp.float32)
    field_lo: wp.array(dtype=wp.float32)  # certified range of each element's field
    field_hi: wp.array(dtype=wp.float32)
    # how far an evaluation of the element's field can be off by rounding (a segment's bound
    # from its samples is widened by this): EVAL_ERROR_FACTOR eps sum |c_m| max |phi_m|
    field_err: wp.array(dtype=wp.float32)
    # element e's neighbour across its reference face f (element.face_plane order): e * MAX_FACES + f;
    # -1 on the boundary or where no element shares the face exactly
    neighbour: wp.array(dtype=wp.int32)
    # ... and where it has one, a point of that face in e's reference coordinates in the
    # neighbour's: face_map_a xi + face_map_b (engine/adjacency.face_maps)
    face_map_a: wp.array(dtype=wp.mat33)
    face_map_b: wp.array(dtype=wp.vec3)
    # curved / non-affine elements: (x - centre) w^2 as tensor Legendre coefficients of
    # degree geo_degree per direction (engine/tensor_geometry.py), and boxes
    affine: wp.array(dtype=wp.int32)
    geo_degree: wp.array(dtype=wp.int32)
    geo_offset: wp.array(dtype=wp.int32)
    geo_coeffs: wp.array(dtype=wp.vec3)
    geo_centre: wp.array(dtype=wp.vec3)
    # how far an evaluation of x(xi) can be off by rounding (before the pyramid's 1 / w^2):
    # GEO_ERROR_FACTOR eps (sum |coefficients| + |centre|); Newton stops at steps this makes
    geo_err: wp.array(dtype=wp.float32)
    box_lo: wp.array(dtype=wp.vec3)
    box_hi: wp.array(dtype=wp.vec3)
    derived: DerivedArgs  # a derived field's components (none: active 0)


@wp.struct
class CameraArgs:
    o0: wp.vec3
    ou: wp.vec3
    ov: wp.vec3
    d0: wp.vec3
    du: wp.vec3
    dv: wp.vec3
    width: wp.int32
    height: wp.int32
    t_min: wp.float32
    t_max: wp.float32
    # Blender's clip planes measured along the view axis (zero axis: unused): per ray,
    # t in [clip_near / c, clip_far / c] with c = dot(d, clip_axis)
    clip_axis: wp.vec3
    clip_near: wp.float32
    clip_far: wp.float32


@wp.struct
class SurfaceArgs:
    """The look's surfaces (render contract §7; kernels/isosurface.py): isosurfaces, cut planes
    and the clipping they do. A default struct (no isosurface, no plane) changes nothing."""

    n_iso: wp.int32
    iso_s: wp.array(dtype=wp.float32)  # the levels, in the field's frame (engine/field_frame.py)
    iso_rgba: wp.array(dtype=wp.vec4)  # each level's linear colour and opacity
    n_planes: wp.int32
    plane: wp.array(dtype=wp.vec4)  # (n, c): the plane n . x = c, |n| = 1, world units
    # (opacity, clip, 0, 0): clip +1 removes the volume where n . x > c, -1 where n . x < c, 0 none
    plane_style: wp.array(dtype=wp.vec4)
    # per element: 1 where a level lies in its certified range or a plane crosses its box, so
    # the walk samples it even where the density is 0 (walk.element_transparent)
    keep: wp.array(dtype=wp.int32)
    # the reference gradient of the field, component k of element e's expansion at
    # k * grad_stride + MeshArgs.coeff_offset[e] (engine/isosurfaces.reference_gradient); 0: none
    grad_stride: wp.int32
    grad: wp.array(dtype=wp.float32)
    # per level: -1, or the derived field (kernels/derived.py: SPEED, ...) of the mesh's velocity
    # that colours it through the ramp (ramp_s in that field's own units, ramp_rgb)
    iso_color_by: wp.array(dtype=wp.int32)
    ramp_s: wp.array(dtype=wp.float32)
    ramp_rgb: wp.array(dtype=wp.vec3)


@wp.struct
class TransferArgs:
    color_s: wp.array(dtype=wp.float32)
    color_rgb: wp.array(dtype=wp.vec3)
    density_s: wp.array(dtype=wp.float32)
    density_tau: wp.array(dtype=wp.float32)
    surf: SurfaceArgs  # isosurfaces and planes: part of the look, as the transfer function is


@wp.struct
class QuadArgs:
    method: wp.int32
    inner: wp.int32
    h: wp.float32  # the fixed step; 0: classified chooses each piecewise-smooth segment's (quadrature.auto_steps)
    max_steps: wp.int32  # steps of h per segment at most (the samples-per-ray limit; the host refuses more)
    h_min: wp.float32  # auto_steps' smallest step: the data's box diagonal / the samples-per-ray limit
    step_error: wp.float32  # auto_steps' error bound per piecewise-smooth segment
    tol: wp.float32
    min_transmittance: wp.float32
    background: wp.vec3
    gk_x: wp.array(dtype=wp.float32)  # 15 Kronrod nodes on [-1, 1], ascending
    gk_wk: wp.array(dtype=wp.float32)
    gk_wg: wp.array(dtype=wp.float32)  # zero at non-Gauss nodes
    gk_s: wp.array2d(dtype=wp.float32)  # spectral integration matrix on the nodes


@wp.struct
class Segments:
    """Up to SEGMENTS_PER_ROUND segments per ray of the tile, slot = ray * SEGMENTS_PER_ROUND + k.
    The traverse kernel fills a slot's record and lists the slots that need samples; the
    sample kernel fills them, one thread per sample point; refine doubles a curved slot's
    degree where its tail is too large."""

    count: wp.array(dtype=wp.int32)  # per ray: slots filled this round
    element: wp.array(dtype=wp.int32)
    t0: wp.array(dtype=wp.float32)
    t1: wp.array(dtype=wp.float32)
    degree: wp.array(dtype=wp.int32)  # samples 0..degree at Chebyshev-Lobatto points of [t0, t1]
    flags: wp.array(dtype=wp.int32)  # SEG_CURVED, SEG_EVALUATE
    tail: wp.array(dtype=wp.float32)  # curved: the interpolant's error estimate
    # curved: the solutions (xi) and reference velocities (dxi/dt) at both ends, for the
    # sample points' Newton starts (cubic Hermite between the ends)
    xi0: wp.array(dtype=wp.vec3)
    v0: wp.array(dtype=wp.vec3)
    xi1: wp.array(dtype=wp.vec3)
    v1: wp.array(dtype=wp.vec3)
    # slot * MAX_SAMPLES + j: f(t_j) w(t_j)^2 at t_j = mid + half cos(pi j / degree) (w = 1 but
    # for pyramids); MAX_SAMPLES - 2 / - 1: w(t0), w(t1)
    samples: wp.array(dtype=wp.float32)
    # slot * MAX_SAMPLES + k: the Chebyshev coefficients c_0 .. c_degree of the samples, then the
    # same two weights (restriction.series_weights)
    coeffs: wp.array(dtype=wp.float32)
    # classified without a fixed step: the slot's quadrature.step_error_terms (the step_terms kernel)
    step_terms: wp.array(dtype=wp.vec3)
    # the slots that need samples this round: list[0..list_count)
    list: wp.array(dtype=wp.int32)
    list_count: wp.array(dtype=wp.int32)


@wp.struct
class RayState:
    """Per ray of the tile, carried across rounds."""

    color_t: wp.array(dtype=wp.vec4)  # C.rgb, T
    # depth: t where 1 - T first reaches 0.5 (-1 until then); error: summed a-posteriori estimates
    depth_err: wp.array(dtype=wp.vec2)
    # (t, f) where the last segment searched for isosurfaces ended (RayIntegral.surface_end; t
    # NO_SURFACE_END: none yet)
    surface_end: wp.array(dtype=wp.vec2)
    t_cur: wp.array(dtype=wp.float32)  # how far the traversal got
    t_end: wp.array(dtype=wp.float32)  # the ray's far end (camera t_max, clip far, an opaque surface)
    t_search: wp.array(dtype=wp.float32)  # where its last search started (kernels/entry.py: stalled walks)
    next_element: wp.array(dtype=wp.int32)  # the element the ray enters at t_cur (-1: search the BVH)
    left_element: wp.array(dtype=wp.int32)  # the element the ray has just left (-1: none)
    # the search's solution in a curved next_element at t_cur (entry_r[3] > 0: valid)
    entry_r: wp.array(dtype=wp.vec4)
    entry_dv: wp.array(dtype=wp.vec4)
    # 0 active, 1 traversal finished (integrate what is left), 2 done
    phase: wp.array(dtype=wp.int32)
    stats: wp.array2d(dtype=wp.int32)
    # the active rays of this round (tile-local indices) and the next round's, with its count
    active: wp.array(dtype=wp.int32)
    active_next: wp.array(dtype=wp.int32)
    active_count: wp.array(dtype=wp.int32)


@wp.struct
class SegmentCache:
    """Every element segment of every ray of a trace, with its Chebyshev series, for the shade
    kernel (engine/renderer.py Renderer.trace / shade). A round appends each ray's segments as one
    chunk (contiguous, in ray order); a ray's chunks are linked in the order of the rounds, so
    walking them gives its segments front to back. Segments, chunks and coefficients are
    reserved with atomic counters, so the arrays are in no particular order across rays."""

    head: wp.array(dtype=wp.int32)  # per ray: its first chunk (-1: no segment)
    t_end: wp.array(dtype=wp.float32)  # per ray: its far end (the depth output where 1 - T stays < 0.5)
    chunk_start: wp.array(dtype=wp.int32)  # per chunk: its first segment
    chunk_count: wp.array(dtype=wp.int32)  # ... how many
    chunk_next: wp.array(dtype=wp.int32)  # ... and the ray's next chunk (-1: the last)
    element: wp.array(dtype=wp.int32)  # per segment, as Segments holds them
    t0: wp.array(dtype=wp.float32)
    t1: wp.array(dtype=wp.float32)
    degree: wp.array(dtype=wp.int32)  # -1: no series (SEG_EVALUATE)
    flags: wp.array(dtype=wp.int32)
    tail: wp.array(dtype=wp.float32)
    coeff_offset: wp.array(dtype=wp.int32)  # where its series (degree + 3 values) starts in coeffs
    coeffs: wp.array(dtype=wp.float32)
    # segments, chunks and coefficients reserved so far (the trace's atomic counters)
    counts: wp.array(dtype=wp.int32)
