"""Curved (non-affine) elements on the device: the map x(xi), its inversion, and where a ray
enters and leaves an element.

The map comes as a tensor Legendre polynomial of (x - centre) w^2 (engine/tensor_geometry.py),
so x and its exact Jacobian cost one pass over the coefficients with no collapse to avoid.
Inversion is Newton with the exact Jacobian, started from the element's vertex-affine map
(or a neighbour's solution), steps held inside an enlarged reference box. Inside/outside is
the margin to the nearest reference face (element.face_plane), a plane in xi.

Two ways to find a ray's stretch in a curved element:
- curved_exit: the ray is already inside (it came through a shared face): march along the
  ray by predictor-corrector steps, each predicted to the first face the tangent in
  reference space reaches, until a step lands outside; then the crossing is found by
  Newton on the margin (regula falsi where that fails). A few solves per element.
- curved_entry: the ray comes from outside (the BVH entry search): samples of the box
  interval, then the same crossing search. Used where there is no neighbour to walk from.
"""
from __future__ import annotations

import warp as wp

from . import element as el_k
from .args import MeshArgs

wp.set_module_options({"enable_backward": False})

# Tolerances sized for float32; the float64 twin gets kernels/precision.FLOAT64_CONSTANTS.
INSIDE_TOL = 1.0e-5  # reference-space margin still counted as inside (float32 noise in xi)
NEWTON_STEP_TOL = 1.0e-5  # Newton stops after a step below this (quadratic: xi then ~1e-10 off)
ROOT_RTOL = 1.0e-7  # relative bracket width where boundary and level crossings stop
CURVED_SAMPLES = 16  # samples of the box interval in the entry search
EXIT_OVERSHOOT = 0.05  # a predicted exit step goes this fraction beyond the tangent's face hit
MAX_EXIT_STEPS = 32


@wp.func
def geometry_with_jacobian(mesh: MeshArgs, e: int, xi_in: wp.vec3):
    """x(xi) and dx/dxi (columns d/dxi_k) of curved element e, in one pass. The Legendre
    values run as recurrences inside the loops (no arrays: they would live in local memory)."""
    sh = mesh.shape[e]
    xi = xi_in
    if sh == el_k.PYR:
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
                fi = float(i)
                an = ((2.0 * fi + 1.0) * xi[0] * ai - fi * aim) / (fi + 1.0)
                dan = daim + (2.0 * fi + 1.0) * ai
                aim = ai
                ai = an
                daim = dai
                dai = dan
            p += bj * s
            p1 += bj * sd
            p2 += dbj * s
            fj = float(j)
            bn = ((2.0 * fj + 1.0) * xi[1] * bj - fj * bjm) / (fj + 1.0)
            dbn = dbjm + (2.0 * fj + 1.0) * bj
            bjm = bj
            bj = bn
            dbjm = dbj
            dbj = dbn
        x += ck * p
        g1 += ck * p1
        g2 += ck * p2
        g3 += dck * p
        fk = float(k)
        cn = ((2.0 * fk + 1.0) * xi[2] * ck - fk * ckm) / (fk + 1.0)
        dcn = dckm + (2.0 * fk + 1.0) * ck
        ckm = ck
        ck = cn
        dckm = dck
        dck = dcn
    if sh == el_k.PYR:
        # stored G = (x - centre) w^2 with w = (1 - xi3) / 2: x - centre = G / w^2 and
        # d/dxi3 (G / w^2) = (G_3 + (x - centre) w) / w^2
        w = 0.5 * (1.0 - xi[2])
        iw2 = 1.0 / (w * w)
        x = x * iw2
        g1 = g1 * iw2
        g2 = g2 * iw2
        g3 = (g3 + x * w) * iw2
    J = wp.mat33(g1[0], g2[0], g3[0], g1[1], g2[1], g3[1], g1[2], g2[2], g3[2])
    return x + mesh.geo_centre[e], J


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
    stays in a slightly enlarged reference box; and the last inverse Jacobian dxi/dx (it turns
    the ray direction into the reference-space velocity, for warm starts and slopes)."""
    xi = xi0
    ok = float(0.0)
    Jinv = wp.identity(n=3, dtype=float)
    held_count = int(0)
    for it in range(12):
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
        # float32 reaches ~1e-7 in xi; the step before that is below 1e-5 (quadratic convergence)
        if wp.length(dxi) < NEWTON_STEP_TOL:
            ok = 1.0
            break
    return wp.vec4(xi[0], xi[1], xi[2], ok), Jinv


@wp.func
def margin_and_face(shape: int, xi: wp.vec3) -> wp.vec2:
    """(margin, face): the smallest c_f - n_f . xi over the reference faces (> 0 inside) and
    which face it is."""
    m = float(1.0e30)
    face = int(0)
    for f in range(el_k.num_faces(shape)):
        p = el_k.face_plane(shape, f)
        mf = p[3] - (p[0] * xi[0] + p[1] * xi[1] + p[2] * xi[2])
        if mf < m:
            m = mf
            face = f
    return wp.vec2(m, float(face))


@wp.func
def curved_inside(mesh: MeshArgs, e: int, o: wp.vec3, d: wp.vec3, t: float, xi0: wp.vec3):
    """(xi, margin + INSIDE_TOL) at ray parameter t: > 0 inside; -1 where Newton fails; and
    (dxi/dt, dmargin/dt) there, for warm starts one step ahead and Newton on the margin."""
    p = o + t * d
    r, Jinv = invert_point(mesh, e, p, xi0)
    if r[3] <= 0.0:  # a warm start from a bad neighbour: retry from the affine guess
        r, Jinv = invert_point(mesh, e, p, start_guess(mesh, e, p))
    xi = wp.vec3(r[0], r[1], r[2])
    v = Jinv * d
    m = float(-1.0)
    slope = float(0.0)
    if r[3] > 0.0:
        mf = margin_and_face(mesh.shape[e], xi)
        m = mf[0] + INSIDE_TOL
        pl = el_k.face_plane(mesh.shape[e], int(mf[1]))
        slope = -(pl[0] * v[0] + pl[1] * v[1] + pl[2] * v[2])
    return wp.vec4(xi[0], xi[1], xi[2], m), wp.vec4(v[0], v[1], v[2], slope)


@wp.func
def ahead(r: wp.vec4, dv: wp.vec4, dt: float) -> wp.vec3:
    """Warm start dt further along the ray from a solved point (xi, velocity), kept in Newton's box."""
    y = wp.vec3(r[0], r[1], r[2])
    if r[3] > -1.0:
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


@wp.func
def boundary_crossing(mesh: MeshArgs, e: int, o: wp.vec3, d: wp.vec3, t_out: float, m_out: float, t_in: float,
                      r_in: wp.vec4, dv_in: wp.vec4):
    """Where the ray crosses element e's boundary between t_out (margin m_out <= 0) and t_in
    (solution r_in inside, velocity dv_in): an inside point within ROOT_RTOL relative of the
    crossing, with its solution and velocity (curved_inside's), as (t, r, dv). The margin is
    smooth across one face and its slope is known, so Newton steps on it are taken while they
    stay inside the bracket, with Illinois regula falsi otherwise (a failed Newton solve's
    margin of -1 only slows it). The solution is the one found there: solving again at that t
    can land a rounding error on the other side of the face."""
    a = t_out
    fa = m_out
    b = t_in
    fb = r_in[3]
    g = wp.vec3(r_in[0], r_in[1], r_in[2])
    rb = r_in
    dvb = dv_in
    side = int(0)
    have = int(0)  # a converged last evaluation: its t, margin, slope and solution
    tl = float(0.0)
    ml = float(0.0)
    rl = wp.vec4(0.0, 0.0, 0.0, 0.0)
    dvl = wp.vec4(0.0, 0.0, 0.0, 0.0)
    for it in range(40):
        tol = ROOT_RTOL * (wp.abs(a) + wp.abs(b)) + 1.0e-30
        if wp.abs(b - a) <= tol:
            break
        m = 0.5 * (a + b)
        if fb != fa:
            m = b - fb * (b - a) / (fb - fa)
            # stay strictly inside the bracket, and halve when falsi would crawl along one end
            lim = 0.01 * wp.abs(b - a)
            if wp.abs(m - a) < lim or wp.abs(m - b) < lim:
                m = 0.5 * (a + b)
        start = g
        if have == 1:
            start = ahead(rl, dvl, m - tl)
            if dvl[3] != 0.0:
                tn = tl - ml / dvl[3]
                if tn > wp.min(a, b) and tn < wp.max(a, b):
                    m = tn
                    start = ahead(rl, dvl, m - tl)
        rm, dvm = curved_inside(mesh, e, o, d, m, start)
        have = int(0)
        if rm[3] > -1.0:
            have = 1
            tl = m
            ml = rm[3]
            rl = rm
            dvl = dvm
        if rm[3] > 0.0:
            b = m
            fb = rm[3]
            g = wp.vec3(rm[0], rm[1], rm[2])
            rb = rm
            dvb = dvm
            if side == 1:
                fa = 0.5 * fa
            side = 1
            # inside, and Newton says the crossing is within the tolerance: done
            if dvm[3] != 0.0 and wp.abs(rm[3] / dvm[3]) <= tol:
                break
        else:
            a = m
            fa = rm[3]
            if side == -1:
                fb = 0.5 * fb
            side = -1
    return b, rb, dvb


@wp.func
def tangent_face_step(shape: int, xi: wp.vec3, v: wp.vec3) -> float:
    """How far along the ray (t units) the tangent line xi + s v reaches the first reference
    face it is heading for (1e30 if none): the predictor of curved_exit."""
    best = float(1.0e30)
    for f in range(el_k.num_faces(shape)):
        p = el_k.face_plane(shape, f)
        rate = p[0] * v[0] + p[1] * v[1] + p[2] * v[2]
        if rate > 0.0:
            s = (p[3] - (p[0] * xi[0] + p[1] * xi[1] + p[2] * xi[2])) / rate
            best = wp.min(best, wp.max(s, 0.0))
    return best


@wp.func
def curved_exit(mesh: MeshArgs, e: int, o: wp.vec3, d: wp.vec3, t_in: float, r_in: wp.vec4, dv_in: wp.vec4,
                t_end: float):
    """The ray is inside curved element e at t_in (solution r_in, velocity dv_in): where it
    leaves, as (t_exit, exit face or -1, its solution) and the velocity there. Steps go to the
    face the tangent predicts (a little beyond it, at most half the box chord at a time) until
    one lands outside; the crossing is then found by boundary_crossing. Reaching t_end (the
    box's or the ray's end) inside ends the stretch there with face -1."""
    t = t_in
    r = r_in
    dv = dv_in
    span = t_end - t_in
    shape = mesh.shape[e]
    for step in range(MAX_EXIT_STEPS):
        s = tangent_face_step(shape, wp.vec3(r[0], r[1], r[2]), wp.vec3(dv[0], dv[1], dv[2]))
        dt = wp.min(s * (1.0 + EXIT_OVERSHOOT) + 1.0e-4 * span, 0.5 * span)
        t_new = wp.min(t + dt, t_end)
        r_new, dv_new = curved_inside(mesh, e, o, d, t_new, ahead(r, dv, t_new - t))
        if r_new[3] > 0.0:
            t = t_new
            r = r_new
            dv = dv_new
            if t >= t_end:
                return wp.vec3(t_end, -1.0, 0.0), r, dv
        else:
            tc, rc, dvc = boundary_crossing(mesh, e, o, d, t_new, r_new[3], t, r, dv)
            mf = margin_and_face(shape, wp.vec3(rc[0], rc[1], rc[2]))
            return wp.vec3(tc, mf[1], 0.0), rc, dvc
    return wp.vec3(t, -1.0, 0.0), r, dv


@wp.func
def curved_entry(mesh: MeshArgs, e: int, o: wp.vec3, d: wp.vec3, t_from: float):
    """Where the ray first is inside curved element e beyond t_from: (found, t, 0) and the
    solution and velocity there (for curved_exit). Samples of the box interval
    (CURVED_SAMPLES) find an inside point; before the first one the entry is located to
    ROOT_RTOL relative. With no sample inside but the margin close, a clip thinner than the
    sample spacing may hide next to the best sample: the margin's peak there is ternary-
    searched. A thinner stretch can be missed; the traversal asks again beyond its t, so a
    later re-entry is still found."""
    none = wp.vec4(0.0, 0.0, 0.0, -1.0)
    bi = box_interval(mesh, e, o, d)
    ta = wp.max(bi[0], t_from)
    tb = bi[1]
    if tb <= ta:
        return wp.vec3(0.0, 0.0, 0.0), none, none
    xi = start_guess(mesh, e, o + ta * d)
    n_samples = int(CURVED_SAMPLES)  # a local int: Warp retypes a global cast in place (float64 twin)
    dt = (tb - ta) / float(n_samples)
    prev_t = ta
    prev_r = wp.vec4(xi[0], xi[1], xi[2], -1.0)
    prev_dv = wp.vec4(0.0, 0.0, 0.0, 0.0)
    best_r = prev_r
    best_t = ta
    # the bracket handed to boundary_crossing: outside at t_out, inside at t_in
    t_out = float(0.0)
    m_out = float(-1.0)
    t_in = float(0.0)
    r_in = prev_r
    dv_in = prev_dv
    found = int(0)
    for i in range(n_samples + 1):
        t = ta + float(i) * dt
        r, dv = curved_inside(mesh, e, o, d, t, ahead(prev_r, prev_dv, t - prev_t))
        if r[3] > best_r[3]:
            best_r = r
            best_t = t
        if r[3] > 0.0:
            if i == 0:
                return wp.vec3(1.0, t, 0.0), r, dv
            found = 1
            t_out = prev_t
            m_out = prev_r[3]
            t_in = t
            r_in = r
            dv_in = dv
            break
        prev_t = t
        prev_r = r
        prev_dv = dv
    if found == 0 and best_r[3] > -0.25:
        lo = wp.max(ta, best_t - dt)
        hi = wp.min(tb, best_t + dt)
        g = wp.vec3(best_r[0], best_r[1], best_r[2])
        for it in range(30):
            m1 = lo + (hi - lo) / 3.0
            m2 = hi - (hi - lo) / 3.0
            r1, dv1 = curved_inside(mesh, e, o, d, m1, g)
            r2, dv2 = curved_inside(mesh, e, o, d, m2, g)
            if r1[3] < r2[3]:
                lo = m1
                g = wp.vec3(r2[0], r2[1], r2[2])
            else:
                hi = m2
                g = wp.vec3(r1[0], r1[1], r1[2])
        tp = 0.5 * (lo + hi)
        rp, dvp = curved_inside(mesh, e, o, d, tp, g)
        if rp[3] > 0.0:
            found = 1
            t_out = wp.max(ta, best_t - dt)
            m_out = -1.0
            t_in = tp
            r_in = rp
            dv_in = dvp
    if found == 0:
        return wp.vec3(0.0, 0.0, 0.0), none, none
    tc, rc, dvc = boundary_crossing(mesh, e, o, d, t_out, m_out, t_in, r_in, dv_in)
    return wp.vec3(1.0, tc, 0.0), rc, dvc
