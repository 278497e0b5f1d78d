"""The walk (the traverse kernel) and the samples along its segments (sample, refine, coefficients).

Each ray walks front to back through shared faces (MeshArgs.neighbour) and writes up to
SEGMENTS_PER_ROUND element segments per round: an affine element's exact clip, or a curved one's
Newton solution followed along the ray to its exit (geometry.curved_exit). The next segment
starts where the last one ended (no gap, no double count). Where there is no neighbour (the
domain's boundary, a gap, a non-conforming face, a ray through an edge) the next round's search
finds where the ray goes on (kernels/entry.py). Then one thread per sample point fills each listed
segment's samples, refine doubles a curved interpolant's degree where its tail is too large, and
coefficients turns the samples into the segment's Chebyshev series.
"""
from __future__ import annotations

import warp as wp

from ..shapes import MAX_FACES
from . import crossing
from . import derived
from . import element
from . import geometry
from . import quadrature
from . import restriction
from .args import (MAX_SAMPLES, STAT_BVH_CANDIDATES, SEG_CURVED, SEG_EVALUATE, SEG_INTERPOLANT, SEGMENTS_PER_ROUND, STAT_EMPTY, STAT_FIELD_EVALS,
                   STAT_NEWTON_SAMPLE, STAT_NEWTON_WALK, STAT_ROUNDS, STAT_SEGMENTS, STAT_WALKS, CameraArgs, MeshArgs,
                   QuadArgs, RayState, Segments, TransferArgs)
from .quadrature import samples_segments
from .rays import MAX_REGISTERS, SAMPLE_MAX_REGISTERS, affine_clip_rounding, affine_stretch, camera_ray, walk_options
from .tolerances import SHARED_FACE_TOL, STRETCH_RTOL

wp.set_module_options({"enable_backward": False})

MAX_ZERO_STEPS = 3  # zero-length walks in a row (a ray through an edge) before searching instead
PYRAMID_W_RATIO = 2.0  # a pyramid's segment is cut where its weight w changes by more than this
PYRAMID_W_FLOOR = 1.0e-6  # ... down to this w (the last sliver at the apex stays whole)
STEPS_PER_ROUND = 64 * SEGMENTS_PER_ROUND  # walking steps a ray may take in one round (hang guard)


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


@wp.func
def affine_walk_step(mesh: MeshArgs, e: int, o: wp.vec3, d: wp.vec3, a: float, t_end: float, left: int) -> wp.vec3:
    """(inside, b, exit face) of the ray entering affine element e at a, from `left` (-1: none):
    inside 0 where its clip starts beyond a by more than STRETCH_RTOL of |a| and its chord and the
    rounding of both clips of the face between (affine_clip_rounding: a ray grazing the face sees
    left's exit early and e's entry late, and the stretch between would be lost)."""
    cl = affine_stretch(mesh, e, o, d)
    if cl[0] <= 0.0:
        return wp.vec3(0.0, a, -1.0)
    late = cl[1] - a
    if late > STRETCH_RTOL * (wp.abs(a) + cl[2] - cl[1]):
        slack = affine_clip_rounding(mesh, e, o, d, cl[1], -1.0)
        if left >= 0 and mesh.affine[left] == 1:
            slack += affine_clip_rounding(mesh, left, o, d, a, 1.0)
        if late > STRETCH_RTOL * (wp.abs(a) + cl[2] - cl[1]) + slack:
            return wp.vec3(0.0, a, -1.0)
    return wp.vec3(1.0, wp.max(a, wp.min(cl[2], t_end)), cl[3])


@wp.func
def on_boundary_face(mesh: MeshArgs, e: int, r: wp.vec4) -> int:
    """1 where the face of e nearest the solution r has no neighbour (the domain's boundary)."""
    face = int(geometry.margin_and_face(mesh.shape[e], wp.vec3(r[0], r[1], r[2]))[1])
    if mesh.neighbour[e * MAX_FACES + face] < 0:
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
    velocities at a and b, the segment's ends, Newton's iterations and the BVH candidates: Newton at
    a (or the search's solution r_entry, where valid), then the exit: the first crossing of e's own
    faces that leaves it (crossing.next_crossing over the element's group of triangles), exact on
    the face; where none is found, geometry.curved_exit up to the element's box or t_end, whose
    ends are brackets:

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
        return wp.vec3(0.0, a, -1.0), r_a, dv_a, r_a, dv_a, a, a, newton, int(0)
    shift_a = float(0.0)  # only the search's entries can come from outside the domain
    if r_entry[3] > 0.0 and dv_a[3] > 0.0 and r_a[3] < geometry.INSIDE_TOL and on_boundary_face(mesh, e, r_a) == 1:
        shift_a = (geometry.INSIDE_TOL - r_a[3]) / dv_a[3]
    r_a[3] = wp.max(r_a[3], 0.5 * geometry.INSIDE_TOL)
    # the exit: the first crossing of e's own faces beyond a that leaves it (the element's group of
    # triangles in the BVH, each candidate polished on its face: kernels/crossing.py)
    out, work = crossing.next_crossing(mesh, wp.bvh_get_group_root(mesh.bvh, e), o, d, a, 1.0e30,
                                       STRETCH_RTOL * wp.abs(a), crossing.WANT_EXIT, -1, crossing.no_passed())
    newton += work[1]
    # an entry through one of e's faces before that exit: the ray left e before it (a dip outside
    # by a grazing face, whose polishes all found the way back in): the walk's own search instead
    if out.element == e and out.t_other >= out.t:
        b = wp.max(a, wp.min(out.t, t_end))
        face = out.face
        r_b = crossing.solution_at(mesh, out)
        dv_b = crossing.velocity_at(mesh, out)
        ends_inside = int(0)
        if out.t > t_end:
            # the ray ends inside e (a clip plane, an opaque surface, the camera's far end)
            face = -1
            r_b, dv_b, its_end = geometry.curved_inside(mesh, e, o, d, b, geometry.ahead(r_a, dv_a, b - a))
            newton += its_end
            if r_b[3] <= 0.0:
                ends_inside = -1  # not located there: the walk's own exit search below
        if ends_inside == 0:
            shift_a = wp.min(shift_a, 0.5 * (b - a))
            if shift_a > 0.0:
                r_a = to_face(r_a, dv_a, shift_a)
            return wp.vec3(1.0, b, float(face)), r_a, dv_a, r_b, dv_b, a + shift_a, b, newton, work[2]
    # no crossing found: the walk's own exit search, stepping the element's point location along the ray
    bx = geometry.box_interval(mesh, e, o, d)
    ex, r_b, dv_b, its = geometry.curved_exit(mesh, e, o, d, a, r_a, dv_a, wp.min(bx[1], t_end))
    newton += its
    b = wp.max(a, ex[0])
    shift_b = float(0.0)
    if ex[1] >= 0.0 and mesh.neighbour[e * MAX_FACES + int(ex[1])] < 0:
        # the domain's boundary: the segment ends on the face itself, its crossing polished from
        # the bracket's end (which lies in the band outside it); else moved along the margin's tangent
        xi_f, t_f, ok, vel, its_f = crossing.polish(mesh, e, int(ex[1]), o, d, wp.vec3(r_b[0], r_b[1], r_b[2]), b)
        newton += its_f
        leaving = int(0)
        if ok >= 1 and t_f <= b and crossing.entering(mesh, e, int(ex[1]), vel) == 0:
            leaving = 1
        if leaving == 1 and t_f > a:
            shift_b = t_f - b
            r_b = crossing.solution_at_xi(mesh, e, xi_f)
            pl = element.face_plane(mesh.shape[e], int(ex[1]))
            dv_b = wp.vec4(vel[0], vel[1], vel[2], -(pl[0] * vel[0] + pl[1] * vel[1] + pl[2] * vel[2]))
        elif leaving == 1:
            # the ray left through the boundary before a: it was in e only within the margin's
            # tolerance (SHARED_FACE_TOL, a ray by the edge it shares with the element before)
            shift_b = a - b
        elif dv_b[3] < 0.0 and r_b[3] < geometry.INSIDE_TOL:
            shift_b = wp.max((geometry.INSIDE_TOL - r_b[3]) / dv_b[3], -0.5 * (b - a))
    shift_a = wp.min(shift_a, 0.5 * (b - a))
    if shift_a > 0.0:
        r_a = to_face(r_a, dv_a, shift_a)
    return wp.vec3(1.0, b, ex[1]), r_a, dv_a, r_b, dv_b, a + shift_a, b + shift_b, newton, work[2]


@wp.func
def entry_across(mesh: MeshArgs, e: int, f: int, n: int, xi_e: wp.vec3, o: wp.vec3, d: wp.vec3, t: float):
    """Curved element n's solution and velocity where the ray leaves e through face f at t into n
    (xi_e: the exit's point on the face in e's coordinates), as the walk's (r, dv) (r[3] <= 0:
    not found, and Newton at t from the vertex-affine guess locates it instead): the face's point
    in n's coordinates (adjacency.face_maps), checked and refined by one Newton step."""
    slot = e * MAX_FACES + f
    xi = mesh.face_map_a[slot] * xi_e + mesh.face_map_b[slot]
    x, J = geometry.local_geometry_with_jacobian(mesh, n, xi)
    r = wp.vec4(0.0, 0.0, 0.0, -1.0)
    dv = wp.vec4(0.0, 0.0, 0.0, 0.0)
    if wp.abs(wp.determinant(J)) > 1.0e-30:
        Jinv = wp.inverse(J)
        step = Jinv * (geometry.local_ray_point(mesh, n, o, d, t) - x)
        if wp.length(step) < SHARED_FACE_TOL:
            xi = xi + step
            r = crossing.solution_at_xi(mesh, n, xi)
            if geometry.margin_and_face(mesh.shape[n], xi)[0] <= -SHARED_FACE_TOL:
                r[3] = -1.0
            v = Jinv * d
            pl = element.face_plane(mesh.shape[n], int(geometry.margin_and_face(mesh.shape[n], xi)[1]))
            dv = wp.vec4(v[0], v[1], v[2], -(pl[0] * v[0] + pl[1] * v[1] + pl[2] * v[2]))
    return r, dv


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
    segs.flags[slot] = curved * SEG_CURVED + mesh.derived.active * SEG_INTERPOLANT
    segs.list[wp.atomic_add(segs.list_count, 0, 1)] = slot
    return deg + 1


@wp.func
def density_transparent(mesh: MeshArgs, tf: TransferArgs, e: int) -> int:
    """1 where the density is 0 over element e's whole certified range."""
    if quadrature.density_max_on(tf, mesh.field_lo[e], mesh.field_hi[e]) <= 0.0:
        return 1
    return 0


@wp.func
def element_transparent(mesh: MeshArgs, tf: TransferArgs, e: int) -> int:
    """1 where the density is 0 over element e's whole certified range and no surface needs
    the element (SurfaceArgs.keep): classified and split take no samples there (traverse) and
    integrate nothing (shade)."""
    if tf.surf.n_iso + tf.surf.n_planes > 0:
        if tf.surf.keep[e] == 1:
            return 0
    return density_transparent(mesh, tf, e)


@wp.func
def store_walk(rays: RayState, segs: Segments, i: int, pixel: int, finished: int, t: float, e: int, left: int,
               r_entry: wp.vec4, dv_entry: wp.vec4, n: int, n_field: int, n_seg: int, n_empty: int, n_walk: int,
               n_newton: int):
    """Where ray i's walk got this round (its n segments, the counters) into the ray state."""
    if finished == 1:
        rays.phase[i] = 1
    rays.t_cur[i] = t
    rays.next_element[i] = e
    rays.left_element[i] = left
    rays.entry_r[i] = r_entry
    rays.entry_dv[i] = dv_entry
    segs.count[i] = n
    rays.stats[pixel, STAT_FIELD_EVALS] += n_field
    rays.stats[pixel, STAT_SEGMENTS] += n_seg
    rays.stats[pixel, STAT_EMPTY] += n_empty
    rays.stats[pixel, STAT_WALKS] += n_walk
    rays.stats[pixel, STAT_NEWTON_WALK] += n_newton


def make_traverse_kernel(CURVED: bool):
    @wp.kernel(enable_backward=False, module="unique", module_options=walk_options(CURVED),
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
        if samples_segments(q.method) != 0:
            uses_restriction = 1
        n_field = int(0)
        n_seg = int(0)
        n_empty = int(0)
        n_walk = int(0)
        n_newton = int(0)
        n_cand = int(0)
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
                stretch = affine_walk_step(mesh, e, o, d, a, t_end, left)
            elif wp.static(CURVED):
                stretch, r_a, dv_a, r_b, dv_b, seg_a, seg_b, its, cands = curved_walk_step(mesh, e, o, d, a, t_end,
                                                                                           r_entry, dv_entry)
                n_newton += its
                n_cand += cands
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
                e = mesh.neighbour[e * MAX_FACES + face]
                if wp.static(CURVED):
                    # into a curved neighbour from a curved element: its solution from the exit's own
                    if e >= 0 and r_b[3] > 0.0 and mesh.affine[e] == 0:
                        r_entry, dv_entry = entry_across(mesh, left, face, e, wp.vec3(r_b[0], r_b[1], r_b[2]), o, d, t)
                        n_newton += 1
            else:
                e = -1
        store_walk(rays, segs, i, pixel, finished, t, e, left, r_entry, dv_entry, n, n_field, n_seg, n_empty, n_walk,
                   n_newton)
        rays.stats[pixel, STAT_BVH_CANDIDATES] += n_cand

    return traverse


def make_sample_kernel(CURVED: bool, MODES: int, DERIVED: bool):
    # MODES > 0: hexahedra and prisms of (MODES,) * 3 modes evaluate through the unrolled
    # element.static_evaluator (its loops need max_unroll >= MODES); DERIVED: samples of the
    # mesh's derived field (kernels/derived.py) from its components, exact at each point
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
        xi, w, dxi_dx, newton = restriction.sample_point(mesh, o, d, segs, slot, j, deg, curved)
        if wp.static(CURVED):
            if newton > 0:
                wp.atomic_add(stats, slot // SEGMENTS_PER_ROUND + pixel_offset, STAT_NEWTON_SAMPLE, newton)
        e = segs.element[slot]
        f = float(0.0)
        if wp.static(DERIVED):
            f = derived.sample_value(mesh, e, xi, dxi_dx)
        else:
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
    """One thread per sampled slot: an interpolant's (a curved slot's or a derived field's) tail
    is its error estimate; if it is too large (and allow is 1) the degree is doubled and the slot
    goes on the `again` list for the sample kernel's odd points."""
    idx = wp.tid()
    if idx >= count[0]:
        return
    slot = slots[idx]
    if (segs.flags[slot] & (SEG_CURVED | SEG_INTERPOLANT)) == 0:
        return
    if restriction.refine_degree(segs, slot, allow) == 1:
        again[wp.atomic_add(again_count, 0, 1)] = slot
        rays.stats[slot // SEGMENTS_PER_ROUND + pixel_offset, STAT_FIELD_EVALS] += segs.degree[slot] // 2
