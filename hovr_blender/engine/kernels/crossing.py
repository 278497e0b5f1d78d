"""Where a ray crosses element faces (docs/traversal.md): the triangles of every element's faces
(engine/faces.py, each within the bound mesh.face_bound of its curved face) in a BVH of their boxes
grown by that bound, grouped by element (bvh_get_group_root: one element's own faces); a
triangle the ray passes within a few bounds of is a candidate, and the crossing itself is Newton
on the curved face in (u, v, t) started from the triangle's point (polish), one map evaluation
with its Jacobian a step, 2-4 steps from a start within the bound. An affine element's faces are
planar: its crossing is the exact clip (rays.affine_stretch), no Newton.

A crossing is an entry into its element where the ray's reference velocity points into the face
(n_f . dxi/dt < 0), else an exit; a shared face is stored once per side, so crossing it is an
exit from one element and an entry into the other at the same t.
"""
from __future__ import annotations

import warp as wp

from ..shapes import MAX_FACES
from . import element
from . import geometry
from .args import MeshArgs
from .tolerances import INSIDE_TOL, NEWTON_STEP_TOL, SHARED_FACE_TOL

wp.set_module_options({"enable_backward": False})

POLISH_ITERATIONS = 12  # Newton steps on a face at most (from within the bound: 2-4)
GRAZING_COS = 0.25  # every triangle whose box the ray crosses at a shallower angle than this (cosine) is a candidate
# ... and every other where the ray meets its plane within this many bounds of it: the curved face's
# crossing p lies within one bound of a point q of the triangle, so the ray meets the plane within
# the bound of q in the plane plus the bound times tan(angle) <= sqrt(1/GRAZING_COS^2 - 1) = 3.873
# beyond (tests/engine/test_entry_regressions.py checks the derivation)
NEAR_BOUNDS = 4.9
SLACK_BOUNDS = 8.0  # a candidate can polish to a crossing up to this many bounds before its triangle's t
WANT_ENTRY = 0  # next_crossing: entries only, exits only, or the first crossing either way
WANT_EXIT = 1
WANT_ANY = 2
NEAR_EDGE = 2  # polish's `ok`: converged on the face's surface just beyond an edge (within SHARED_FACE_TOL)
STALLED = -2  # next_crossing's skip: every crossing at or before t_from + eps (a ray searching again where it was)


@wp.struct
class Crossing:
    """A ray's crossing of an element face."""

    element: wp.int32  # -1: none
    face: wp.int32
    t: wp.float32
    xi: wp.vec3  # the element's reference point there (on the face)
    v: wp.vec3  # dxi/dt there (the reference velocity)
    t_tri: wp.float32  # the candidate triangle's t it was polished from
    enters: wp.int32  # 1: an entry into the element, 0: an exit
    # next_crossing's: the first crossing of the other kind than wanted it met beyond t_from (an
    # entry, asked for an exit: the ray left the element before it, however its polishes ran)
    t_other: wp.float32


@wp.func
def no_crossing(t: float) -> Crossing:
    c = Crossing()
    c.element = -1
    c.face = -1
    c.t = t
    c.xi = wp.vec3(0.0, 0.0, 0.0)
    c.v = wp.vec3(0.0, 0.0, 0.0)
    c.t_tri = t
    c.enters = 0
    c.t_other = 1.0e30
    return c


@wp.func
def triangle_candidate(mesh: MeshArgs, tri: int, o: wp.vec3, d: wp.vec3) -> wp.vec4:
    """(keep, t, 1 + cosine, span) of the ray against triangle `tri`: its plane's t, and keep 1 where
    the ray meets the plane within NEAR_BOUNDS bounds of the triangle or grazes it (|cos| <
    GRAZING_COS), where t is the middle of the triangle's extent along the ray and span its half
    (the crossings lie within t +- span); the cosine between d and the triangle's outward normal
    (> 0: leaving its element)."""
    ids = mesh.face_tris[tri]
    p0 = mesh.face_points[ids[0]]
    e1 = mesh.face_points[ids[1]] - p0
    e2 = mesh.face_points[ids[2]] - p0
    n = wp.cross(e1, e2)
    nn = wp.length(n)
    if nn <= 0.0:
        return wp.vec4(0.0, 0.0, 0.0, 0.0)
    n = n / nn
    cosine = wp.dot(d, n)
    if wp.abs(cosine) < GRAZING_COS:
        # grazing: the plane's t is no guide; the middle of the triangle's extent along the ray
        # and half that extent (grown by the bound): the face may be crossed anywhere in it
        t0 = wp.dot(p0 - o, d)
        t1 = t0 + wp.dot(e1, d)
        t2 = t0 + wp.dot(e2, d)
        lo = wp.min(t0, wp.min(t1, t2))
        hi = wp.max(t0, wp.max(t1, t2))
        return wp.vec4(1.0, 0.5 * (lo + hi), 1.0 + cosine, 0.5 * (hi - lo) + mesh.face_bound)
    t = wp.dot(p0 - o, n) / cosine
    p = o + t * d - p0
    # distance outside each edge, in the plane
    reach = NEAR_BOUNDS * mesh.face_bound
    keep = float(1.0)
    q0 = wp.cross(n, e1)  # inward normals of the edges p0-p1, p1-p2, p2-p0 (counter-clockwise about n)
    if wp.dot(p, q0) < -reach * wp.length(q0):
        keep = 0.0
    e3 = e2 - e1
    q1 = wp.cross(n, e3)
    if wp.dot(p - e1, q1) < -reach * wp.length(q1):
        keep = 0.0
    q2 = wp.cross(e2, n)
    if wp.dot(p, q2) < -reach * wp.length(q2):
        keep = 0.0
    return wp.vec4(keep, t, 1.0 + cosine, 0.0)


@wp.func
def triangle_start(mesh: MeshArgs, tri: int, o: wp.vec3, d: wp.vec3, t: float) -> wp.vec3:
    """The reference point of the triangle's point nearest o + t d (its barycentric point, clamped
    to the triangle): Newton's start on the face."""
    ids = mesh.face_tris[tri]
    p0 = mesh.face_points[ids[0]]
    e1 = mesh.face_points[ids[1]] - p0
    e2 = mesh.face_points[ids[2]] - p0
    p = o + t * d - p0
    d11 = wp.dot(e1, e1)
    d12 = wp.dot(e1, e2)
    d22 = wp.dot(e2, e2)
    det = d11 * d22 - d12 * d12
    b1 = float(1.0 / 3.0)
    b2 = float(1.0 / 3.0)
    if det > 0.0:
        r1 = wp.dot(p, e1)
        r2 = wp.dot(p, e2)
        b1 = wp.clamp((d22 * r1 - d12 * r2) / det, 0.0, 1.0)
        b2 = wp.clamp((d11 * r2 - d12 * r1) / det, 0.0, 1.0 - b1)
    x0 = mesh.face_xi[ids[0]]
    return x0 + b1 * (mesh.face_xi[ids[1]] - x0) + b2 * (mesh.face_xi[ids[2]] - x0)


@wp.func
def polish(mesh: MeshArgs, e: int, f: int, o: wp.vec3, d: wp.vec3, xi_start: wp.vec3, t_start: float):
    """Newton on (u, v, t) for x(xi(u, v)) = o + t d with xi(u, v) on reference face f of curved
    element e, from xi_start (on the face) and t_start: (xi, t, ok: 1 converged within the face,
    NEAR_EDGE converged just beyond one of its edges, 0 not), the reference velocity dxi/dt there
    and the iterations (each a map evaluation with its Jacobian).
    Beyond an edge where the map folds no point has a usable preimage, but the face itself is a
    regular patch."""
    shape = mesh.shape[e]
    pl = element.face_plane(shape, f)
    n = wp.vec3(pl[0], pl[1], pl[2])
    axis = wp.vec3(1.0, 0.0, 0.0)
    if wp.abs(n[0]) > 0.5 * wp.length(n):
        axis = wp.vec3(0.0, 1.0, 0.0)
    a = wp.normalize(wp.cross(n, axis))
    b = wp.normalize(wp.cross(n, a))
    # the start moved onto the face's plane exactly
    xs = xi_start + ((pl[3] - wp.dot(n, xi_start)) / wp.dot(n, n)) * n
    u = float(0.0)
    v = float(0.0)
    # in the element's own frame, t_start + dt along the ray (geometry.local_ray_point)
    p0 = geometry.local_ray_point(mesh, e, o, d, t_start)
    dt = float(0.0)
    ok = int(0)
    its = int(0)
    J = wp.identity(n=3, dtype=float)
    xi = xs
    for it in range(POLISH_ITERATIONS):
        its += 1
        xi = xs + u * a + v * b
        x, Jx = geometry.local_geometry_with_jacobian(mesh, e, xi)
        J = Jx
        ca = J * a
        cb = J * b
        M = wp.mat33(ca[0], cb[0], -d[0], ca[1], cb[1], -d[1], ca[2], cb[2], -d[2])
        if wp.abs(wp.determinant(M)) < 1.0e-30:
            break
        Minv = wp.inverse(M)
        s = Minv * (x - p0 - dt * d)
        u = wp.clamp(u - s[0], -3.0, 3.0)
        v = wp.clamp(v - s[1], -3.0, 3.0)
        dt = dt - s[2]
        step = wp.length(s)
        mn = float(0.0)  # |M^-1| (rows' sums): how far the rounding of x moves (u, v, t)
        for r in range(3):
            mn = wp.max(mn, wp.abs(Minv[r, 0]) + wp.abs(Minv[r, 1]) + wp.abs(Minv[r, 2]))
        converged = int(0)
        if step < NEWTON_STEP_TOL:
            converged = 1
        elif step < geometry.NEWTON_NOISE_MAX and step < mn * mesh.geo_err[e]:
            # a step within the map's rounding floor is as converged as it gets (geometry.solved_margin)
            converged = 2
        if ok == 1:
            xi = xs + u * a + v * b
            break
        if converged == 1:
            xi = xs + u * a + v * b
            ok = 1
            break
        if converged == 2:
            # one more step on the rounding floor (a face by a degenerate edge, a map whose
            # coefficients cancel): its steps are the rounding's, and the last one is as good a
            # sample of it as the first that met the floor
            ok = 1
    t = t_start + dt
    vel = wp.vec3(0.0, 0.0, 0.0)
    if ok == 1:
        # within the face: inside every other face's plane (by an edge, within SHARED_FACE_TOL: NEAR_EDGE)
        off = float(0.0)
        for g in range(element.num_faces(shape)):
            q = element.face_plane(shape, g)
            if g != f:
                off = wp.max(off, (q[0] * xi[0] + q[1] * xi[1] + q[2] * xi[2]) - q[3])
        if off > SHARED_FACE_TOL:
            ok = 0
        elif off > INSIDE_TOL:
            ok = NEAR_EDGE
        if wp.abs(wp.determinant(J)) > 1.0e-30:
            vel = wp.inverse(J) * d
        else:
            ok = 0
    return xi, t, ok, vel, its


@wp.func
def entering(mesh: MeshArgs, e: int, f: int, vel: wp.vec3) -> int:
    """1 where the reference velocity vel at a point of face f of e points into the element."""
    pl = element.face_plane(mesh.shape[e], f)
    if pl[0] * vel[0] + pl[1] * vel[1] + pl[2] * vel[2] < 0.0:
        return 1
    return 0


@wp.func
def allowed(e: int, t: float, skip: int, t_from: float, eps: float) -> int:
    """0 for a crossing of element `skip` at or before t_from + eps (every element's, skip STALLED)."""
    if t > t_from + eps:
        return 1
    if skip == STALLED or e == skip:
        return 0
    return 1


PASSED_MAX = 8  # elements a search may set aside at its start (the elements that meet at a vertex)
PassedSet = wp.types.vector(length=PASSED_MAX, dtype=wp.int32)


@wp.func
def no_passed() -> PassedSet:
    """The empty set of elements set aside."""
    return PassedSet(-1, -1, -1, -1, -1, -1, -1, -1)


@wp.func
def passed_at(e: int, t: float, passed: PassedSet, t_from: float, eps: float) -> int:
    """1 for a crossing at or before t_from + eps of an element in `passed` (-1: an empty place):
    elements the search has set aside there (left again by t_from: a sliver by an edge; touched
    at a vertex or an edge only)."""
    if t > t_from + eps:
        return 0
    for k in range(PASSED_MAX):
        if passed[k] == e:
            return 1
    return 0


@wp.func
def next_crossing(mesh: MeshArgs, root: int, o: wp.vec3, d: wp.vec3, t_from: float, t_to: float, eps: float,
                  want: int, skip: int, passed: PassedSet):
    """The first crossing beyond t_from (less eps; an entry less the bound) and before t_to of a curved element's face
    among the triangles under `root` (-1: all; a group root: one element's faces): entries (want
    WANT_ENTRY), exits (WANT_EXIT) or either (WANT_ANY: at one t an entry comes before an exit),
    none of element `skip`'s crossings at or before t_from + eps (allowed), nor those of the
    elements in `passed` (passed_at; -1: none); and the work: (polishes, Newton
    iterations, candidates). Affine elements are left out (their crossings are their clips: the
    callers')."""
    slack = SLACK_BOUNDS * mesh.face_bound
    q0 = t_from - eps - slack
    best = no_crossing(t_to)
    polishes = int(0)
    newton = int(0)
    n_cand = int(0)
    query = wp.bvh_query_ray(mesh.bvh, o + q0 * d, d, root)
    tri = int(0)
    # the query's reach may only shrink (Warp never revisits a subtree it has cut)
    reach = float(1.0e30)
    while wp.bvh_query_next(query, tri, reach):
        reach = wp.min(reach, best.t + slack - q0)
        n_cand += 1
        owner = mesh.face_owner[tri]
        e = owner // MAX_FACES
        if mesh.affine[e] == 1:
            continue
        f = owner - e * MAX_FACES
        cand = triangle_candidate(mesh, tri, o, d)
        if cand[0] == 0.0:
            continue
        cosine = cand[2] - 1.0
        # clearly the other way through the face (the triangle's normal is within ~0.1 rad of the face's)
        if want == WANT_EXIT and cosine < -GRAZING_COS:
            continue
        if want == WANT_ENTRY and cosine > GRAZING_COS:
            continue
        t_tri = cand[1]
        span = cand[3]
        if t_tri - span > best.t + slack or t_tri + span < q0:
            continue
        grazing = int(0)
        if wp.abs(cosine) < GRAZING_COS:
            grazing = 1
            # polished from its point at the query's start, where the triangle reaches back that far
            t_tri = wp.max(t_tri - span, wp.min(t_tri + span, t_from))
        # the same face near the same t as the best so far polishes to the same crossing, unless
        # the ray grazes it (it crosses a curved face twice there, close together)
        if grazing == 0 and best.element == e and best.face == f and wp.abs(t_tri - best.t_tri) < slack:
            continue
        start = triangle_start(mesh, tri, o, d, t_tri)
        t_start = t_tri
        for attempt in range(2):
            xi, t, ok, vel, its = polish(mesh, e, f, o, d, start, t_start)
            polishes += 1
            newton += its
            if ok != 1:
                break
            enters = entering(mesh, e, f, vel)
            across = mesh.neighbour[e * MAX_FACES + f]  # the element on the face's other side
            # one crossing: within eps, or a shared face's two sides (each element's map fits the
            # face on its own: their t differ by that fit, 1e-8 of the chord on the curved cube)
            tie = int(0)
            if best.element >= 0:
                if wp.abs(t - best.t) <= eps:
                    tie = 1
                elif across == best.element and wp.abs(t - best.t) <= slack:
                    # only the face they share: best's face must lead back to e
                    if mesh.neighbour[best.element * MAX_FACES + best.face] == e:
                        tie = 1
            # at one crossing: at the start the ray goes on into the element entered there;
            # beyond it, it was inside the element that it leaves there
            first = int(0)
            if t > best.t + slack:
                first = 0
            elif tie == 0 or enters == best.enters:
                if t < best.t:
                    first = 1
            else:
                at_start = int(0)
                if t <= t_from + eps:
                    at_start = 1
                if enters == at_start:
                    first = 1
            if want == WANT_ENTRY and enters == 0:
                first = 0
                if t > t_from + eps:
                    best.t_other = wp.min(best.t_other, t)
            if want == WANT_EXIT and enters == 1:
                first = 0
                if t > t_from + eps:
                    best.t_other = wp.min(best.t_other, t)
            # an element entered before t_from (the other side of a non-conforming face, whose
            # surface differs by the maps' fit) is found by its exit beyond t_from (the caller's)
            # ... but the entry from the element just left, through their shared face, is at t_from
            lower = t_from - eps
            if enters == 1 and skip >= 0 and across == skip:
                lower = t_from - slack
            if first == 1 and t >= lower and allowed(e, t, skip, t_from, eps) == 1 and passed_at(e, t, passed, t_from, eps) == 0:
                best.element = e
                best.face = f
                best.t = wp.max(t, wp.min(t_from, t + slack))
                best.xi = xi
                best.v = vel
                best.t_tri = t_tri
                best.enters = enters
            if grazing == 0:
                break
            # a grazing ray crosses a curved face twice, close together, often between the triangles
            # and the face: Newton may have found either; the other lies beyond the start, mirrored
            start = 2.0 * start - xi
            t_start = 2.0 * t_start - t
    return best, wp.vec3i(polishes, newton, n_cand)


@wp.func
def solution_at_xi(mesh: MeshArgs, e: int, xi: wp.vec3) -> wp.vec4:
    """The walk's record of a point xi on a face of element e: (xi, margin + INSIDE_TOL)
    (geometry.curved_inside's convention), the margin held above 0 (the point is on the face)."""
    m = geometry.margin_and_face(mesh.shape[e], xi)
    return wp.vec4(xi[0], xi[1], xi[2], wp.max(m[0] + INSIDE_TOL, 0.5 * INSIDE_TOL))


@wp.func
def solution_at(mesh: MeshArgs, c: Crossing) -> wp.vec4:
    """solution_at_xi of a crossing."""
    return solution_at_xi(mesh, c.element, c.xi)


@wp.func
def velocity_at(mesh: MeshArgs, c: Crossing) -> wp.vec4:
    """(dxi/dt, dmargin/dt) at a crossing (the margin's nearest face)."""
    sh = mesh.shape[c.element]
    m = geometry.margin_and_face(sh, c.xi)
    pl = element.face_plane(sh, int(m[1]))
    return wp.vec4(c.v[0], c.v[1], c.v[2], -(pl[0] * c.v[0] + pl[1] * c.v[1] + pl[2] * c.v[2]))
