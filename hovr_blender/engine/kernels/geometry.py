"""Curved (non-affine) elements on the device: the map x(xi), its inversion, and where a ray
leaves an element.

The map comes as a tensor Legendre polynomial of (x - centre) w^2 (engine/tensor_geometry.py),
so x and its exact Jacobian cost one pass over the coefficients with no collapse to avoid.
Inversion is Newton with the exact Jacobian, started from the element's vertex-affine map
(or a neighbour's solution), steps held inside an enlarged reference box. Inside/outside is
the margin to the nearest reference face (element.face_plane), a plane in xi.

Where a ray leaves a curved element it is inside of (curved_exit): march along the ray by
predictor-corrector steps, each predicted to the first face the tangent in reference space
reaches, until a step lands outside; then the crossing is found by Newton on the margin (regula
falsi where that fails). A few solves per element. Where a ray enters one: kernels/crossing.py.
"""
from __future__ import annotations

import warp as wp

from . import element
from .args import MeshArgs
# the precision's tolerances (kernels/tolerances.py): INSIDE_TOL, the reference-space margin still
# counted as inside; NEWTON_STEP_TOL, Newton's last step; ROOT_RTOL, a crossing's relative bracket
from .tolerances import INSIDE_TOL, NEWTON_STEP_TOL, ROOT_RTOL

wp.set_module_options({"enable_backward": False})

NEWTON_NOISE_MAX = 1.0e-3  # ... or below its rounding floor, where that is larger, up to this
# Newton's iterations at most: quadratic convergence needs a few, but next to an edge where
# the element's Jacobian vanishes (NGSolve's ball) it converges linearly, about a bit a step
NEWTON_ITERATIONS = 40
NEWTON_FAILED = -1.0e30  # curved_inside's margin where Newton did not converge
EXIT_OVERSHOOT = 0.05  # a predicted exit step goes this fraction beyond the tangent's face hit
MAX_EXIT_STEPS = 32


@wp.func
def legendre_next(n: int, x: float, p: float, pm: float, dp: float, dpm: float) -> wp.vec2:
    """(L_{n+1}(x), L'_{n+1}(x)) from L_n = p, L_{n-1} = pm and their derivatives dp, dpm:
    Bonnet's recurrence and L'_{n+1} = L'_{n-1} + (2n + 1) L_n."""
    fn = float(n)
    return wp.vec2(((2.0 * fn + 1.0) * x * p - fn * pm) / (fn + 1.0), dpm + (2.0 * fn + 1.0) * p)


@wp.func
def local_ray_point(mesh: MeshArgs, e: int, o: wp.vec3, d: wp.vec3, t: float) -> wp.vec3:
    """o + t d - the element's centre, summed in float64 and rounded once: a point of the ray in
    the frame local_geometry_with_jacobian works in, rounded to its own size (the element's), not
    to the size of o and t d (the camera's distance). A ray that grazes a face has its crossing
    there to that rounding over the sine of the angle."""
    return wp.vec3(wp.vec3d(o) - wp.vec3d(mesh.geo_centre[e]) + wp.float64(t) * wp.vec3d(d))


@wp.func
def geometry_with_jacobian(mesh: MeshArgs, e: int, xi: wp.vec3):
    """x(xi) and dx/dxi (columns d/dxi_k) of curved element e (local_geometry_with_jacobian
    and the element's centre)."""
    x, J = local_geometry_with_jacobian(mesh, e, xi)
    return x + mesh.geo_centre[e], J


@wp.func
def local_geometry_with_jacobian(mesh: MeshArgs, e: int, xi_in: wp.vec3):
    """x(xi) - the element's centre and dx/dxi (columns d/dxi_k) of curved element e, in one pass.
    The Legendre values run as recurrences inside the loops (no arrays: they would live in local
    memory)."""
    sh = mesh.shape[e]
    xi = xi_in
    if sh == element.PYR:
        xi[2] = wp.min(xi[2], 0.9999)  # the apex: x w^2 is polynomial, x is not defined there
    n = mesh.geo_degree[e] + 1
    x = wp.vec3(0.0, 0.0, 0.0)
    g1 = wp.vec3(0.0, 0.0, 0.0)
    g2 = wp.vec3(0.0, 0.0, 0.0)
    g3 = wp.vec3(0.0, 0.0, 0.0)
    idx = mesh.geo_offset[e]
    ck = float(1.0)  # L_k(xi2), L_{k-1}, and derivatives
    ckm = float(0.0)
    dck = float(0.0)
    dckm = float(0.0)
    for k in range(n):
        p = wp.vec3(0.0, 0.0, 0.0)
        p1 = wp.vec3(0.0, 0.0, 0.0)
        p2 = wp.vec3(0.0, 0.0, 0.0)
        bj = float(1.0)
        bjm = float(0.0)
        dbj = float(0.0)
        dbjm = float(0.0)
        for j in range(n):
            s = wp.vec3(0.0, 0.0, 0.0)
            sd = wp.vec3(0.0, 0.0, 0.0)
            ai = float(1.0)
            aim = float(0.0)
            dai = float(0.0)
            daim = float(0.0)
            for i in range(n):
                cc = mesh.geo_coeffs[idx]
                idx += 1
                s += ai * cc
                sd += dai * cc
                an = legendre_next(i, xi[0], ai, aim, dai, daim)
                aim = ai
                ai = an[0]
                daim = dai
                dai = an[1]
            p += bj * s
            p1 += bj * sd
            p2 += dbj * s
            bn = legendre_next(j, xi[1], bj, bjm, dbj, dbjm)
            bjm = bj
            bj = bn[0]
            dbjm = dbj
            dbj = bn[1]
        x += ck * p
        g1 += ck * p1
        g2 += ck * p2
        g3 += dck * p
        cn = legendre_next(k, xi[2], ck, ckm, dck, dckm)
        ckm = ck
        ck = cn[0]
        dckm = dck
        dck = cn[1]
    if sh == element.PYR:
        # stored G = (x - centre) w^2 with w = (1 - xi3) / 2: x - centre = G / w^2 and
        # d/dxi3 (G / w^2) = (G_3 + (x - centre) w) / w^2
        w = 0.5 * (1.0 - xi[2])
        iw2 = 1.0 / (w * w)
        x = x * iw2
        g1 = g1 * iw2
        g2 = g2 * iw2
        g3 = (g3 + x * w) * iw2
    J = wp.mat33(g1[0], g2[0], g3[0], g1[1], g2[1], g3[1], g1[2], g2[2], g3[2])
    return x, J


@wp.func
def start_guess(mesh: MeshArgs, e: int, p: wp.vec3) -> wp.vec3:
    """Newton's start for the point p: the element's vertex-affine map (exact for affine
    elements, the curved map's straight-sided twin otherwise), held in the start box."""
    xi = mesh.ref_a[e] * p + mesh.ref_b[e]
    for k in range(3):
        xi[k] = wp.clamp(xi[k], -1.2, 1.2)
    return xi


@wp.func
def invert_point(mesh: MeshArgs, e: int, p: wp.vec3, xi0: wp.vec3):
    """(xi, converged) with x(xi) = p: Newton with the exact Jacobian, steps clamped so xi
    stays in a slightly enlarged reference box; the last inverse Jacobian dxi/dx (it turns
    the ray direction into the reference-space velocity, for warm starts and slopes); and the
    iterations taken (each one map evaluation with its Jacobian: the work counts' STAT_NEWTON_*)."""
    xi = xi0
    ok = float(0.0)
    Jinv = wp.identity(n=3, dtype=float)
    held_count = int(0)
    iterations = int(0)
    for it in range(NEWTON_ITERATIONS):
        iterations += 1
        x, J = geometry_with_jacobian(mesh, e, xi)
        det = wp.determinant(J)
        if wp.abs(det) < 1.0e-30:
            break
        Jinv = wp.inverse(J)
        dxi = Jinv * (x - p)
        xi = xi - dxi
        held = int(0)
        for k in range(3):
            if wp.abs(xi[k]) > 1.5:
                held = 1
            xi[k] = wp.clamp(xi[k], -1.5, 1.5)
        # pushed against the enlarged box twice: p is far outside the element (the usual
        # fate of box samples off the element), not worth the remaining iterations
        held_count += held
        if held_count >= 2:
            break
        # float32 reaches ~1e-7 in xi; the step before that is below 1e-5 (quadratic convergence).
        # Where rounding in x(xi) moves xi by more than that (near a pyramid's apex x = G / w^2:
        # float32 steps stalled above 1e-4 and the walk left the element early), a step within
        # that noise is as converged as it gets (up to NEWTON_NOISE_MAX: at the apex itself the
        # floor is unbounded)
        step = wp.length(dxi)
        if step < NEWTON_STEP_TOL:
            ok = 1.0
            break
        if step < NEWTON_NOISE_MAX:  # the floor is only worth computing for a step this small
            noise = mesh.geo_err[e]
            if mesh.shape[e] == element.PYR:
                if xi[2] < 0.9999:
                    w = 0.5 * (1.0 - xi[2])
                    noise = noise / (w * w)
                else:
                    noise = 0.0  # beyond the apex geometry_with_jacobian held xi: no shortcut there
            jn = float(0.0)
            for r in range(3):
                jn = wp.max(jn, wp.abs(Jinv[r, 0]) + wp.abs(Jinv[r, 1]) + wp.abs(Jinv[r, 2]))
            if step < jn * noise:
                ok = 1.0
                break
    return wp.vec4(xi[0], xi[1], xi[2], ok), Jinv, iterations


@wp.func
def margin_and_face(shape: int, xi: wp.vec3) -> wp.vec2:
    """(margin, face): the smallest c_f - n_f . xi over the reference faces (> 0 inside) and
    which face it is."""
    m = float(1.0e30)
    face = int(0)
    for f in range(element.num_faces(shape)):
        p = element.face_plane(shape, f)
        mf = p[3] - (p[0] * xi[0] + p[1] * xi[1] + p[2] * xi[2])
        if mf < m:
            m = mf
            face = f
    return wp.vec2(m, float(face))


@wp.func
def solved_margin(mesh: MeshArgs, e: int, p: wp.vec3, xi0: wp.vec3):
    """invert_point from xi0 and the solution's margin + INSIDE_TOL (NEWTON_FAILED where Newton
    did not converge), with the inverse Jacobian, the nearest face and Newton's iterations."""
    r, Jinv, its = invert_point(mesh, e, p, xi0)
    m = float(NEWTON_FAILED)
    face = float(0.0)
    if r[3] > 0.0:
        mf = margin_and_face(mesh.shape[e], wp.vec3(r[0], r[1], r[2]))
        m = mf[0] + INSIDE_TOL
        face = mf[1]
    return wp.vec3(r[0], r[1], r[2]), m, face, Jinv, its


@wp.func
def reference_centre(shape: int) -> wp.vec3:
    """The mean of the reference element's vertices (engine/shapes.py VERTICES)."""
    if shape == element.PRISM:
        return wp.vec3(-1.0 / 3.0, 0.0, -1.0 / 3.0)
    if shape == element.TET:
        return wp.vec3(-0.5, -0.5, -0.5)
    if shape == element.PYR:
        return wp.vec3(-0.2, -0.2, -0.6)
    return wp.vec3(0.0, 0.0, 0.0)


@wp.func
def curved_inside(mesh: MeshArgs, e: int, o: wp.vec3, d: wp.vec3, t: float, xi0: wp.vec3):
    """(xi, margin + INSIDE_TOL) at ray parameter t: > 0 inside; NEWTON_FAILED where Newton does
    not converge; and (dxi/dt, dmargin/dt) there, for warm starts one step ahead and Newton on
    the margin; and Newton's iterations. A warm start that fails, or that lands outside the
    element, is retried from the affine guess and then from the element's centre; the best
    answer is kept.

    Beyond the element the polynomial map can fold (an element whose Jacobian vanishes along an
    edge, as where NGSolve's ball puts a hexahedron's edge on the sphere with its faces at 180
    degrees), so Newton can converge to a second preimage of p outside the reference element
    while p lies inside: from the extrapolated warm start, and from the affine guess too, whose
    straight-sided twin of that element reaches past the edge. Without the retries the entry
    search stepped between such a point and one before the element until it gave up, and the
    ray lost the element."""
    p = o + t * d
    xi, m, face, Jinv, its = solved_margin(mesh, e, p, xi0)
    if m <= 0.0:
        xi2, m2, face2, Jinv2, its2 = solved_margin(mesh, e, p, start_guess(mesh, e, p))
        its += its2
        if m2 > m:
            xi = xi2
            m = m2
            face = face2
            Jinv = Jinv2
    if m <= 0.0:
        xi3, m3, face3, Jinv3, its3 = solved_margin(mesh, e, p, reference_centre(mesh.shape[e]))
        its += its3
        if m3 > m:
            xi = xi3
            m = m3
            face = face3
            Jinv = Jinv3
    v = Jinv * d
    slope = float(0.0)
    if m > NEWTON_FAILED:
        pl = element.face_plane(mesh.shape[e], int(face))
        slope = -(pl[0] * v[0] + pl[1] * v[1] + pl[2] * v[2])
    return wp.vec4(xi[0], xi[1], xi[2], m), wp.vec4(v[0], v[1], v[2], slope), its


@wp.func
def ahead(r: wp.vec4, dv: wp.vec4, dt: float) -> wp.vec3:
    """Warm start dt further along the ray from a solved point (xi, velocity), kept in Newton's box."""
    y = wp.vec3(r[0], r[1], r[2])
    if r[3] > NEWTON_FAILED:
        y = y + dt * wp.vec3(dv[0], dv[1], dv[2])
    for k in range(3):
        y[k] = wp.clamp(y[k], -1.5, 1.5)
    return y


@wp.func
def box_interval(mesh: MeshArgs, e: int, o: wp.vec3, d: wp.vec3) -> wp.vec2:
    lo = mesh.box_lo[e]
    hi = mesh.box_hi[e]
    t0 = float(-1.0e30)
    t1 = float(1.0e30)
    for k in range(3):
        if wp.abs(d[k]) < 1.0e-30:
            if o[k] < lo[k] or o[k] > hi[k]:
                t1 = -1.0e30
        else:
            ta = (lo[k] - o[k]) / d[k]
            tb = (hi[k] - o[k]) / d[k]
            t0 = wp.max(t0, wp.min(ta, tb))
            t1 = wp.min(t1, wp.max(ta, tb))
    return wp.vec2(t0, t1)


# ------------------------------------------------------------------ boundary crossings
# Where the ray crosses an element's boundary between an outside point a (margin fa <= 0) and
# an inside point b (solution rb, velocity dvb): the margin is smooth across one face and its
# slope is known (curved_inside), so Newton steps on it are taken while they stay inside the
# bracket, with bisection where the outside end's solve failed and Illinois regula falsi otherwise.
# The margin is the smallest over the faces, so its slope jumps where the nearest face changes:
# Newton from a point whose nearest face is not the one crossed can go back and forth between
# the bracket's ends (Hex_Mushroom: 1.31 and 1.89 for 80 steps, the crossing at 1.56), so a
# Newton step must be under half the step before the last one (Numerical Recipes' rtsafe),
# else the bracket is halved.
# The result is an inside point within ROOT_RTOL relative of the crossing with the solution
# found there (solving again at that t can land a rounding error on the other side). The
# callers' loops ask bracket_query for the next t, solve there, and hand it to bracket_update,
# so each has a single Newton call site.


@wp.struct
class Bracket:
    a: wp.float32
    fa: wp.float32
    b: wp.float32
    fb: wp.float32  # the inside margin as regula falsi weighs it (Illinois halves it)
    rb: wp.vec4
    dvb: wp.vec4
    side: wp.int32
    have: wp.int32  # the last evaluation converged: its t, solution and velocity
    tl: wp.float32
    rl: wp.vec4
    dvl: wp.vec4
    done: wp.int32
    last: wp.float32  # the last t solved at
    dx: wp.float32  # the last step's length, and the one before
    dxold: wp.float32


@wp.func
def bracket_start(t_out: float, m_out: float, t_in: float, r_in: wp.vec4, dv_in: wp.vec4) -> Bracket:
    br = Bracket()
    br.a = t_out
    br.fa = m_out
    br.b = t_in
    br.fb = r_in[3]
    br.rb = r_in
    br.dvb = dv_in
    br.side = 0
    br.have = 0
    br.tl = t_in
    br.rl = r_in
    br.dvl = dv_in
    br.done = 0
    br.last = t_in
    # the first two Newton steps may go anywhere inside the bracket
    br.dx = 2.0 * wp.abs(t_in - t_out)
    br.dxold = br.dx
    return br


@wp.func
def bracket_query(br: Bracket):
    """The next t to solve at and its warm start (br.done set where the bracket is closed)."""
    a = br.a
    b = br.b
    fb = br.fb
    m = 0.5 * (a + b)
    if fb != br.fa:
        m = b - fb * (b - a) / (fb - br.fa)
        # stay strictly inside the bracket, and halve when falsi would crawl along one end
        lim = 0.01 * wp.abs(b - a)
        if wp.abs(m - a) < lim or wp.abs(m - b) < lim:
            m = 0.5 * (a + b)
    start = wp.vec3(br.rb[0], br.rb[1], br.rb[2])
    if br.have == 1:
        start = ahead(br.rl, br.dvl, m - br.tl)
        if br.dvl[3] != 0.0:
            tn = br.tl - br.rl[3] / br.dvl[3]
            if tn > wp.min(a, b) and tn < wp.max(a, b):
                if wp.abs(tn - br.tl) <= 0.5 * br.dxold:
                    m = tn
                else:
                    m = 0.5 * (a + b)  # Newton is not converging here: halve
                start = ahead(br.rl, br.dvl, m - br.tl)
    return m, start


@wp.func
def bracket_update(br_in: Bracket, m: float, rm: wp.vec4, dvm: wp.vec4) -> Bracket:
    br = br_in
    br.have = 0
    br.dxold = br.dx
    br.dx = wp.abs(m - br.last)
    br.last = m
    if rm[3] > NEWTON_FAILED:
        br.have = 1
        br.tl = m
        br.rl = rm
        br.dvl = dvm
    tol = ROOT_RTOL * (wp.abs(br.a) + wp.abs(br.b)) + 1.0e-30
    if rm[3] > 0.0:
        br.b = m
        br.fb = rm[3]
        br.rb = rm
        br.dvb = dvm
        if br.side == 1:
            br.fa = 0.5 * br.fa
        br.side = 1
        # inside, and Newton says the crossing is within the tolerance: done
        if dvm[3] != 0.0 and wp.abs(rm[3] / dvm[3]) <= tol:
            br.done = 1
    else:
        br.a = m
        br.fa = rm[3]
        if br.side == -1:
            br.fb = 0.5 * br.fb
        br.side = -1
    if wp.abs(br.b - br.a) <= ROOT_RTOL * (wp.abs(br.a) + wp.abs(br.b)) + 1.0e-30:
        br.done = 1
    return br


@wp.func
def tangent_face_step(shape: int, xi: wp.vec3, v: wp.vec3) -> float:
    """How far along the ray (t units) the tangent line xi + s v reaches the first reference
    face it is heading for (1e30 if none): the predictor of curved_exit."""
    best = float(1.0e30)
    for f in range(element.num_faces(shape)):
        p = element.face_plane(shape, f)
        rate = p[0] * v[0] + p[1] * v[1] + p[2] * v[2]
        if rate > 0.0:
            s = (p[3] - (p[0] * xi[0] + p[1] * xi[1] + p[2] * xi[2])) / rate
            best = wp.min(best, wp.max(s, 0.0))
    return best


@wp.func
def curved_exit(mesh: MeshArgs, e: int, o: wp.vec3, d: wp.vec3, t_in: float, r_in: wp.vec4, dv_in: wp.vec4,
                t_end: float):
    """The ray is inside curved element e at t_in (solution r_in, velocity dv_in): where it
    leaves, as (t_exit, exit face or -1, 0), with the solution and velocity there, and Newton's
    iterations. Steps go to
    the face the tangent in reference space predicts (a little beyond it, at most half the box
    chord at a time) until one lands outside; then the bracket closes on the crossing. Reaching
    t_end (the box's or the ray's end) inside ends the stretch there with face -1."""
    t = t_in
    r = r_in
    dv = dv_in
    span = t_end - t_in
    shape = mesh.shape[e]
    stepping = int(1)
    br = Bracket()
    newton = int(0)
    for it in range(MAX_EXIT_STEPS + 40):
        tq = t
        start = wp.vec3(0.0, 0.0, 0.0)
        if stepping == 1:
            s = tangent_face_step(shape, wp.vec3(r[0], r[1], r[2]), wp.vec3(dv[0], dv[1], dv[2]))
            tq = wp.min(t + wp.min(s * (1.0 + EXIT_OVERSHOOT) + 1.0e-4 * span, 0.5 * span), t_end)
            start = ahead(r, dv, tq - t)
        else:
            tq, start = bracket_query(br)
        rq, dvq, its = curved_inside(mesh, e, o, d, tq, start)
        newton += its
        if stepping == 1:
            if rq[3] > 0.0:
                t = tq
                r = rq
                dv = dvq
                if t >= t_end:
                    return wp.vec3(t_end, -1.0, 0.0), r, dv, newton
            else:
                stepping = 0
                br = bracket_start(tq, rq[3], t, r, dv)
        else:
            br = bracket_update(br, tq, rq, dvq)
            if br.done == 1:
                break
    if stepping == 1:
        # out of steps short of t_end (a ray grazing a face steps along it in the band): the walk
        # goes on through the nearest face, where the neighbour's own Newton checks the ray is inside
        mf_last = margin_and_face(shape, wp.vec3(r[0], r[1], r[2]))
        return wp.vec3(t, mf_last[1], 0.0), r, dv, newton
    mf = margin_and_face(shape, wp.vec3(br.rb[0], br.rb[1], br.rb[2]))
    return wp.vec3(br.b, mf[1], 0.0), br.rb, br.dvb, newton
