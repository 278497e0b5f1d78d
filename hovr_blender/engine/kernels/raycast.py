"""The ray kernels: render contract §3-4, one thread per pixel of a tile, in rounds.

A render of a tile (engine/renderer.py) runs init_rays once, then rounds of
1. search: rays that are not inside a known element find, in the BVH over element boxes,
   the element they enter next (search_entry);
2. traverse: each ray walks front to back through the mesh and writes up to
   SEGMENTS_PER_ROUND element segments with the field's samples along each, until it needs
   a search again;
3. integrate: each ray integrates its segments (kernels/quadrature.py) into colour,
   transmittance, depth and error, and puts itself on the next round's list if it is not done;
until no ray is left, then finalize writes the pixels. Rounds run over the list of rays
still going (no thread is spent on a finished ray). Three kernels instead of one keep each
small: the search (BVH, locating curved candidates), the walk (Newton, element evaluation)
and the quadrature never hold their registers at the same time, and each compiles quickly.

A trace (Renderer.trace) runs the same rounds with trace_reserve and trace_write in place of
integrate: every segment of every ray, with its series, goes into a SegmentCache, and the
shade kernel later integrates a ray's cached segments through any transfer function as
integrate would have, then writes its pixel.

Traversal walks through shared faces: where a ray leaves an element through a face it
shares with another (MeshArgs.neighbour), the next segment starts there, at the same t (no
gap, no double count), in that element: an affine element's exact clip, or a curved one's
Newton solution followed along the ray to its exit (geometry.curved_exit). Where there is
no neighbour (the domain's boundary, a gap, a non-conforming face, a ray through an edge),
the next round's search finds the next element beyond t: the smallest exact entry among
affine candidates, curved candidates located lazily in order of their box entry. Meshes of
affine elements get search and traverse kernels with the curved machinery compiled out.
"""
from __future__ import annotations

import warp as wp

from . import element
from . import geometry
from . import quadrature
from . import restriction
from .args import (MAX_SAMPLES, NUM_STATS, SEG_CURVED, SEG_EVALUATE, SEGMENTS_PER_ROUND, STAT_BVH_CANDIDATES,
                   STAT_EMPTY, STAT_FIELD_EVALS, STAT_LOCATES, STAT_NEWTON_SAMPLE, STAT_NEWTON_SEARCH, STAT_NEWTON_WALK,
                   STAT_PIECEWISE, STAT_RESTRICTION_EVALS,
                   STAT_ROUNDS, STAT_SEGMENTS, STAT_SMOOTH, STAT_WALKS, CameraArgs, MeshArgs, QuadArgs, RayState, SegmentCache, Segments,
                   TransferArgs)
from .quadrature import METHOD_CLASSIFIED, METHOD_RIEMANN, METHOD_SPLIT, RayIntegral

wp.set_module_options({"enable_backward": False})

__all__ = ["MeshArgs", "CameraArgs", "TransferArgs", "QuadArgs", "RayState", "Segments", "SegmentCache", "NUM_STATS",
           "MAX_SAMPLES", "SEGMENTS_PER_ROUND", "walk_kernels", "init_rays", "refine", "coefficients", "integrate",
           "finalize", "trace_reserve", "trace_write", "trace_ends", "shade", "sum_counts"]

WINDOW = 8  # curved candidates gathered per BVH pass of the entry search
LOCATED = 32  # curved candidates an entry search remembers having located
SEARCH_PASSES = 4
BACK_STEPS = 16  # elements walk_back may step back through before it keeps what it has
SHARED_FACE_TOL = 1.0e-3  # a point this close to a curved element's face (reference units) is on it
SHARED_FACE_TOL_FLOAT64 = 1.0e-8
# a stretch beyond t must reach past t + STRETCH_RTOL |t| to count (rounding of the exit just
# left); an affine neighbour's entry may lie STRETCH_RTOL (|t| + its chord) beyond the exit it is
# walked to. A curved element just left counts as entered again only where the ray comes
# INSIDE_TOL inside it (geometry.curved_entry's `again`)
STRETCH_RTOL = 1.0e-5
STRETCH_RTOL_FLOAT64 = 1.0e-11  # in the float64 twin (kernels/precision.py)
MAX_ZERO_STEPS = 3  # zero-length walks in a row (a ray through an edge) before searching instead
PYRAMID_W_RATIO = 2.0  # a pyramid's segment is cut where its weight w changes by more than this
PYRAMID_W_FLOOR = 1.0e-6  # ... down to this w (the last sliver at the apex stays whole)
STEPS_PER_ROUND = 64 * SEGMENTS_PER_ROUND  # walking steps a ray may take in one round (hang guard)

# Register caps (CUDA __maxnreg__; ignored on the CPU). Uncapped, search, traverse and integrate
# take 255 registers and run few threads per SM; at 128 the spills are cheaper than the lost
# occupancy: H100, paper-scale curved 1920x1080 split-1e-3, 767 -> 636 ms (search 248 -> 200,
# traverse 159 -> 120, integrate 190 -> 139); 96 measured the same, 168 no better.
# The curved sample kernel (one point per thread) is held to 64 (160 -> 154 ms).
MAX_REGISTERS = 128
SAMPLE_MAX_REGISTERS = 64

WindowKeys = wp.types.vector(length=WINDOW, dtype=wp.float32)
WindowElements = wp.types.vector(length=WINDOW, dtype=wp.int32)
LocatedElements = wp.types.vector(length=LOCATED, dtype=wp.int32)
CounterSums = wp.types.vector(length=NUM_STATS, dtype=wp.int64)  # sum_counts' per-thread sums


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


@wp.kernel
def init_rays(cam: CameraArgs, pixel_offset: wp.int32, rays: RayState, t_limit: wp.array(dtype=wp.float32),
              use_limit: wp.int32):
    """Each ray's span [t_lo, t_hi]: the camera's t range and clip planes and, with use_limit,
    the pixel's own far limit t_limit[pixel] (the first opaque surface's t along the same unit
    ray, +inf where none: engine/surfaces.py); without it t_limit is a one-element dummy."""
    i = wp.tid()
    o, d = camera_ray(cam, i + pixel_offset)
    t_lo = cam.t_min
    t_hi = cam.t_max
    cax = wp.dot(d, cam.clip_axis)
    if cax > 0.0:
        t_lo = wp.max(t_lo, cam.clip_near / cax)
        t_hi = wp.min(t_hi, cam.clip_far / cax)
    if use_limit != 0:
        t_hi = wp.min(t_hi, t_limit[i + pixel_offset])
    rays.color_t[i] = wp.vec4(0.0, 0.0, 0.0, 1.0)
    rays.depth_err[i] = wp.vec2(-1.0, 0.0)
    rays.t_cur[i] = t_lo
    rays.t_end[i] = t_hi
    rays.next_element[i] = -1
    rays.left_element[i] = -1
    rays.entry_r[i] = wp.vec4(0.0, 0.0, 0.0, -1.0)
    rays.phase[i] = 0
    if t_hi <= t_lo:
        rays.phase[i] = 2
    rays.active[i] = i


@wp.func
def in_list(ids: wp.ref[LocatedElements], n: int, e: int) -> int:
    for k in range(n):
        if ids[k] == e:
            return 1
    return 0


@wp.func
def affine_stretch(mesh: MeshArgs, e: int, o: wp.vec3, d: wp.vec3) -> wp.vec4:
    """(hit, t0, t1, exit face) of the ray in affine element e: the clip in reference space."""
    A = mesh.ref_a[e]
    return element.reference_clip(mesh.shape[e], A * o + mesh.ref_b[e], A * d)


@wp.func
def pyramid_piece_end(mesh: MeshArgs, e: int, o: wp.vec3, d: wp.vec3, a: float, b: float) -> float:
    """Where the first piece of affine pyramid e's segment [a, b] ends: w = (1 - xi_3) / 2 is
    linear along the ray, and the piece goes on while w stays within a factor
    PYRAMID_W_RATIO of w(a). A pyramid's restriction is f w^2: its rounding is amplified by
    1 / w^2 where w is small, near the apex; in such pieces it stays within PYRAMID_W_RATIO^2
    of the rest of the segment."""
    A = mesh.ref_a[e]
    wa = 0.5 * (1.0 - (A * (o + a * d) + mesh.ref_b[e])[2])
    wb = 0.5 * (1.0 - (A * (o + b * d) + mesh.ref_b[e])[2])
    wa = wp.max(wa, 0.0)
    wb = wp.max(wb, 0.0)
    # within the ratio, or all of it below PYRAMID_W_FLOOR (the apex's own sliver): one piece
    if wp.max(wa, wb) <= PYRAMID_W_RATIO * wp.max(wp.min(wa, wb), PYRAMID_W_FLOOR):
        return b
    target = wa / PYRAMID_W_RATIO
    if wb > wa:
        target = PYRAMID_W_RATIO * wp.max(wa, PYRAMID_W_FLOOR)
    return a + (b - a) * (target - wa) / (wb - wa)


# ------------------------------------------------------------------ the entry search


@wp.struct
class Entry:
    """Where a ray enters an element (the entry search's best candidate so far)."""

    element: wp.int32  # -1: none
    span: wp.vec3  # (t0, t1, exit face); a curved element's t1 and face are curved_exit's to find
    r: wp.vec4  # curved: the solution at t0 (r[3] > 0: valid)
    dv: wp.vec4  # ... and the velocity there


@wp.func
def no_entry(t_end: float) -> Entry:
    """No element before t_end."""
    entry = Entry()
    entry.element = -1
    entry.span = wp.vec3(t_end, t_end, -1.0)
    entry.r = wp.vec4(0.0, 0.0, 0.0, -1.0)
    entry.dv = wp.vec4(0.0, 0.0, 0.0, 0.0)
    return entry


@wp.func
def affine_candidate(mesh: MeshArgs, e: int, o: wp.vec3, d: wp.vec3, t_from: float, t_end: float, eps: float,
                     best: Entry) -> Entry:
    """best, or affine element e where its stretch starts first beyond t_from and reaches past
    t_from + eps."""
    entry = best
    cl = affine_stretch(mesh, e, o, d)
    a0 = wp.max(cl[1], t_from)
    b0 = wp.min(cl[2], t_end)
    if cl[0] > 0.0 and b0 > t_from + eps and a0 < entry.span[0]:
        entry.element = e
        entry.span = wp.vec3(a0, b0, cl[3])
        entry.r = wp.vec4(0.0, 0.0, 0.0, -1.0)
    return entry


@wp.func
def window_offer(keys: wp.ref[WindowKeys], elements: wp.ref[WindowElements], count: int, thresh: float, key: float,
                 e: int):
    """Curved candidate e with box entry `key` into the window of the WINDOW smallest keys, kept
    in order: returns the window's new count and thresh, the smallest key left out of it."""
    if count == WINDOW and key >= keys[WINDOW - 1]:
        return count, wp.min(thresh, key)
    left_out = thresh
    if count == WINDOW:
        left_out = wp.min(thresh, keys[WINDOW - 1])
    k = wp.min(count, WINDOW - 1)
    while k > 0 and keys[k - 1] > key:
        keys[k] = keys[k - 1]
        elements[k] = elements[k - 1]
        k -= 1
    keys[k] = key
    elements[k] = e
    return wp.min(count + 1, WINDOW), left_out


@wp.func
def inside_window(mesh: MeshArgs, o: wp.vec3, d: wp.vec3, t_near: float, left: int, keys: wp.ref[WindowKeys],
                  elements: wp.ref[WindowElements], count: int, nloc: int, newton: int):
    """Is the ray just past t_from (at t_near) inside one of the window's candidates (but `left`)?
    Where a walk stopped at a face without a neighbour, e.g. a hexahedron's face against two
    tetrahedra, the element beyond holds the ray there. One Newton solve each; elements do not
    overlap, so that element's stretch comes first. Returns it as an Entry (element -1: none),
    nloc counting the solves and newton their iterations."""
    found = Entry()
    found.element = -1
    for w in range(count):
        e = elements[w]
        if e != left and keys[w] <= t_near:
            nloc += 1
            r, dv, its = geometry.curved_inside(mesh, e, o, d, t_near, geometry.start_guess(mesh, e, o + t_near * d))
            newton += its
            if r[3] > 0.0:
                found.element = e
                found.span = wp.vec3(t_near, t_near, -1.0)
                found.r = r
                found.dv = dv
                return found, nloc, newton
    return found, nloc, newton


@wp.func
def locate_window(mesh: MeshArgs, o: wp.vec3, d: wp.vec3, t_from: float, eps: float, left: int,
                  keys: wp.ref[WindowKeys], elements: wp.ref[WindowElements], count: int,
                  located: wp.ref[LocatedElements], n_listed: int, best: Entry, nloc: int, newton: int):
    """The window's candidates located in order (curved_entry) while they can still come first:
    returns best updated, n_listed (each is remembered in `located`), nloc and newton counting. The
    element just left must be entered again, not found in the band its exit counted as inside
    (a thin re-entry: the annulus' inner wall, Hex_Mushroom's cap)."""
    entry = best
    for w in range(count):
        if keys[w] < entry.span[0]:
            e = elements[w]
            nloc += 1
            if n_listed < LOCATED:
                located[n_listed] = e
                n_listed += 1
            again = int(0)
            if e == left:
                again = 1
            ent, r, dv, its = geometry.curved_entry(mesh, e, o, d, t_from + eps, again)
            newton += its
            if ent[0] > 0.0 and ent[1] < entry.span[0]:
                entry.element = e
                entry.span = wp.vec3(ent[1], ent[1], -1.0)  # the exit is the caller's to find
                entry.r = r
                entry.dv = dv
    return entry, n_listed, nloc, newton


def _walk_options(CURVED: bool) -> dict:
    # The curved kernels inline Newton solves at several call sites: unrolling their fixed
    # loops costs NVRTC time, not speed (bench/results/h100/compile_unroll.json).
    return {"max_unroll": 4} if CURVED else {}


def _make_search_entry(CURVED: bool):
    @wp.func
    def search_entry(mesh: MeshArgs, o: wp.vec3, d: wp.vec3, t_from: float, t_end: float, left: int):
        """The element whose stretch of the ray starts first beyond t_from (and reaches past
        t_from + eps), as an Entry, and the work: (curved candidates located, Newton iterations,
        BVH candidates returned). Each BVH pass
        takes the smallest exact entry among affine candidates and gathers the WINDOW curved
        candidates with the smallest box entries, then locates those in order while they can
        still come first; another pass follows only if a curved candidate left out of the
        window could. `left`: the element the ray has just left (or -1)."""
        eps = STRETCH_RTOL * wp.abs(t_from)
        q0 = t_from - eps
        best = no_entry(t_end)
        located = LocatedElements()  # the curved candidates already located (curved_entry), n_listed of them
        n_listed = int(0)
        nloc = int(0)  # Newton locations of any kind (the statistics' count)
        newton = int(0)
        n_cand = int(0)
        for p in range(SEARCH_PASSES):
            win_key = WindowKeys()
            win_e = WindowElements()
            nwin = int(0)
            thresh = float(1.0e30)
            # the query starts at t_from (less eps): boxes wholly behind it are culled in the tree
            # (from the camera, a ray leaving the mesh walked every box along its way again)
            query = wp.bvh_query_ray(mesh.bvh, o + q0 * d, d)
            cand = int(0)
            while wp.bvh_query_next(query, cand, best.span[0] - q0):
                n_cand += 1
                if mesh.affine[cand] == 1:
                    if p == 0:
                        best = affine_candidate(mesh, cand, o, d, t_from, t_end, eps, best)
                elif wp.static(CURVED):
                    bx = geometry.box_interval(mesh, cand, o, d)
                    key = wp.max(bx[0], t_from)
                    if bx[1] > t_from + eps and key < best.span[0] and in_list(located, n_listed, cand) == 0:
                        nwin, thresh = window_offer(win_key, win_e, nwin, thresh, key, cand)
            if wp.static(CURVED):
                t_near = t_from + eps
                if p == 0 and best.span[0] > t_near:
                    inside, nloc, newton = inside_window(mesh, o, d, t_near, left, win_key, win_e, nwin, nloc, newton)
                    if inside.element >= 0:
                        return inside, wp.vec3i(nloc, newton, n_cand)
                best, n_listed, nloc, newton = locate_window(mesh, o, d, t_from, eps, left, win_key, win_e, nwin,
                                                             located, n_listed, best, nloc, newton)
            if thresh >= best.span[0]:
                break
        return best, wp.vec3i(nloc, newton, n_cand)

    return search_entry


@wp.func
def entry_face(mesh: MeshArgs, entry: Entry, o: wp.vec3, d: wp.vec3) -> int:
    """The face of entry.element the ray comes in through: the reference face nearest the entry
    point (curved: the search's solution there; affine: the exact map)."""
    e = entry.element
    xi = wp.vec3(entry.r[0], entry.r[1], entry.r[2])
    if mesh.affine[e] == 1:
        xi = mesh.ref_a[e] * (o + entry.span[0] * d) + mesh.ref_b[e]
    return int(geometry.margin_and_face(mesh.shape[e], xi)[1])


@wp.func
def walk_back(mesh: MeshArgs, o: wp.vec3, d: wp.vec3, t_from: float, left: int, found: Entry, work_in: wp.vec3i):
    """The search's entry, moved back to where the ray really comes in. An element entered
    through a face that has a neighbour was entered from that neighbour: the ray was inside it
    just before, so the search missed it (a curved element's entry search can step over a
    stretch thinner than its steps where Newton has nothing to predict with outside the element,
    e.g. a corner clipped on a ball's surface). Walked backwards from the shared face (the
    reversed ray, inside the neighbour, to its exit, as the forward walk finds exits), element
    by element, until a face without a neighbour or t_from. It does not step back into `left`,
    the element the ray has just left, at t_from: where the forward walk left it through a face
    it took for the boundary (next to an edge), the search would find it there again, and the
    walk would leave it again, without end. work: the search's (locations, Newton iterations, BVH
    candidates), counted on."""
    entry = found
    work = work_in
    eps = STRETCH_RTOL * wp.abs(t_from)
    for k in range(BACK_STEPS):
        if entry.element < 0 or entry.span[0] <= t_from + eps:
            break
        if mesh.affine[entry.element] == 0 and entry.r[3] <= 0.0:
            break  # no solution at the entry to name its face
        n = mesh.neighbour[entry.element * 6 + entry_face(mesh, entry, o, d)]
        if n < 0:
            break
        t_e = entry.span[0]
        back = -d
        t_in = t_from  # where the ray enters n (forward), unless it does so after t_from
        r = wp.vec4(0.0, 0.0, 0.0, -1.0)
        dv = wp.vec4(0.0, 0.0, 0.0, 0.0)
        if mesh.affine[n] == 1:
            cl = affine_stretch(mesh, n, o, back)
            if cl[0] <= 0.0:
                break
            t_in = wp.max(-cl[2], t_from)
            if n == left and t_in <= t_from + eps:
                break  # the element the ray has just left, back to where it left: walked already
        else:
            work[0] += 1
            r_b, dv_b, its = geometry.curved_inside(mesh, n, o, back, -t_e, geometry.start_guess(mesh, n, o + t_e * d))
            work[1] += its
            # on the shared face n's margin is 0 up to Newton's rounding either way
            if r_b[3] <= -SHARED_FACE_TOL:
                break  # not on n's face after all: keep the search's entry
            r_b[3] = wp.max(r_b[3], 0.5 * geometry.INSIDE_TOL)
            bx = geometry.box_interval(mesh, n, o, back)
            ex, r_x, dv_x, its_x = geometry.curved_exit(mesh, n, o, back, -t_e, r_b, dv_b, wp.min(bx[1], -t_from))
            work[1] += its_x
            t_in = wp.max(-ex[0], t_from)
            if n == left and t_in <= t_from + eps:
                break  # the element the ray has just left, back to where it left: walked already
            # the forward solution where the ray enters n, for the walk (and this loop's face)
            r, dv, its_in = geometry.curved_inside(mesh, n, o, d, t_in, wp.vec3(r_x[0], r_x[1], r_x[2]))
            work[1] += its_in
        entry.element = n
        entry.span = wp.vec3(t_in, t_in, -1.0)
        entry.r = r
        entry.dv = dv
    return entry, work


def _make_search_kernel(CURVED: bool):
    search_entry = _make_search_entry(CURVED)

    @wp.kernel(enable_backward=False, module="unique", module_options=_walk_options(CURVED),
               cuda_max_registers=MAX_REGISTERS)
    def search(mesh: MeshArgs, cam: CameraArgs, pixel_offset: wp.int32, rays: RayState):
        i = rays.active[wp.tid()]
        if rays.phase[i] != 0 or rays.next_element[i] >= 0:
            return
        pixel = i + pixel_offset
        o, d = camera_ray(cam, pixel)
        entry, work = search_entry(mesh, o, d, rays.t_cur[i], rays.t_end[i], rays.left_element[i])
        if wp.static(CURVED):
            entry, work = walk_back(mesh, o, d, rays.t_cur[i], rays.left_element[i], entry, work)
        rays.stats[pixel, STAT_LOCATES] += work[0]
        rays.stats[pixel, STAT_NEWTON_SEARCH] += work[1]
        rays.stats[pixel, STAT_BVH_CANDIDATES] += work[2]
        if entry.element < 0:
            rays.phase[i] = 1
        else:
            rays.next_element[i] = entry.element
            rays.t_cur[i] = wp.max(rays.t_cur[i], entry.span[0])
            rays.entry_r[i] = entry.r
            rays.entry_dv[i] = entry.dv

    return search


# ------------------------------------------------------------------ the walk


@wp.func
def affine_walk_step(mesh: MeshArgs, e: int, o: wp.vec3, d: wp.vec3, a: float, t_end: float) -> wp.vec3:
    """(inside, b, exit face) of the ray entering affine element e at a: inside 0 where its clip
    starts beyond a (more than STRETCH_RTOL of |a| and its chord)."""
    cl = affine_stretch(mesh, e, o, d)
    if cl[0] <= 0.0 or cl[1] > a + STRETCH_RTOL * (wp.abs(a) + cl[2] - cl[1]):
        return wp.vec3(0.0, a, -1.0)
    return wp.vec3(1.0, wp.max(a, wp.min(cl[2], t_end)), cl[3])


@wp.func
def on_boundary_face(mesh: MeshArgs, e: int, r: wp.vec4) -> int:
    """1 where the face of e nearest the solution r has no neighbour (the domain's boundary)."""
    face = int(geometry.margin_and_face(mesh.shape[e], wp.vec3(r[0], r[1], r[2]))[1])
    if mesh.neighbour[e * 6 + face] < 0:
        return 1
    return 0


@wp.func
def to_face(r: wp.vec4, dv: wp.vec4, dt: float) -> wp.vec4:
    """The solution r moved dt along the ray (its velocity dv), to first order."""
    return r + dt * dv


@wp.func
def curved_walk_step(mesh: MeshArgs, e: int, o: wp.vec3, d: wp.vec3, a: float, t_end: float, r_entry: wp.vec4,
                     dv_entry: wp.vec4):
    """(inside, b, exit face) of the ray entering curved element e at a, the solutions and
    velocities at a and b, the segment's ends and Newton's iterations: Newton at a (or the search's solution r_entry, where valid),
    then geometry.curved_exit up to the element's box or t_end.

    Entries and exits are brackets on margin + INSIDE_TOL, so they lie INSIDE_TOL (reference
    units) outside the face. Between two elements that costs nothing (the neighbour takes over
    at the same t); on the domain's boundary it lengthens the chord by INSIDE_TOL / |dmargin/dt|
    at each end, which grows as the ray grazes the face (float32, the annulus' inner wall:
    2.4e-4 of a unit chord). There the segment's ends (the last two values returned) move to the
    face itself along the margin's tangent, at most half the stretch each; the walk still goes on
    from b, so that the next search does not start inside the band just left (it would find the
    element there again, and again, without end)."""
    r_a = r_entry
    dv_a = dv_entry
    newton = int(0)
    if r_entry[3] <= 0.0:
        r_a, dv_a, newton = geometry.curved_inside(mesh, e, o, d, a, geometry.start_guess(mesh, e, o + a * d))
    # a is on e's entry face: its margin is 0 up to Newton's rounding either way (float32 next
    # to a degenerate edge: beyond INSIDE_TOL, and the search then skipped STRETCH_RTOL |t|)
    if r_a[3] <= -SHARED_FACE_TOL:
        return wp.vec3(0.0, a, -1.0), r_a, dv_a, r_a, dv_a, a, a, newton
    shift_a = float(0.0)  # only the search's entries can come from outside the domain
    if r_entry[3] > 0.0 and dv_a[3] > 0.0 and r_a[3] < geometry.INSIDE_TOL and on_boundary_face(mesh, e, r_a) == 1:
        shift_a = (geometry.INSIDE_TOL - r_a[3]) / dv_a[3]
    r_a[3] = wp.max(r_a[3], 0.5 * geometry.INSIDE_TOL)
    bx = geometry.box_interval(mesh, e, o, d)
    ex, r_b, dv_b, its = geometry.curved_exit(mesh, e, o, d, a, r_a, dv_a, wp.min(bx[1], t_end))
    newton += its
    b = wp.max(a, ex[0])
    shift_b = float(0.0)
    if ex[1] >= 0.0 and dv_b[3] < 0.0 and r_b[3] < geometry.INSIDE_TOL:
        if mesh.neighbour[e * 6 + int(ex[1])] < 0:
            shift_b = wp.max((geometry.INSIDE_TOL - r_b[3]) / dv_b[3], -0.5 * (b - a))
    shift_a = wp.min(shift_a, 0.5 * (b - a))
    if shift_a > 0.0:
        r_a = to_face(r_a, dv_a, shift_a)
    if shift_b < 0.0:
        r_b = to_face(r_b, dv_b, shift_b)
    return wp.vec3(1.0, b, ex[1]), r_a, dv_a, r_b, dv_b, a + shift_a, b + shift_b, newton


@wp.func
def write_segment(mesh: MeshArgs, segs: Segments, slot: int, e: int, a: float, b: float, curved: int,
                  uses_restriction: int, r_a: wp.vec4, dv_a: wp.vec4, r_b: wp.vec4, dv_b: wp.vec4) -> int:
    """Segment [a, b] of element e into `slot`, on the sample kernel's list unless the baselines
    evaluate the (affine) element themselves; returns its samples (field evaluations)."""
    segs.element[slot] = e
    segs.t0[slot] = a
    segs.t1[slot] = b
    segs.tail[slot] = 0.0
    if curved == 0 and uses_restriction == 0:
        segs.degree[slot] = -1
        segs.flags[slot] = SEG_EVALUATE
        return 0
    deg = int(0)
    if curved == 1:
        deg = restriction.curved_base_degree(mesh, e)
        segs.xi0[slot] = wp.vec3(r_a[0], r_a[1], r_a[2])
        segs.v0[slot] = wp.vec3(dv_a[0], dv_a[1], dv_a[2])
        segs.xi1[slot] = wp.vec3(r_b[0], r_b[1], r_b[2])
        segs.v1[slot] = wp.vec3(dv_b[0], dv_b[1], dv_b[2])
    else:
        deg = restriction.restriction_degree(mesh, e)
    segs.degree[slot] = deg
    segs.flags[slot] = curved * SEG_CURVED
    segs.list[wp.atomic_add(segs.list_count, 0, 1)] = slot
    return deg + 1


@wp.func
def element_transparent(mesh: MeshArgs, tf: TransferArgs, e: int) -> int:
    """1 where the density is 0 over element e's whole certified range: classified and split
    take no samples there (traverse) and integrate nothing (shade)."""
    if quadrature.density_max_on(tf, mesh.field_lo[e], mesh.field_hi[e]) <= 0.0:
        return 1
    return 0


@wp.func
def store_walk(rays: RayState, segs: Segments, i: int, pixel: int, finished: int, t: float, e: int, left: int,
               r_entry: wp.vec4, n: int, n_field: int, n_seg: int, n_empty: int, n_walk: int, n_newton: int):
    """Where ray i's walk got this round (its n segments, the counters) into the ray state."""
    if finished == 1:
        rays.phase[i] = 1
    rays.t_cur[i] = t
    rays.next_element[i] = e
    rays.left_element[i] = left
    rays.entry_r[i] = r_entry
    segs.count[i] = n
    rays.stats[pixel, STAT_FIELD_EVALS] += n_field
    rays.stats[pixel, STAT_SEGMENTS] += n_seg
    rays.stats[pixel, STAT_EMPTY] += n_empty
    rays.stats[pixel, STAT_WALKS] += n_walk
    rays.stats[pixel, STAT_NEWTON_WALK] += n_newton


def _make_traverse_kernel(CURVED: bool):
    @wp.kernel(enable_backward=False, module="unique", module_options=_walk_options(CURVED),
               cuda_max_registers=MAX_REGISTERS)
    def traverse(mesh: MeshArgs, cam: CameraArgs, tf: TransferArgs, q: QuadArgs, pixel_offset: wp.int32,
                 rays: RayState, segs: Segments):
        i = rays.active[wp.tid()]
        pixel = i + pixel_offset
        rays.stats[pixel, STAT_ROUNDS] += 1
        n = int(0)
        if rays.phase[i] != 0 or rays.next_element[i] < 0:
            segs.count[i] = 0
            return
        o, d = camera_ray(cam, pixel)
        t = rays.t_cur[i]
        t_end = rays.t_end[i]
        e = rays.next_element[i]
        r_entry = rays.entry_r[i]  # the search's solution in a curved e at t (margin > 0: valid)
        dv_entry = rays.entry_dv[i]
        uses_restriction = int(0)  # classified and split integrate the restriction; skip empty elements
        if q.method >= METHOD_CLASSIFIED:
            uses_restriction = 1
        n_field = int(0)
        n_seg = int(0)
        n_empty = int(0)
        n_walk = int(0)
        n_newton = int(0)
        zero_steps = int(0)
        finished = int(0)
        left = rays.left_element[i]  # the element the ray has just left
        for step in range(STEPS_PER_ROUND):
            if n >= SEGMENTS_PER_ROUND:
                break
            if t >= t_end:
                finished = 1
                break
            if e < 0:
                break  # the next round's search finds where the ray goes on
            a = t
            n_walk += 1
            stretch = wp.vec3(1.0, a, -1.0)  # (inside, b, exit face)
            seg_a = a  # the segment integrated: [a, b] but where a curved step moves its ends
            seg_b = a
            r_a = wp.vec4(0.0, 0.0, 0.0, -1.0)  # curved: the solutions and velocities at a and b
            dv_a = wp.vec4(0.0, 0.0, 0.0, 0.0)
            r_b = r_a
            dv_b = dv_a
            if mesh.affine[e] == 1:
                stretch = affine_walk_step(mesh, e, o, d, a, t_end)
            elif wp.static(CURVED):
                stretch, r_a, dv_a, r_b, dv_b, seg_a, seg_b, its = curved_walk_step(mesh, e, o, d, a, t_end,
                                                                                    r_entry, dv_entry)
                n_newton += its
                r_entry = wp.vec4(0.0, 0.0, 0.0, -1.0)  # the search's solution served this entry only
            if stretch[0] == 0.0:
                e = -1  # not in the neighbour after all: the next round searches from here
                break
            b = stretch[1]
            if mesh.affine[e] == 1:
                seg_b = b
            face = int(stretch[2])
            stay = int(0)
            if uses_restriction == 1 and mesh.shape[e] == element.PYR and mesh.affine[e] == 1 and b > a:
                cut = pyramid_piece_end(mesh, e, o, d, a, b)
                if cut < b:
                    b = cut
                    seg_b = cut
                    stay = 1
            if b > a:
                zero_steps = 0
                n_seg += 1
                if uses_restriction == 1 and element_transparent(mesh, tf, e) == 1:
                    n_empty += 1  # the element's whole range is transparent: no samples
                else:
                    curved = int(0)  # a constant in the affine kernel: the sample kernel's Newton compiles out
                    if wp.static(CURVED):
                        curved = int(1) - mesh.affine[e]
                    n_field += write_segment(mesh, segs, i * SEGMENTS_PER_ROUND + n, e, seg_a, seg_b, curved,
                                             uses_restriction, r_a, dv_a, r_b, dv_b)
                    n += 1
            else:
                zero_steps += 1
            t = wp.max(t, b)
            if stay == 1:
                continue  # the rest of the pyramid's stretch next
            left = e
            if face >= 0 and zero_steps < MAX_ZERO_STEPS:
                e = mesh.neighbour[e * 6 + face]
            else:
                e = -1
        store_walk(rays, segs, i, pixel, finished, t, e, left, r_entry, n, n_field, n_seg, n_empty, n_walk, n_newton)

    return traverse


def _make_sample_kernel(CURVED: bool, MODES: int):
    # MODES > 0: hexahedra and prisms of (MODES,) * 3 modes evaluate through the unrolled
    # element.static_evaluator (its loops need max_unroll >= MODES)
    opts = {"max_unroll": max(4, MODES)} if CURVED or MODES else {}
    evaluate = element.static_evaluator(MODES) if MODES else element.eval_element

    @wp.kernel(enable_backward=False, module="unique", module_options=opts, cuda_max_registers=SAMPLE_MAX_REGISTERS if CURVED else None)
    def sample(mesh: MeshArgs, cam: CameraArgs, pixel_offset: wp.int32, segs: Segments, slots: wp.array(dtype=wp.int32),
               stride: wp.int32, odd: wp.int32, stats: wp.array2d(dtype=wp.int32)):
        """One thread per sample point: slots[tid // stride]'s point tid % stride (odd = 1: its
        odd points, the ones a doubled degree adds). The threads of one slot run side by side,
        so a warp evaluates one element or the end of one and the start of the next. A curved
        point's Newton iterations go to its ray's stats (an atomic add per curved point)."""
        tid = wp.tid()
        slot = slots[tid // stride]
        j = tid % stride
        deg = segs.degree[slot]
        if odd == 1:
            j = 2 * j + 1
        if j > deg:
            return
        o, d = camera_ray(cam, slot // SEGMENTS_PER_ROUND + pixel_offset)
        curved = int(0)
        if wp.static(CURVED):
            if (segs.flags[slot] & SEG_CURVED) != 0:
                curved = 1
        xi, w, newton = restriction.sample_point(mesh, o, d, segs, slot, j, deg, curved)
        if wp.static(CURVED):
            if newton > 0:
                wp.atomic_add(stats, slot // SEGMENTS_PER_ROUND + pixel_offset, STAT_NEWTON_SAMPLE, newton)
        e = segs.element[slot]
        f = wp.static(evaluate)(mesh.shape[e], mesh.coeffs, mesh.coeff_offset[e], mesh.modes[e], xi)
        segs.samples[slot * MAX_SAMPLES + j] = f * w * w
        if j == 0:
            ends = restriction.end_weights(mesh, o, d, segs, slot, curved)
            segs.samples[slot * MAX_SAMPLES + MAX_SAMPLES - 2] = ends[0]
            segs.samples[slot * MAX_SAMPLES + MAX_SAMPLES - 1] = ends[1]

    return sample


@wp.kernel(enable_backward=False)
def coefficients(segs: Segments, slots: wp.array(dtype=wp.int32), stride: wp.int32):
    """stride threads per slot (the sample kernel's: its first-pass points): thread j of
    slots[tid // stride] writes c_j, c_(j + stride), ... up to the slot's degree, so a slot
    whose degree was doubled needs no wider launch (with 64 threads a slot for the largest
    refined degree, most idled)."""
    tid = wp.tid()
    slot = slots[tid // stride]
    k = tid % stride
    deg = segs.degree[slot]
    base = slot * MAX_SAMPLES
    kk = k
    while kk <= deg:
        segs.coeffs[base + kk] = restriction.chebyshev_coefficient(segs, slot, kk, deg)
        kk += stride
    if k == 0:  # the weights right after the series (restriction.series_weights)
        segs.coeffs[base + deg + 1] = segs.samples[base + MAX_SAMPLES - 2]
        segs.coeffs[base + deg + 2] = segs.samples[base + MAX_SAMPLES - 1]


@wp.kernel(enable_backward=False)
def refine(pixel_offset: wp.int32, rays: RayState, segs: Segments, slots: wp.array(dtype=wp.int32),
           count: wp.array(dtype=wp.int32), again: wp.array(dtype=wp.int32), again_count: wp.array(dtype=wp.int32),
           allow: wp.int32):
    """One thread per sampled slot: a curved slot's tail is its error estimate; if it is too
    large (and allow is 1) the degree is doubled and the slot goes on the `again` list for the
    sample kernel's odd points."""
    idx = wp.tid()
    if idx >= count[0]:
        return
    slot = slots[idx]
    if (segs.flags[slot] & SEG_CURVED) == 0:
        return
    if restriction.refine_degree(segs, slot, allow) == 1:
        again[wp.atomic_add(again_count, 0, 1)] = slot
        rays.stats[slot // SEGMENTS_PER_ROUND + pixel_offset, STAT_FIELD_EVALS] += segs.degree[slot] // 2


_WALK = {}
_SAMPLE = {}


def walk_kernels(curved: bool, modes: int = 0):
    """(search, traverse, sample), specialised at compile time: with `curved` False the Newton
    location and curved sampling are compiled out (affine meshes pay only for what they use);
    with `modes` N > 0 (element.static_modes of the mesh) the sample kernel evaluates
    hexahedra and prisms of N modes unrolled."""
    key = bool(curved)
    if key not in _WALK:
        _WALK[key] = (_make_search_kernel(key), _make_traverse_kernel(key))
    skey = (key, int(modes))
    if skey not in _SAMPLE:
        _SAMPLE[skey] = _make_sample_kernel(*skey)
    return _WALK[key] + (_SAMPLE[skey],)


@wp.func
def classify(mesh: MeshArgs, tf: TransferArgs, q: QuadArgs, e: int, flags: int, coeffs: wp.array(dtype=wp.float32),
             base: int, deg: int) -> wp.vec4:
    """classified and split: (lo, hi) bounding f on the segment, emitting (1 where the colour is not 0
    over them), and the segment's class: 1 empty, 2 smooth, 3 piecewise-smooth."""
    bnd = wp.vec2(0.0, 0.0)
    if (flags & SEG_CURVED) != 0 and q.method != METHOD_SPLIT:
        # the paper's classes bound the true field; a curved segment's interpolant is no bound
        # of it (split integrates the interpolant itself, so its bounds decide there)
        bnd = wp.vec2(mesh.field_lo[e], mesh.field_hi[e])
    else:
        bnd = restriction.segment_bounds(coeffs, base, deg, mesh.field_err[e])
    emitting = int(0)
    if quadrature.color_max_on(tf, bnd[0], bnd[1]) > 0.0:
        emitting = 1
    piecewise = quadrature.breakpoint_inside(tf.density_s, bnd[0], bnd[1])
    if emitting == 1 and quadrature.breakpoint_inside(tf.color_s, bnd[0], bnd[1]) == 1:
        piecewise = 1
    kind = 2 + piecewise
    if quadrature.density_max_on(tf, bnd[0], bnd[1]) <= 0.0:
        kind = 1
    return wp.vec4(bnd[0], bnd[1], float(emitting), float(kind))


@wp.func
def segment_step_terms(mesh: MeshArgs, tf: TransferArgs, q: QuadArgs, e: int, flags: int,
                       coeffs: wp.array(dtype=wp.float32), base: int, deg: int, a: float, b: float) -> wp.vec3:
    """A segment's quadrature.step_error_terms where it is piecewise-smooth (else 0)."""
    cls = classify(mesh, tf, q, e, flags, coeffs, base, deg)
    terms = wp.vec3(0.0, 0.0, 0.0)
    if int(cls[3]) == 3:
        terms = quadrature.step_error_terms(tf, coeffs, base, deg, a, b, cls[0], cls[1], int(cls[2]))
    return terms


@wp.kernel(enable_backward=False, module="unique")
def step_terms(mesh: MeshArgs, tf: TransferArgs, q: QuadArgs, segs: Segments, slots: wp.array(dtype=wp.int32)):
    """classified without a fixed step, one thread per sampled slot: the segment's
    quadrature.step_error_terms where it is piecewise-smooth, for integrate to turn into its steps
    with the transmittance the ray reaches it with (quadrature.auto_steps). A kernel of its own so
    that integrate's registers do not grow."""
    slot = slots[wp.tid()]
    segs.step_terms[slot] = segment_step_terms(mesh, tf, q, segs.element[slot], segs.flags[slot], segs.coeffs,
                                               slot * MAX_SAMPLES, segs.degree[slot], segs.t0[slot], segs.t1[slot])


@wp.func
def integrate_segment(mesh: MeshArgs, tf: TransferArgs, q: QuadArgs, e: int, o: wp.vec3, d: wp.vec3, a: float,
                      b: float, deg: int, flags: int, coeffs: wp.array(dtype=wp.float32), base: int,
                      terms: wp.vec3, state_in: RayIntegral):
    """One segment into the ray state (its series at coeffs[base ..], restriction.py's layout,
    wherever it is kept: a round's slot or a cached segment; `terms`: its step_error_terms, for
    classified without a fixed step); returns the new state and
    (element evaluations, restriction evaluations, class: 1 empty, 2 smooth, 3
    piecewise-smooth, 0 unclassified)."""
    state = state_in
    evaluate = int(0)
    xo = wp.vec3(0.0, 0.0, 0.0)
    xd = wp.vec3(0.0, 0.0, 0.0)
    if (flags & SEG_EVALUATE) != 0:
        evaluate = 1
        A = mesh.ref_a[e]
        xo = A * o + mesh.ref_b[e]
        xd = A * d
    counts = wp.vec3(0.0, 0.0, 0.0)
    mode = int(0)  # 0: march (the baselines; classified's piecewise-smooth), 1: Gauss-Kronrod pieces
    trapezoid = int(1)
    piecewise = int(0)
    emitting = int(1)
    if q.method == METHOD_RIEMANN:
        trapezoid = 0
    elif q.method >= METHOD_CLASSIFIED:
        cls = classify(mesh, tf, q, e, flags, coeffs, base, deg)
        emitting = int(cls[2])
        counts[2] = cls[3]
        if int(cls[3]) == 1:
            return state, counts
        piecewise = int(cls[3]) - 2
        if piecewise == 0 or q.method == METHOD_SPLIT:
            mode = 1
    if mode == 0:
        n = int(0)
        if q.h > 0.0:
            n = quadrature.fixed_steps(q, a, b)
        else:  # classified without a fixed step (riemann and trapezoid always have one: engine/view.py)
            nb = quadrature.auto_steps(q, terms, a, b, state.transmittance)
            n = int(nb[0])
            state.error = state.error + nb[1]
        state, nev = quadrature.march(mesh, tf, q, trapezoid, e, xo, xd, evaluate, coeffs, base, deg, a, b, n, state)
        counts[0] = nev[0]
        counts[1] = nev[1]
    else:
        piece = a
        while piece < b and state.transmittance >= q.min_transmittance:
            cut = b
            if piecewise == 1:
                nc = quadrature.next_cut(tf, coeffs, base, deg, a, b, piece)
                cut = nc[0]
                counts[1] = counts[1] + nc[1]
            state = quadrature.gauss_kronrod_smooth(tf, q, coeffs, base, deg, a, b, piece, cut, emitting, state)
            piece = cut
    return state, counts


@wp.struct
class Tally:
    """What a ray's integration of its segments counted (the stats' STAT_* counters)."""

    field_evals: wp.int32
    restriction_evals: wp.float32
    empty: wp.int32
    smooth: wp.int32
    piecewise: wp.int32


@wp.func
def no_tally() -> Tally:
    t = Tally()
    t.field_evals = 0
    t.restriction_evals = 0.0
    t.empty = 0
    t.smooth = 0
    t.piecewise = 0
    return t


@wp.func
def integrate_counted(mesh: MeshArgs, tf: TransferArgs, q: QuadArgs, e: int, o: wp.vec3, d: wp.vec3, a: float,
                      b: float, deg: int, flags: int, tail: float, coeffs: wp.array(dtype=wp.float32), base: int,
                      terms: wp.vec3, state_in: RayIntegral, tally_in: Tally):
    """integrate_segment, the segment's tail added to the error estimate first, its counts to
    the tally: one segment as the integrate and shade kernels both take it."""
    state = state_in
    tally = tally_in
    state.error = state.error + tail
    state, counts = integrate_segment(mesh, tf, q, e, o, d, a, b, deg, flags, coeffs, base, terms, state)
    tally.field_evals += int(counts[0])
    tally.restriction_evals += counts[1]
    cls = int(counts[2])
    if cls == 1:
        tally.empty += 1
    elif cls == 2:
        tally.smooth += 1
    elif cls == 3:
        tally.piecewise += 1
    return state, tally


@wp.kernel(enable_backward=False, module="unique", module_options={"max_unroll": 1}, cuda_max_registers=MAX_REGISTERS)
def integrate(mesh: MeshArgs, cam: CameraArgs, tf: TransferArgs, q: QuadArgs, pixel_offset: wp.int32,
              rays: RayState, segs: Segments):
    i = rays.active[wp.tid()]
    if rays.phase[i] == 2:
        return
    pixel = i + pixel_offset
    o, d = camera_ray(cam, pixel)
    ct = rays.color_t[i]
    de = rays.depth_err[i]
    state = RayIntegral()
    state.color = wp.vec3(ct[0], ct[1], ct[2])
    state.transmittance = ct[3]
    state.restriction_evals = 0.0
    state.depth = de[0]
    state.error = de[1]
    tally = no_tally()
    for k in range(segs.count[i]):
        if state.transmittance < q.min_transmittance:
            break
        slot = i * SEGMENTS_PER_ROUND + k
        state, tally = integrate_counted(mesh, tf, q, segs.element[slot], o, d, segs.t0[slot], segs.t1[slot],
                                         segs.degree[slot], segs.flags[slot], segs.tail[slot], segs.coeffs,
                                         slot * MAX_SAMPLES, segs.step_terms[slot], state, tally)
    rays.color_t[i] = wp.vec4(state.color[0], state.color[1], state.color[2], state.transmittance)
    rays.depth_err[i] = wp.vec2(state.depth, state.error)
    rays.stats[pixel, STAT_FIELD_EVALS] += tally.field_evals
    rays.stats[pixel, STAT_RESTRICTION_EVALS] += int(tally.restriction_evals + state.restriction_evals)
    rays.stats[pixel, STAT_EMPTY] += tally.empty
    rays.stats[pixel, STAT_SMOOTH] += tally.smooth
    rays.stats[pixel, STAT_PIECEWISE] += tally.piecewise
    if state.transmittance < q.min_transmittance or rays.phase[i] == 1:
        rays.phase[i] = 2
    else:
        rays.active_next[wp.atomic_add(rays.active_count, 0, 1)] = i


@wp.func
def pixel_values(q: QuadArgs, ct: wp.vec4, de: wp.vec2, t_end: float):
    """A ray's pixel from its (C, T) and (depth, error): RGB = C + T background, alpha = 1 - T;
    depth (the ray's far end where the opacity never reached 0.5) and the error estimate."""
    T = ct[3]
    depth = de[0]
    if depth < 0.0:
        depth = t_end
    return (wp.vec4(ct[0] + T * q.background[0], ct[1] + T * q.background[1], ct[2] + T * q.background[2], 1.0 - T),
            wp.vec2(depth, de[1]))


@wp.kernel(enable_backward=False)
def finalize(q: QuadArgs, pixel_offset: wp.int32, rays: RayState, rgba: wp.array(dtype=wp.vec4),
             aux: wp.array(dtype=wp.vec2)):
    """Pixels of the tile (pixel_values)."""
    i = wp.tid()
    pixel = i + pixel_offset
    px, ax = pixel_values(q, rays.color_t[i], rays.depth_err[i], rays.t_end[i])
    rgba[pixel] = px
    aux[pixel] = ax


# ------------------------------------------------------------------ the segment cache


@wp.kernel(enable_backward=False)
def trace_reserve(rays: RayState, segs: Segments, cache: SegmentCache, reserved: wp.array(dtype=wp.vec3i)):
    """A trace's round, after the samples, one thread per active ray (the integrate kernel's
    place): reserve (first segment, chunk, first coefficient) in the cache for the ray's segments
    of the round, one chunk, and put the ray on the next round's list unless its traversal has
    finished. Nothing is integrated, so no ray stops early: the cache holds the whole ray."""
    i = rays.active[wp.tid()]
    reserved[i] = wp.vec3i(-1, -1, -1)
    if rays.phase[i] == 2:
        return
    k = segs.count[i]
    if k > 0:
        n_coeffs = int(0)
        for j in range(k):
            deg = segs.degree[i * SEGMENTS_PER_ROUND + j]
            if deg >= 0:
                n_coeffs += deg + 3
        reserved[i] = wp.vec3i(wp.atomic_add(cache.counts, 0, k), wp.atomic_add(cache.counts, 1, 1),
                               wp.atomic_add(cache.counts, 2, n_coeffs))
    if rays.phase[i] == 1:
        rays.phase[i] = 2
    else:
        rays.active_next[wp.atomic_add(rays.active_count, 0, 1)] = i


@wp.kernel(enable_backward=False)
def trace_write(rays: RayState, segs: Segments, cache: SegmentCache, reserved: wp.array(dtype=wp.vec3i),
                last_chunk: wp.array(dtype=wp.int32), ray_offset: wp.int32):
    """One thread per slot of the active rays: the ray's segment k into its reserved place, with
    its series (degree + 3 values); thread 0 of a ray writes the chunk and links it after the
    ray's last one (last_chunk, per ray of the tile), so the chunks go in the rounds' order."""
    tid = wp.tid()
    i = rays.active[tid // SEGMENTS_PER_ROUND]
    k = tid % SEGMENTS_PER_ROUND
    r = reserved[i]
    if r[0] < 0 or k >= segs.count[i]:
        return
    first_slot = i * SEGMENTS_PER_ROUND
    offset = r[2]
    for j in range(k):
        dj = segs.degree[first_slot + j]
        if dj >= 0:
            offset += dj + 3
    slot = first_slot + k
    s = r[0] + k
    deg = segs.degree[slot]
    cache.element[s] = segs.element[slot]
    cache.t0[s] = segs.t0[slot]
    cache.t1[s] = segs.t1[slot]
    cache.degree[s] = deg
    cache.flags[s] = segs.flags[slot]
    cache.tail[s] = segs.tail[slot]
    cache.coeff_offset[s] = offset
    for m in range(deg + 3):  # none for deg = -1
        cache.coeffs[offset + m] = segs.coeffs[slot * MAX_SAMPLES + m]
    if k == 0:
        c = r[1]
        cache.chunk_start[c] = r[0]
        cache.chunk_count[c] = segs.count[i]
        cache.chunk_next[c] = -1
        prev = last_chunk[i]
        if prev < 0:
            cache.head[i + ray_offset] = c
        else:
            cache.chunk_next[prev] = c
        last_chunk[i] = c


@wp.kernel(enable_backward=False)
def trace_ends(rays: RayState, cache: SegmentCache, ray_offset: wp.int32):
    """Each ray's far end into the cache (the depth output where its opacity stays below 0.5)."""
    i = wp.tid()
    cache.t_end[i + ray_offset] = rays.t_end[i]


@wp.kernel(enable_backward=False, module="unique", module_options={"max_unroll": 1}, cuda_max_registers=MAX_REGISTERS)
def shade(mesh: MeshArgs, cam: CameraArgs, tf: TransferArgs, q: QuadArgs, pixel_offset: wp.int32,
          ray_offset: wp.int32, cache: SegmentCache, rgba: wp.array(dtype=wp.vec4), aux: wp.array(dtype=wp.vec2),
          stats: wp.array2d(dtype=wp.int32), nonfinite: wp.array(dtype=wp.int32)):
    """One thread per ray of a trace (ray i is pixel i + pixel_offset): its cached segments front
    to back through integrate_counted, as the integrate kernel takes them round by round, then
    its pixel (pixel_values) into rgba[i], aux[i]. Classified and split skip the elements the
    traverse kernel would not have sampled under tf (element_transparent), and the ray stops
    where integrate stops it (transmittance below q.min_transmittance), so the pixel is a fresh
    render's. Its counters go to stats[i] (segments: those walked up to the stop), and a pixel
    that is not finite counts in nonfinite[0]."""
    i = wp.tid() + ray_offset
    o, d = camera_ray(cam, i + pixel_offset)
    state = RayIntegral()
    state.color = wp.vec3(0.0, 0.0, 0.0)
    state.transmittance = 1.0
    state.restriction_evals = 0.0
    state.depth = -1.0
    state.error = 0.0
    tally = no_tally()
    skip_transparent = int(0)
    if q.method >= METHOD_CLASSIFIED:
        skip_transparent = 1
    n_seg = int(0)
    n_skipped = int(0)
    going = int(1)
    c = cache.head[i]
    while c >= 0 and going == 1:
        s = cache.chunk_start[c]
        s_end = s + cache.chunk_count[c]
        while s < s_end:
            e = cache.element[s]
            if skip_transparent == 1 and element_transparent(mesh, tf, e) == 1:
                n_skipped += 1
            else:
                if state.transmittance < q.min_transmittance:
                    going = 0
                    break
                terms = wp.vec3(0.0, 0.0, 0.0)
                if q.method == METHOD_CLASSIFIED and q.h <= 0.0:  # its own steps: step_terms' work, here
                    terms = segment_step_terms(mesh, tf, q, e, cache.flags[s], cache.coeffs, cache.coeff_offset[s],
                                               cache.degree[s], cache.t0[s], cache.t1[s])
                state, tally = integrate_counted(mesh, tf, q, e, o, d, cache.t0[s], cache.t1[s], cache.degree[s],
                                                 cache.flags[s], cache.tail[s], cache.coeffs, cache.coeff_offset[s],
                                                 terms, state, tally)
            n_seg += 1
            s += 1
        c = cache.chunk_next[c]
    px, ax = pixel_values(q, wp.vec4(state.color[0], state.color[1], state.color[2], state.transmittance),
                          wp.vec2(state.depth, state.error), cache.t_end[i])
    rgba[i] = px
    aux[i] = ax
    if not (wp.isfinite(px) and wp.isfinite(ax)):
        wp.atomic_add(nonfinite, 0, 1)
    stats[i, STAT_FIELD_EVALS] = tally.field_evals
    stats[i, STAT_RESTRICTION_EVALS] = int(tally.restriction_evals + state.restriction_evals)
    stats[i, STAT_SEGMENTS] = n_seg
    stats[i, STAT_EMPTY] = n_skipped + tally.empty
    stats[i, STAT_SMOOTH] = tally.smooth
    stats[i, STAT_PIECEWISE] = tally.piecewise
    stats[i, STAT_LOCATES] = 0
    stats[i, STAT_WALKS] = 0
    stats[i, STAT_BVH_CANDIDATES] = 0
    stats[i, STAT_NEWTON_SEARCH] = 0
    stats[i, STAT_NEWTON_WALK] = 0
    stats[i, STAT_NEWTON_SAMPLE] = 0
    stats[i, STAT_ROUNDS] = 0


@wp.kernel(enable_backward=False)
def sum_counts(stats: wp.array2d(dtype=wp.int32), threads: wp.int32, out: wp.array(dtype=wp.int64)):
    """The per-ray counters summed on the device into out: thread t takes rows t, t + threads, ...
    (neighbouring threads read neighbouring rows), then adds its sums."""
    acc = CounterSums()
    r = wp.tid()
    while r < stats.shape[0]:
        for k in range(NUM_STATS):
            acc[k] += wp.int64(stats[r, k])
        r += threads
    for k in range(NUM_STATS):
        wp.atomic_add(out, k, acc[k])


# The kernels by name, the one list: the renderer loads, launches and times them by these names
# (kernel_table), a render, a trace and a shade each launching their own.
RENDER_KERNELS = ("init_rays", "search", "traverse", "sample", "refine", "coefficients", "step_terms", "integrate",
                  "finalize")
TRACE_KERNELS = ("init_rays", "search", "traverse", "sample", "refine", "coefficients", "trace_reserve", "trace_write",
                 "trace_ends")
SHADE_KERNELS = ("shade", "sum_counts")


def kernel_table(curved: bool, modes: int = 0) -> dict:
    """Every kernel of RENDER_KERNELS, TRACE_KERNELS and SHADE_KERNELS by name, the walk's
    specialised as walk_kernels(curved, modes)."""
    search, traverse, sample = walk_kernels(curved, modes)
    table = {"init_rays": init_rays, "search": search, "traverse": traverse, "sample": sample, "refine": refine,
             "coefficients": coefficients, "step_terms": step_terms, "integrate": integrate, "finalize": finalize,
             "trace_reserve": trace_reserve, "trace_write": trace_write, "trace_ends": trace_ends, "shade": shade,
             "sum_counts": sum_counts}
    assert set(table) == set(RENDER_KERNELS + TRACE_KERNELS + SHADE_KERNELS)
    return table
