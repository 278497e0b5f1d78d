"""The entry (the search kernel): where a ray that is not inside a known element enters the next
one, by face crossing (kernels/crossing.py; docs/traversal.md).

The first crossing beyond t that enters an element is the entry: a ray query against the
triangles of every element face, the candidates polished by Newton on their curved face. The
element just left (the walk stopped at a face without a neighbour) is not entered again at its
own exit. A ray's first search also looks behind its start (the reversed ray's first exit, that
is the last entry before it): a camera inside the domain, or a clip plane through it, starts
inside that element. Affine elements are entered at their exact clip (rays.affine_stretch), as
every BVH candidate of theirs offers. Meshes of affine elements get a search with the curved
machinery compiled out.
"""
from __future__ import annotations

import warp as wp

from ..shapes import MAX_FACES
from . import crossing
from . import element
from . import geometry
from .args import STAT_BVH_CANDIDATES, STAT_LOCATES, STAT_NEWTON_SEARCH, CameraArgs, MeshArgs, RayState
from .rays import MAX_REGISTERS, affine_stretch, camera_ray, walk_options
from .tolerances import INSIDE_TOL, STRETCH_RTOL

wp.set_module_options({"enable_backward": False})

BACK_STEPS = 4  # elements an entry may be moved back through (shared faces) to one the triangles missed
SEARCH_ATTEMPTS = 8  # crossing queries of one search (an exit, an entry before t_from or a passed sliver found first: on past it)
UNDECIDED = -2  # Entry.element: the search set aside every crossing it met; the next round searches on from Entry.t


@wp.func
def set_aside(passed: crossing.PassedSet, n: int, e: int):
    """`passed` with element e added (while there is room) and its count."""
    out = passed
    if n < crossing.PASSED_MAX:
        out[n] = e
        return out, n + 1
    return out, n


@wp.struct
class Entry:
    """Where a ray enters an element."""

    element: wp.int32  # -1: none
    t: wp.float32
    r: wp.vec4  # curved: the solution at t (xi, margin + INSIDE_TOL; r[3] > 0: valid)
    dv: wp.vec4  # ... and the velocity there (dxi/dt, dmargin/dt)


@wp.func
def no_entry(t_end: float) -> Entry:
    """No element before t_end."""
    entry = Entry()
    entry.element = -1
    entry.t = t_end
    entry.r = wp.vec4(0.0, 0.0, 0.0, -1.0)
    entry.dv = wp.vec4(0.0, 0.0, 0.0, 0.0)
    return entry


@wp.func
def affine_entry(mesh: MeshArgs, o: wp.vec3, d: wp.vec3, t_from: float, t_end: float, eps: float, skip: int,
                 work_in: wp.vec3i):
    """The affine element whose exact stretch starts first beyond t_from and reaches past t_from + eps,
    among the owners of the triangles whose boxes the ray crosses (every element the ray meets has
    one on its way out), none starting at or before t_from + eps if skip is crossing.STALLED, as
    an Entry; work counted on (candidates)."""
    # the element holding t_from may have all its faces beyond t_end: the query is not bounded by it
    best = no_entry(1.0e30)
    work = work_in
    q0 = t_from - eps
    query = wp.bvh_query_ray(mesh.bvh, o + q0 * d, d, -1)
    tri = int(0)
    while wp.bvh_query_next(query, tri, best.t - q0):
        work[2] += 1
        e = mesh.face_owner[tri] // MAX_FACES
        if mesh.affine[e] == 1:
            cl = affine_stretch(mesh, e, o, d)
            a0 = wp.max(cl[1], t_from)
            b0 = wp.min(cl[2], t_end)
            if cl[0] > 0.0 and b0 > t_from + eps and a0 < best.t and crossing.allowed(e, a0, skip, t_from, eps) == 1:
                best.element = e
                best.t = a0
    if best.t >= t_end:
        best = no_entry(t_end)
    return best, work


@wp.func
def curved_start(mesh: MeshArgs, o: wp.vec3, d: wp.vec3, t_from: float, eps: float, work_in: wp.vec3i):
    """The curved element holding the ray's start t_from, if any (Entry, element -1: none): the
    last entry behind it (the reversed ray's first exit), checked by Newton at t_from (the last
    crossing behind may be the domain's exit, and an entry behind it one of an element left since)."""
    found = no_entry(t_from)
    work = work_in
    back, w = crossing.next_crossing(mesh, -1, o, -d, -t_from, 1.0e30, eps, crossing.WANT_EXIT, -1, crossing.no_passed())
    work += w
    if back.element < 0:
        return found, work
    e = back.element
    t_back = -back.t
    r = crossing.solution_at(mesh, back)
    dv = crossing.velocity_at(mesh, back)
    dv = -dv  # the reversed ray's velocity: the forward one
    if t_back < t_from - eps:
        y = wp.vec3(back.xi[0], back.xi[1], back.xi[2]) + (t_from - t_back) * wp.vec3(dv[0], dv[1], dv[2])
        for k in range(3):
            y[k] = wp.clamp(y[k], -1.5, 1.5)
        r_in, dv_in, its = geometry.curved_inside(mesh, e, o, d, t_from, y)
        work[0] += 1
        work[1] += its
        if r_in[3] <= 0.0:
            return found, work
        r = r_in
        dv = dv_in
    found.element = e
    found.t = t_from
    found.r = r
    found.dv = dv
    return found, work


@wp.func
def missed_entry(mesh: MeshArgs, o: wp.vec3, d: wp.vec3, eps: float, exit: crossing.Crossing):
    """Where the ray entered the element it leaves at `exit`, as a Crossing (element -1: none), and
    the work: the later of the reversed ray's first exit from the element beyond the exit, among
    the element's own triangles (its group in the BVH; a grazing ray's entry through the face it
    leaves by too), and the last entry among the crossings of the element's other faces, each
    polished from the exit's point (a thin re-entry after a dip outside, whose triangles'
    starts polish to the crossing before the dip); failing both, the walk's own exit search
    (geometry.curved_exit) along the reversed ray from just inside the exit. It may lie before the search's start: a
    walk's exit is a bracket on the margin, so the face it crossed and the next element's entry
    differ by its rounding, and more where the ray passes by an edge."""
    e = exit.element
    back, work = crossing.next_crossing(mesh, wp.bvh_get_group_root(mesh.bvh, e), o, -d, -exit.t, 1.0e30, eps,
                                        crossing.WANT_EXIT, -1, crossing.no_passed())
    found = crossing.no_crossing(-1.0e30)
    if back.element == e and -back.t <= exit.t + eps:
        found.element = e
        found.face = back.face
        found.t = -back.t
        found.xi = back.xi
        found.v = -back.v
        found.enters = 1
    polishes = work[0]
    newton = work[1]
    for g in range(element.num_faces(mesh.shape[e])):
        if g != exit.face:
            xi, t, ok, vel, its = crossing.polish(mesh, e, g, o, d, exit.xi, exit.t)
            polishes += 1
            newton += its
            if ok == 1 and t > found.t and t <= exit.t and crossing.entering(mesh, e, g, vel) == 1:
                found.element = e
                found.face = g
                found.t = t
                found.xi = xi
                found.v = vel
                found.enters = 1
    if found.element < 0:
        # the ray is inside e just before its exit: the walk's own exit search along the reversed
        # ray finds where it came in (a grazing clip entering and leaving by one face: both its
        # triangles' polishes, and the mirrored ones, converge to the exit)
        back_r = crossing.solution_at(mesh, exit)
        back_dv = -crossing.velocity_at(mesh, exit)
        span = geometry.box_interval(mesh, e, o, -d)
        ex, r_b, dv_b, its_b = geometry.curved_exit(mesh, e, o, -d, -exit.t, back_r, back_dv, span[1])
        polishes += 1
        newton += its_b
        if ex[1] >= 0.0 and -ex[0] < exit.t:
            found.element = e
            found.face = int(ex[1])
            found.t = -ex[0]
            found.xi = wp.vec3(r_b[0], r_b[1], r_b[2])
            found.v = -wp.vec3(dv_b[0], dv_b[1], dv_b[2])
            found.enters = 1
            # the bracket's end lies in the band outside the face: the crossing itself, polished from it
            xi, t, ok, vel, its = crossing.polish(mesh, e, found.face, o, d, found.xi, found.t)
            polishes += 1
            newton += its
            if ok == 1 and t < exit.t and crossing.entering(mesh, e, found.face, vel) == 1:
                found.t = t
                found.xi = xi
                found.v = vel
    return found, wp.vec3i(polishes, newton, work[2])


@wp.func
def shared_exit(mesh: MeshArgs, n: int, c: crossing.Crossing, o: wp.vec3, d: wp.vec3):
    """Curved element n's exit where the ray enters c.element from it at c.t (the face they share),
    polished on n's side from n's straight-sided guess (a Crossing, element -1: not found), and the
    Newton iterations."""
    found = crossing.no_crossing(c.t)
    g = int(-1)
    for f in range(element.num_faces(mesh.shape[n])):
        if mesh.neighbour[n * MAX_FACES + f] == c.element:
            g = f
    if g < 0:
        return found, 0
    xi, t, ok, vel, its = crossing.polish(mesh, n, g, o, d, geometry.start_guess(mesh, n, o + c.t * d), c.t)
    # the two sides' t differ by the fit of each element's map to the face
    if ok == 1 and wp.abs(t - c.t) <= crossing.SLACK_BOUNDS * mesh.face_bound and crossing.entering(mesh, n, g, vel) == 0:
        found.element = n
        found.face = g
        found.t = c.t
        found.xi = xi
        found.v = vel
    return found, its


@wp.func
def first_entry(mesh: MeshArgs, o: wp.vec3, d: wp.vec3, t_from: float, t_to: float, t_query: float, eps: float,
                skip_in: int):
    """The first entry into a curved element beyond t_from (before t_to; none of element skip_in's at
    t_from, crossing.allowed) as a Crossing (element -1: none), the solution and velocity there (at
    t_from where it entered before), and the work. The first crossing may be an exit, or an entry
    through a shared face: the ray was inside that element, or the one beyond, before it (a grazing
    clip the triangles did not show), and the entry is moved back to where it came in. Crossings
    are looked for up to t_query, beyond t_to: a ray inside an element at t_from whose entry the
    triangles put just before t_from (by an edge) is found by its exit, which can lie beyond t_to
    (a clip plane, an opaque surface)."""
    t_q = t_from
    skip = skip_in
    c = crossing.no_crossing(t_to)
    r = wp.vec4(0.0, 0.0, 0.0, -1.0)
    dv = wp.vec4(0.0, 0.0, 0.0, 0.0)
    work = wp.vec3i(0, 0, 0)
    passed = crossing.no_passed()
    n_passed = int(0)
    for attempt in range(SEARCH_ATTEMPTS):
        c, w = crossing.next_crossing(mesh, -1, o, d, t_q, t_query, eps, crossing.WANT_ANY, skip, passed)
        work += w
        if c.element < 0 or (c.enters == 1 and c.t >= t_to):
            return crossing.no_crossing(t_to), r, dv, work
        exit_first = int(0)
        if c.enters == 0:
            # an exit first: where did the ray come into that element?
            exit_first = 1
            e_out = c.element
            t_out = c.t
            c, w = missed_entry(mesh, o, d, eps, c)
            work += w
            if c.element >= 0 and c.t >= t_to:
                return crossing.no_crossing(t_to), r, dv, work
            # (a stalled search takes it: the ray is inside it beyond t_from, up to its exit)
            if c.element < 0 or (skip != crossing.STALLED and crossing.allowed(c.element, c.t, skip, t_q, eps) == 0):
                t_q = t_out  # not found (touched at a vertex or an edge): on from that exit, without it
                passed, n_passed = set_aside(passed, n_passed, e_out)
                if t_q > t_from + eps:
                    skip = -1  # skip_in holds at t_from only: beyond it, the element left is met again
                c = crossing.no_crossing(t_to)
                continue
        # an entry through a shared face was an exit from the element beyond it first
        for k in range(BACK_STEPS):
            if c.t <= t_q + eps:
                break
            n = mesh.neighbour[c.element * MAX_FACES + c.face]
            if n < 0 or mesh.affine[n] == 1:
                break
            out, its = shared_exit(mesh, n, c, o, d)
            work[0] += 1
            work[1] += its
            if out.element < 0:
                break
            prev, w2 = missed_entry(mesh, o, d, eps, out)
            work += w2
            if prev.element < 0 or crossing.allowed(n, prev.t, skip, t_q, eps) == 0:
                break
            c = prev
        if c.t <= t_q + eps:
            # entered at the search's start, perhaps before it (by an edge, the ray crosses slivers of
            # several elements within eps): taken only where its own exit lies beyond the start
            out, w3 = crossing.next_crossing(mesh, wp.bvh_get_group_root(mesh.bvh, c.element), o, d, c.t, 1.0e30, eps,
                                             crossing.WANT_EXIT, -1, crossing.no_passed())
            work += w3
            if out.element == c.element and out.t <= t_q + eps:
                passed, n_passed = set_aside(passed, n_passed, c.element)
                c = crossing.no_crossing(t_to)
                continue
        r = crossing.solution_at(mesh, c)
        dv = crossing.velocity_at(mesh, c)
        if c.t >= t_from - eps:
            return c, r, dv, work
        # entered before t_from: inside at t_from? Where its exit beyond t_from was the first
        # crossing the ray meets it is, between the two; Newton then only refines the point
        y = c.xi + (t_from - c.t) * wp.vec3(dv[0], dv[1], dv[2])
        r_in, dv_in, its = geometry.curved_inside(mesh, c.element, o, d, t_from, y)
        work[0] += 1
        work[1] += its
        if r_in[3] > 0.0:
            return c, r_in, dv_in, work
        if exit_first == 1:
            r = wp.vec4(y[0], y[1], y[2], 0.5 * INSIDE_TOL)
            return c, r, dv, work
        passed, n_passed = set_aside(passed, n_passed, c.element)  # its stretch ended before t_from: on without it
        c = crossing.no_crossing(t_to)
    # every crossing met was set aside: undecided, the next round searches on from t_q
    c = crossing.no_crossing(t_q)
    c.element = UNDECIDED
    return c, r, dv, work


def make_search_entry(CURVED: bool):
    @wp.func
    def search_entry(mesh: MeshArgs, o: wp.vec3, d: wp.vec3, t_from: float, t_end: float, left: int, stalled: int):
        """The element the ray is in or enters first beyond t_from (an Entry, element -1: none before
        t_end; UNDECIDED: search again from its t) and the work: (polishes and locations, Newton iterations, BVH candidates). `left`:
        the element the ray has just left (-1: the ray's first search, which looks behind its start),
        not entered again at t_from; `stalled` 1: the ray searches again where its last search was
        (its walk made no progress), so no element is entered at t_from."""
        eps = STRETCH_RTOL * wp.abs(t_from)
        work = wp.vec3i(0, 0, 0)
        best = no_entry(t_end)
        skip = left
        if stalled == 1:
            skip = crossing.STALLED
        if mesh.has_affine == 1:
            best, work = affine_entry(mesh, o, d, t_from, t_end, eps, skip, work)
        if wp.static(CURVED):
            if left < 0 and stalled == 0 and best.t > t_from:
                start, work = curved_start(mesh, o, d, t_from, eps, work)
                if start.element >= 0:
                    return start, work
            # beyond an affine entry no curved element can hold the ray
            t_query = float(1.0e30)
            if best.element >= 0:
                t_query = best.t
            c, r, dv, w = first_entry(mesh, o, d, t_from, best.t, t_query, eps, skip)
            work += w
            if c.element >= 0:
                best.element = c.element
                best.t = wp.max(c.t, t_from)
                best.r = r
                best.dv = dv
            elif c.element == UNDECIDED and c.t < best.t - eps:
                # undecided within eps of an affine entry: every crossing set aside lies at the
                # entry (a ray through a vertex, float32), and no element holds the ray between
                # them beyond the stretch tolerance; searching on from there would count as a
                # stall, which enters nothing at its start, and the affine element would be lost
                best.element = UNDECIDED
                best.t = wp.max(c.t, t_from)
        return best, work

    return search_entry


def make_search_kernel(CURVED: bool):
    search_entry = make_search_entry(CURVED)

    @wp.kernel(enable_backward=False, module="unique", module_options=walk_options(CURVED),
               cuda_max_registers=MAX_REGISTERS)
    def search(mesh: MeshArgs, cam: CameraArgs, pixel_offset: wp.int32, rays: RayState):
        i = rays.active[wp.tid()]
        if rays.phase[i] != 0 or rays.next_element[i] >= 0:
            return
        pixel = i + pixel_offset
        o, d = camera_ray(cam, pixel)
        # a search again where the last one was: the walk from its entry made no progress
        stalled = int(0)
        if rays.t_cur[i] <= rays.t_search[i]:
            stalled = 1
        rays.t_search[i] = rays.t_cur[i]
        entry, work = search_entry(mesh, o, d, rays.t_cur[i], rays.t_end[i], rays.left_element[i], stalled)
        rays.stats[pixel, STAT_LOCATES] += work[0]
        rays.stats[pixel, STAT_NEWTON_SEARCH] += work[1]
        rays.stats[pixel, STAT_BVH_CANDIDATES] += work[2]
        if entry.element == UNDECIDED:
            rays.t_cur[i] = wp.max(rays.t_cur[i], entry.t)  # searched again next round, from there
        elif entry.element < 0:
            rays.phase[i] = 1
        else:
            rays.next_element[i] = entry.element
            rays.t_cur[i] = wp.max(rays.t_cur[i], entry.t)
            rays.entry_r[i] = entry.r
            rays.entry_dv[i] = entry.dv

    return search
