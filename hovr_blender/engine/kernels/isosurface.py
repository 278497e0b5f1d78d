"""Isosurfaces and cut planes met along one element segment (render contract §7).

A segment's field is its Chebyshev series g(s), s in [-1, 1] over [t0, t1], with f = g / w^2
(w linear along the ray: 1 but on pyramids; restriction.py). f = c where

    p(s) = g(s) - c w(s)^2 = 0,

a polynomial of degree max(deg, 2) whose series is the segment's with c w^2 taken from its first
three coefficients. Its roots in [-1, 1) are isolated by bisection: each interval [u, v] looked
at gets p's own series there (local_series: p at its Chebyshev-Lobatto points, transformed), and
a series q bounds itself, |q - q_0| <= sum_k>0 |q_k|. An interval whose series keeps its sign
has no root; one whose derivative's series keeps its sign holds one root at most, where the
ends' signs differ; one whose second derivative's keeps its sign holds at most two, on either
side of p's one extremum, found as the root of p' first: an extremum within the series' own
rounding of 0 (the ray touching the surface inside the segment) is one root, where sign tests at
samples would miss it; beyond that rounding the pair is two roots, each at its own place. Other
intervals are halved, left half first, so the roots come out in increasing order. Roots are
polished by safeguarded Newton inside their bracket to a few ulps of s.

The segments of a ray abut only to the traversal's rounding (a gap or an overlap of up to
STRETCH_RTOL where the next element was found by a search), and two abutting series' ends agree
only to their rounding. So the sign tests at a segment's start take the sign of f - c at the end
of the ray's previous segment where this one runs on from it (segment_events): a crossing between
the two ends is met once, at this segment's start, and one met at the previous end is not met
again. Near tangency the precision decides whether a ray meets the surface only within a band
(docs/methods.md "Near tangency", contract §7; audit/isosurface_band.py checks it).

On affine elements the series is the field itself (exact to rounding), so these are the exact
crossings. On curved ones it interpolates the field (its tail below restriction's
CURVED_TAIL_RTOL): each root is then corrected by a Newton step on the field itself at the
point located in the element (geometry.invert_point), with the exact gradient.

The surface's normal is grad f / |grad f|, grad f = J^-T grad_xi f: the reference gradient from
its own expansion (SurfaceArgs.grad, exact where the element's space holds the derivatives of its
polynomials: hexahedra, prisms, tetrahedra) and J^-1 the map's (affine: MeshArgs.ref_a; curved:
Newton's). A plane takes the transfer function's colour of the field at the point it cuts the
ray, evaluated there in its element.
"""
from __future__ import annotations

import warp as wp

from . import derived
from . import element
from . import geometry
from .args import MAX_SAMPLES, NO_SURFACE_END, MeshArgs, SurfaceArgs, TransferArgs
from .quadrature import RayIntegral, ramp_segment, tf_color
from .restriction import series_weights
# ROOT_EPS: the arithmetic's epsilon (rounding of a series' value, Newton's stop); STRETCH_RTOL: the
# traversal's rounding of where a segment ends and the next begins
from .tolerances import ROOT_EPS, STRETCH_RTOL

wp.set_module_options({"enable_backward": False})

MAX_EVENTS = 8  # surfaces one segment composites at most (the nearest; more are rare and dropped)
ROOT_STACK = 48  # the isolation's interval stack
ROOT_MAX_DEPTH = 40  # halvings of [-1, 1] at most (2^-40: below float32's resolution of s)
ROOT_ITERATIONS = 64  # safeguarded Newton steps at most
MAX_INTERVALS = 256  # intervals one level's isolation looks at, at most (a bound on a ray's work)
ROUNDING_FACTOR = 16.0  # p's rounding: ROUNDING_FACTOR eps sum |p_k| (deg <= 47 terms of Clenshaw)
NO_START = 2.0  # level_roots' start: none (p's own sign at s = -1)
# headlight shading of an isosurface (contract §7): colour (AMBIENT + DIFFUSE |n . d|)
AMBIENT = 0.25
DIFFUSE = 0.75

Series = wp.types.vector(length=MAX_SAMPLES, dtype=wp.float32)
EventTimes = wp.types.vector(length=MAX_EVENTS, dtype=wp.float32)
EventIds = wp.types.vector(length=MAX_EVENTS, dtype=wp.int32)
IntervalEnds = wp.types.vector(length=ROOT_STACK, dtype=wp.float32)
IntervalDepths = wp.types.vector(length=ROOT_STACK, dtype=wp.int32)


# ------------------------------------------------------------------ series in a local vector


@wp.func
def level_series(coeffs: wp.array(dtype=wp.float32), base: int, deg: int, c: float) -> Series:
    """p = g - c w^2 on [-1, 1] (degree max(deg, 2)): w = alpha + beta s, so
    w^2 = (alpha^2 + beta^2 / 2) T_0 + 2 alpha beta T_1 + beta^2 / 2 T_2."""
    p = Series()
    for k in range(deg + 1):
        p[k] = coeffs[base + k]
    ws = series_weights(coeffs, base, deg)
    alpha = 0.5 * (ws[0] + ws[1])
    beta = 0.5 * (ws[1] - ws[0])
    p[0] = p[0] - c * (alpha * alpha + 0.5 * beta * beta)
    p[1] = p[1] - c * (2.0 * alpha * beta)
    p[2] = p[2] - c * (0.5 * beta * beta)
    return p


@wp.func
def series_derivative(p: Series, n: int) -> Series:
    """The series of p' (degree n - 1) from p's (degree n): d_(k-1) = d_(k+1) + 2 k p_k, d_0 halved."""
    d = Series()
    k = n
    while k >= 1:
        above = float(0.0)
        if k + 1 <= n - 1:
            above = d[k + 1]
        d[k - 1] = above + 2.0 * float(k) * p[k]
        k -= 1
    d[0] = 0.5 * d[0]
    return d


@wp.func
def series_value(p: Series, n: int, s: float) -> float:
    """Clenshaw: sum_k p_k T_k(s), k = 0 .. n (0 for n < 0)."""
    if n < 0:
        return 0.0
    b1 = float(0.0)
    b2 = float(0.0)
    k = n
    while k >= 1:
        b0 = p[k] + 2.0 * s * b1 - b2
        b2 = b1
        b1 = b0
        k -= 1
    return p[0] + s * b1 - b2


@wp.func
def series_abs_sum(p: Series, n: int) -> float:
    """sum_k |p_k|, k = 0 .. n: a bound of |p| on [-1, 1]."""
    acc = float(0.0)
    for k in range(n + 1):
        acc += wp.abs(p[k])
    return acc


@wp.func
def bracketed_root(p: Series, dp: Series, n: int, u: float, v: float, pu: float):
    """The root of p in [u, v] where p changes sign (pu = p(u), of the other sign than p(v)):
    Newton inside the bracket, bisection where Newton leaves it. Returns (root, series
    evaluations)."""
    lo = u
    hi = v
    x = 0.5 * (u + v)
    evals = int(0)
    for it in range(ROOT_ITERATIONS):
        px = series_value(p, n, x)
        evals += 2
        if px == 0.0:
            return x, evals
        if (px < 0.0) == (pu < 0.0):
            lo = x
        else:
            hi = x
        dx = series_value(dp, n - 1, x)
        xn = 0.5 * (lo + hi)
        if dx != 0.0:
            xn = x - px / dx
            if not (xn > lo and xn < hi):
                xn = 0.5 * (lo + hi)
        if wp.abs(xn - x) <= 2.0 * ROOT_EPS * (1.0 + wp.abs(x)) or hi - lo <= 2.0 * ROOT_EPS * (1.0 + wp.abs(x)):
            return xn, evals
        x = xn
    return x, evals


@wp.func
def push_root(roots: EventTimes, count: int, s: float):
    """s appended to roots (ascending already: the isolation finds them left to right)."""
    out = roots
    if count < MAX_EVENTS:
        out[count] = s
        return out, count + 1
    return out, count


@wp.func
def sign_change(a: float, b: float) -> int:
    """1 where [a, b)'s ends say a root lies in it: p(a) = 0, or p(a), p(b) of opposite signs."""
    if a == 0.0:
        return 1
    if (a < 0.0 and b > 0.0) or (a > 0.0 and b < 0.0):
        return 1
    return 0


@wp.func
def local_series(p: Series, n: int, u: float, v: float) -> Series:
    """The series of p on [u, v] (s = m + r x, x in [-1, 1]): p at the n + 1 Chebyshev-Lobatto
    points of [u, v], then their discrete cosine transform (exact for a polynomial of degree n,
    to rounding)."""
    f = Series()
    m = 0.5 * (u + v)
    r = 0.5 * (v - u)
    for j in range(n + 1):
        f[j] = series_value(p, n, m + r * wp.cos(wp.pi * float(j) / float(n)))
    q = Series()
    for k in range(n + 1):
        ca = wp.cos(wp.pi * float(k) / float(n))
        cos_prev = ca
        cos_j = float(1.0)
        acc = float(0.0)
        for j in range(n + 1):
            w = float(1.0)
            if j == 0 or j == n:
                w = 0.5
            acc += w * f[j] * cos_j
            cos_next = 2.0 * ca * cos_j - cos_prev
            cos_prev = cos_j
            cos_j = cos_next
        acc = acc * 2.0 / float(n)
        if k == 0 or k == n:
            acc = 0.5 * acc
        q[k] = acc
    return q


@wp.func
def start_crosses(start: float, side: float) -> int:
    """1 where the start's sign (a previous segment's end: -1, 0, 1; NO_START: none) and `side`,
    the sign p keeps beyond it, say a root lies at the start: the start on c, or across it."""
    if start == NO_START:
        return 0
    if start == 0.0 or (start < 0.0) != (side < 0.0):
        return 1
    return 0


@wp.func
def root_from(p: Series, dp: Series, n: int, u: float, v: float, pu: float, pu_own: float, pv: float):
    """The root in [u, v] where the sign at u (pu: p's own pu_own, or the start's sign) and pv
    differ: u itself where pu is 0 or the change is the start's alone (p keeps its sign from u to
    v), else p's own bracketed root. Returns (root, series evaluations)."""
    if pu == 0.0 or pu_own == 0.0 or sign_change(pu_own, pv) == 0:
        return u, 0
    return bracketed_root(p, dp, n, u, v, pu_own)


@wp.func
def keeps_sign(q: Series, n: int, tol: float) -> int:
    """1 where the series q (on [-1, 1]) stays away from 0 by more than tol: |q_0| > sum_k>0 |q_k| + tol."""
    if wp.abs(q[0]) > series_abs_sum(q, n) - wp.abs(q[0]) + tol:
        return 1
    return 0


@wp.func
def level_roots(coeffs: wp.array(dtype=wp.float32), base: int, deg: int, c: float, err: float, start: float):
    """The roots in [-1, 1) of f = c on the segment whose series is at coeffs[base ..] (degree
    deg): (roots ascending, how many, series evaluations spent). Each interval looked at gets
    its own series (local_series), whose coefficients bound p, p' and p'' there; err widens
    the rounding tolerance (the samples' own rounding, MeshArgs.field_err, and a curved
    interpolant's tail). `start` (NO_START: none) is the sign p takes at s = -1 for the sign
    tests: the previous segment's end where the ray's field runs on from it (segment_events),
    so that a crossing between two segments' ends is met once, at this one's start."""
    roots = EventTimes()
    count = int(0)
    evals = int(0)
    n = wp.max(deg, 2)
    p = level_series(coeffs, base, deg, c)
    total = series_abs_sum(p, n)
    touch = ROUNDING_FACTOR * ROOT_EPS * total  # the series' own rounding: an extremum this near c touches it
    tol = touch + err
    if keeps_sign(p, n, tol) == 1:
        # the series' own bound excludes c: the common case, O(deg)
        if start_crosses(start, p[0]) == 1:
            roots, count = push_root(roots, count, -1.0)
        return roots, count, evals
    if total <= tol:
        return roots, count, evals  # f = c on the whole segment, within rounding: no surface
    d1 = series_derivative(p, n)
    d2 = series_derivative(d1, n - 1)
    tol1 = ROUNDING_FACTOR * ROOT_EPS * series_abs_sum(d1, n - 1)
    lo_stack = IntervalEnds()
    hi_stack = IntervalEnds()
    depth_stack = IntervalDepths()
    lo_stack[0] = -1.0
    hi_stack[0] = 1.0
    depth_stack[0] = 0
    top = int(1)
    visited = int(0)
    while top > 0 and count < MAX_EVENTS and visited < MAX_INTERVALS:
        top -= 1
        visited += 1
        u = lo_stack[top]
        v = hi_stack[top]
        depth = depth_stack[top]
        r = 0.5 * (v - u)
        q = local_series(p, n, u, v)
        evals += n + 1
        first = int(0)  # the interval at the segment's start: its sign there may be the start's
        if u == -1.0 and start != NO_START:
            first = 1
        if keeps_sign(q, n, tol) == 1:
            if first == 1 and start_crosses(start, q[0]) == 1:
                roots, count = push_root(roots, count, u)
            continue  # no root of p: |p| stays above the rounding
        pu_own = series_value(p, n, u)  # the ends from p itself: a shared end has one value and sign
        pu = pu_own
        if first == 1:
            pu = start
        pv = series_value(p, n, v)
        evals += 2
        q1 = series_derivative(q, n)  # r p'(m + r x)
        monotone = keeps_sign(q1, n - 1, r * tol1)
        if monotone == 0:
            q2 = series_derivative(q1, n - 1)  # r^2 p''
            if keeps_sign(q2, n - 2, 0.0) == 1:  # p'' keeps its sign: p has one extremum at most
                q_u = series_value(d1, n - 1, u)
                q_v = series_value(d1, n - 1, v)
                evals += 2
                if sign_change(q_u, q_v) == 0 and q_v != 0.0:
                    monotone = 1
                else:
                    s_ext = u
                    if q_u != 0.0:
                        s_ext, ev = bracketed_root(d1, d2, n - 1, u, v, q_u)
                        evals += ev
                    p_ext = series_value(p, n, s_ext)
                    evals += 1
                    if wp.abs(p_ext) <= touch:
                        # p's extremum on c within the series' own rounding: the ray touches the
                        # surface, one meeting (contract §7), after the start's crossing if any
                        if sign_change(pu, pv) == 1 and sign_change(pu_own, pv) == 0:
                            roots, count = push_root(roots, count, u)
                        roots, count = push_root(roots, count, s_ext)
                    else:
                        # p crosses c where the signs change: a pair near tangency is two meetings,
                        # the first at its own depth, not the extremum's (the samples' rounding
                        # err makes no touch: it would draw rays that miss by up to err / |grad f|)
                        if sign_change(pu, p_ext) == 1:
                            s_root, ev = root_from(p, d1, n, u, s_ext, pu, pu_own, p_ext)
                            evals += ev
                            roots, count = push_root(roots, count, s_root)
                        if sign_change(p_ext, pv) == 1:
                            s_root, ev = bracketed_root(p, d1, n, s_ext, v, p_ext)
                            evals += ev
                            roots, count = push_root(roots, count, s_root)
                    continue
        if monotone == 1:
            if sign_change(pu, pv) == 1:
                s_root, ev = root_from(p, d1, n, u, v, pu, pu_own, pv)
                evals += ev
                roots, count = push_root(roots, count, s_root)
            continue
        if depth >= ROOT_MAX_DEPTH or top + 2 > ROOT_STACK or r <= 4.0 * ROOT_EPS:
            # not resolved at the finest interval (p within rounding of 0 all over it, or a root
            # of multiplicity 3 or more): its middle where its ends' signs differ
            if sign_change(pu, pv) == 1:
                roots, count = push_root(roots, count, u + r)
            continue
        m = u + r
        lo_stack[top] = m  # the right half below the left: the left is taken first
        hi_stack[top] = v
        depth_stack[top] = depth + 1
        lo_stack[top + 1] = u
        hi_stack[top + 1] = m
        depth_stack[top + 1] = depth + 1
        top += 2
    return roots, count, evals


# ------------------------------------------------------------------ events along a segment


@wp.func
def insert_event(times: EventTimes, ids: EventIds, count: int, t: float, event: int):
    """(times, ids, count) with event at t inserted in increasing t (dropped when full and last)."""
    ot = times
    oi = ids
    k = count
    if k == MAX_EVENTS:
        if t >= ot[MAX_EVENTS - 1]:
            return ot, oi, count
        k = MAX_EVENTS - 1
    while k > 0 and ot[k - 1] > t:
        ot[k] = ot[k - 1]
        oi[k] = oi[k - 1]
        k -= 1
    ot[k] = t
    oi[k] = event
    return ot, oi, wp.min(count + 1, MAX_EVENTS)


@wp.func
def plane_hit(surf: SurfaceArgs, j: int, o: wp.vec3, d: wp.vec3) -> float:
    """t where the ray meets plane j (1e30 where it runs parallel to it)."""
    pl = surf.plane[j]
    n = wp.vec3(pl[0], pl[1], pl[2])
    nd = wp.dot(n, d)
    if wp.abs(nd) < 1.0e-12:
        return 1.0e30
    return (pl[3] - wp.dot(n, o)) / nd


@wp.func
def kept_span(surf: SurfaceArgs, o: wp.vec3, d: wp.vec3) -> wp.vec2:
    """The part of the ray the clipping planes keep, (t_lo, t_hi) (empty where t_lo >= t_hi)."""
    k0 = float(-1.0e30)
    k1 = float(1.0e30)
    for j in range(surf.n_planes):
        side = surf.plane_style[j][1]
        if side != 0.0:
            pl = surf.plane[j]
            n = wp.vec3(pl[0], pl[1], pl[2])
            g0 = side * (wp.dot(n, o) - pl[3])  # kept where g0 + t g1 <= 0
            g1 = side * wp.dot(n, d)
            if wp.abs(g1) < 1.0e-12:
                if g0 > 0.0:
                    k1 = float(-1.0e30)
            elif g1 > 0.0:
                k1 = wp.min(k1, -g0 / g1)
            else:
                k0 = wp.max(k0, -g0 / g1)
    return wp.vec2(k0, k1)


@wp.func
def series_ends(coeffs: wp.array(dtype=wp.float32), base: int, deg: int) -> wp.vec4:
    """(g(-1), g(1), g'(-1), sum |g_k|) of the segment's series g (f = g / w^2)."""
    g0 = float(0.0)
    g1 = float(0.0)
    dg0 = float(0.0)
    size = float(0.0)
    sign = float(1.0)
    for k in range(deg + 1):
        ck = coeffs[base + k]
        g1 += ck
        g0 += sign * ck
        dg0 -= sign * float(k * k) * ck  # T_k'(-1) = (-1)^(k+1) k^2
        size += wp.abs(ck)
        sign = -sign
    return wp.vec4(g0, g1, dg0, size)


@wp.func
def runs_on(last: wp.vec2, a: float, b: float, f0: float, err: float, slope: float) -> int:
    """1 where a segment [a, b] whose field starts at f0 (within err; slope |df/dt| there) takes
    over from the previous one's end last = (t, f): it starts there, within the traversal's
    rounding of a crossing (STRETCH_RTOL), and its field agrees with the end's within both ends'
    rounding and what the gap between them changes (a field that jumps across the element's
    face, as a discontinuous one may, does not run on)."""
    gap = a - last[0]
    if last[0] <= NO_SURFACE_END or wp.abs(gap) > STRETCH_RTOL * (wp.abs(a) + (b - a)):
        return 0
    if wp.abs(f0 - last[1]) <= 2.0 * err + 2.0 * slope * wp.abs(gap):
        return 1
    return 0


@wp.func
def segment_events(mesh: MeshArgs, surf: SurfaceArgs, e: int, o: wp.vec3, d: wp.vec3, a: float, b: float, deg: int,
                   coeffs: wp.array(dtype=wp.float32), base: int, span: wp.vec2, tail: float, last: wp.vec2):
    """The surfaces the ray meets in segment [a, b) of element e within the kept span, in
    increasing t: (times, ids, count, series evaluations, the ray's surface_end after it); id
    i >= 0 is isosurface i, -1 - j plane j. Levels outside the element's certified range are
    not searched.

    `last` is (t, f) at the far end of the ray's previous segment (RayIntegral.surface_end).
    Where this one runs on from it (runs_on), each level's sign at this segment's start is the
    previous end's: a crossing between the two series' ends (in a gap the traversal's rounding
    left, or where their roundings put their ends on either side of c) is met once, at this
    start, and one the previous segment met at its end is not met again here."""
    times = EventTimes()
    ids = EventIds()
    count = int(0)
    evals = int(0)
    end = last
    if deg >= 0 and b > a:  # (a zero-length segment changes nothing)
        ws = series_weights(coeffs, base, deg)
        w0 = ws[0] * ws[0]
        w1 = ws[1] * ws[1]
        g = series_ends(coeffs, base, deg)
        err = mesh.field_err[e] + tail
        joined = int(0)
        end = wp.vec2(NO_SURFACE_END, 0.0)
        if w0 > 0.0 and w1 > 0.0:  # (a pyramid's apex: f = g / w^2 is not defined there)
            end = wp.vec2(b, g[1] / w1)
            rounding = (ROUNDING_FACTOR * ROOT_EPS * g[3] + err) / w0
            joined = runs_on(last, a, b, g[0] / w0, rounding, wp.abs(g[2]) * 2.0 / ((b - a) * w0))
        for i in range(surf.n_iso):
            c = surf.iso_s[i]
            start = float(NO_START)
            if joined == 1:
                start = wp.sign(last[1] - c)
                if last[1] == c:
                    start = 0.0
            k = int(0)
            roots = EventTimes()
            if c >= mesh.field_lo[e] and c <= mesh.field_hi[e]:
                roots, k, ev = level_roots(coeffs, base, deg, c, err, start)
                evals += ev
            elif start_crosses(start, mesh.field_lo[e] - c) == 1:
                # c outside this element's range, the previous end across it: met at this start
                roots[0] = -1.0
                k = 1
            for j in range(k):
                # a root at s < 1 is this segment's even where t rounds to b: the next segment
                # starts from this end's sign, already across c, and would not meet it again
                t = wp.min(a + 0.5 * (roots[j] + 1.0) * (b - a), b)
                if roots[j] < 1.0 and t >= span[0] and t <= span[1]:
                    times, ids, count = insert_event(times, ids, count, t, i)
    elif deg < 0:
        end = wp.vec2(NO_SURFACE_END, 0.0)
    for j in range(surf.n_planes):
        t = plane_hit(surf, j, o, d)
        if t >= a and t < b and t >= span[0] and t <= span[1]:
            times, ids, count = insert_event(times, ids, count, t, -1 - j)
    return times, ids, count, evals, end


# ------------------------------------------------------------------ the surface at a point


@wp.func
def locate(mesh: MeshArgs, e: int, x: wp.vec3):
    """(xi, dxi/dx, located) of point x in element e: the affine map, or Newton on a curved one."""
    if mesh.affine[e] == 1:
        return mesh.ref_a[e] * x + mesh.ref_b[e], mesh.ref_a[e], 1
    r, Jinv, its = geometry.invert_point(mesh, e, x, geometry.start_guess(mesh, e, x))
    ok = int(0)
    if r[3] > 0.0:
        ok = 1
    return wp.vec3(r[0], r[1], r[2]), Jinv, ok


@wp.func
def field_gradient(mesh: MeshArgs, surf: SurfaceArgs, e: int, xi: wp.vec3, Jinv: wp.mat33) -> wp.vec3:
    """grad f = J^-T grad_xi f at xi (zero without the reference gradient's expansion)."""
    if surf.grad_stride == 0:
        return wp.vec3(0.0, 0.0, 0.0)
    off = mesh.coeff_offset[e]
    g = wp.vec3(0.0, 0.0, 0.0)
    for k in range(3):
        g[k] = element.eval_element(mesh.shape[e], surf.grad, off + k * surf.grad_stride, mesh.modes[e], xi)
    return wp.transpose(Jinv) * g


@wp.func
def headlight(rgb: wp.vec3, g: wp.vec3, d: wp.vec3) -> wp.vec3:
    """An isosurface's colour lit from the eye: rgb (AMBIENT + DIFFUSE |n . d|), n = g / |g|
    (|n . d| = 1 where the gradient vanishes)."""
    gl = wp.length(g)
    cosine = float(1.0)
    if gl > 0.0:
        cosine = wp.abs(wp.dot(g, d)) / gl
    return rgb * (AMBIENT + DIFFUSE * cosine)


@wp.func
def ramp_color(surf: SurfaceArgs, v: float) -> wp.vec3:
    """The isosurfaces' colour ramp at v (piecewise linear, held beyond its ends)."""
    kw = ramp_segment(surf.ramp_s, v, -1)
    k = int(kw[0])
    if surf.ramp_s.shape[0] == 1:
        return surf.ramp_rgb[0]
    return surf.ramp_rgb[k] + kw[1] * (surf.ramp_rgb[k + 1] - surf.ramp_rgb[k])


@wp.func
def composite_event(mesh: MeshArgs, tf: TransferArgs, e: int, o: wp.vec3, d: wp.vec3, t_in: float, event: int,
                    state_in: RayIntegral):
    """Surface `event` met at t into the ray's state: C += T alpha colour, T *= 1 - alpha, the
    depth set where T falls through 0.5 there. Returns (state, element evaluations)."""
    state = state_in
    surf = tf.surf
    t = t_in
    rgb = wp.vec3(0.0, 0.0, 0.0)
    alpha = float(0.0)
    evals = int(0)
    xi, Jinv, ok = locate(mesh, e, o + t * d)
    if event >= 0:
        c = surf.iso_s[event]
        rgba = surf.iso_rgba[event]
        alpha = rgba[3]
        g = field_gradient(mesh, surf, e, xi, Jinv)
        if mesh.affine[e] == 0 and ok == 1 and surf.grad_stride > 0 and mesh.derived.active == 0:
            # the root of the interpolant, corrected by a Newton step on the field itself
            slope = wp.dot(g, d)
            f = element.eval_element(mesh.shape[e], mesh.coeffs, mesh.coeff_offset[e], mesh.modes[e], xi)
            evals += 1
            if slope != 0.0:
                step = (f - c) / slope
                if wp.abs(step) < 1.0e-3 * (wp.abs(t) + 1.0):
                    t = t - step
                    xi, Jinv, ok = locate(mesh, e, o + t * d)
                    g = field_gradient(mesh, surf, e, xi, Jinv)
        evals += 3
        rgb = wp.vec3(rgba[0], rgba[1], rgba[2])
        by = surf.iso_color_by[event]
        if by >= 0 and mesh.derived.active == 1:  # coloured by a field of the mesh's velocity there
            kind = by + mesh.derived.kind[e] - mesh.derived.kind[e] % derived.PER_DENSITY
            rgb = ramp_color(surf, derived.derived_of(mesh, e, xi, Jinv, kind))
            evals += 1
        rgb = headlight(rgb, g, d)
    else:
        alpha = surf.plane_style[-1 - event][0]
        f = float(0.0)
        if mesh.derived.active == 1:
            f = derived.sample_value(mesh, e, xi, Jinv)  # the derived field itself, exact at the point
        else:
            f = element.eval_element(mesh.shape[e], mesh.coeffs, mesh.coeff_offset[e], mesh.modes[e], xi)
        evals += 1
        rgb = tf_color(tf, f)
    T0 = state.transmittance
    T1 = T0 * (1.0 - alpha)
    state.color = state.color + T0 * alpha * rgb
    state.transmittance = T1
    if state.depth < 0.0 and T0 > 0.5 and T1 <= 0.5:
        state.depth = t
    return state, evals
