"""The entry search (the search kernel): where a ray that is not inside a known element enters
the next one, from the BVH over element boxes.

Each BVH pass takes the smallest exact entry among affine candidates and gathers the WINDOW
curved candidates with the smallest box entries, then locates those in order while they can
still come first (geometry.curved_entry); a ray already inside a curved candidate (a walk that
stopped at a face without a neighbour) is found by one Newton solve each (inside_window). An
element entered through a face that has a neighbour was entered from that neighbour, so the
search's entry is walked back to where the ray really comes in (walk_back). Meshes of affine
elements get a search with the curved machinery compiled out.
"""
from __future__ import annotations

import warp as wp

from ..shapes import MAX_FACES
from . import geometry
from .args import STAT_BVH_CANDIDATES, STAT_LOCATES, STAT_NEWTON_SEARCH, CameraArgs, MeshArgs, RayState
from .rays import MAX_REGISTERS, affine_stretch, camera_ray, walk_options
from .tolerances import SHARED_FACE_TOL, STRETCH_RTOL

wp.set_module_options({"enable_backward": False})

WINDOW = 8  # curved candidates gathered per BVH pass of the entry search
LOCATED = 32  # curved candidates an entry search remembers having located
SEARCH_PASSES = 4
BACK_STEPS = 16  # elements walk_back may step back through before it keeps what it has

WindowKeys = wp.types.vector(length=WINDOW, dtype=wp.float32)
WindowElements = wp.types.vector(length=WINDOW, dtype=wp.int32)
LocatedElements = wp.types.vector(length=LOCATED, dtype=wp.int32)


@wp.func
def in_list(ids: wp.ref[LocatedElements], n: int, e: int) -> int:
    for k in range(n):
        if ids[k] == e:
            return 1
    return 0


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


def make_search_entry(CURVED: bool):
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
        n = mesh.neighbour[entry.element * MAX_FACES + entry_face(mesh, entry, o, d)]
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
