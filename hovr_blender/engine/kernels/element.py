"""Element expansions on the device: Nektar++'s MODIFIED family for all four shapes.

Independent of the numpy oracle (engine/expansions.py); tests compare the two. Conventions:
docs/spec/formats.md §2.8-2.10 (collapsed coordinates, mode storage order, and the collapsed-
vertex corrections without which tets are off by 0.17 and prisms jump across faces).
"""
from __future__ import annotations

import numpy as np
import warp as wp

from ..shapes import HEX, MAX_MODES, PRISM, PYR, TET
from .tolerances import CLIP_TOL  # reference_clip's margin: a few ulps of 1

wp.set_module_options({"enable_backward": False})

ModeValues = wp.types.vector(length=MAX_MODES, dtype=wp.float32)  # one direction's modes


@wp.func
def jacobi_p(n: int, alpha: float, x: float) -> float:
    """Jacobi P^(alpha, 1)_n(x), three-term recurrence."""
    if n == 0:
        return 1.0
    beta = 1.0
    p0 = float(1.0)
    p1 = (alpha + 1.0) + (alpha + beta + 2.0) * (x - 1.0) * 0.5
    for k in range(2, n + 1):
        fk = float(k)
        s = 2.0 * fk + alpha + beta
        a1 = 2.0 * fk * (fk + alpha + beta) * (s - 2.0)
        a2 = (s - 1.0) * (s * (s - 2.0) * x + alpha * alpha - beta * beta)
        a3 = 2.0 * (fk + alpha - 1.0) * (fk + beta - 1.0) * s
        p2 = (a2 * p1 - a3 * p0) / a1
        p0 = p1
        p1 = p2
    return p1


@wp.func
def jacobi11_next(k: int, x: float, pm1: float, pm2: float) -> float:
    """P^(1,1)_k(x) from P_(k-1) = pm1 and P_(k-2) = pm2 (the Modified_A bubbles' recurrence)."""
    if k == 0:
        return 1.0
    if k == 1:
        return 2.0 * x
    fk = float(k)
    return ((2.0 * fk + 1.0) * (fk + 1.0) * x * pm1 - fk * (fk + 1.0) * pm2) / (fk * (fk + 2.0))


@wp.func
def modified_a_values(n: int, x: float) -> ModeValues:
    """Modified_A modes 0..n-1 at x: (1-x)/2, (1+x)/2, then bubbles (1-x)(1+x)/4 P^(1,1)_{p-2}."""
    v = ModeValues()
    v[0] = 0.5 * (1.0 - x)
    if n > 1:
        v[1] = 0.5 * (1.0 + x)
    bubble = 0.25 * (1.0 - x) * (1.0 + x)
    pm2 = float(0.0)
    pm1 = float(1.0)
    for p in range(2, n):
        pk = jacobi11_next(p - 2, x, pm1, pm2)
        v[p] = bubble * pk
        pm2 = pm1
        pm1 = pk
    return v


@wp.func
def collapsed_row(k: int, alpha: float, n: int, x: float) -> ModeValues:
    """((1-x)/2)^k times [1, (1+x)/2 P^(alpha,1)_{r-1}(x) for r >= 1], r = 0..n-1: the shared
    form of Modified_B (k = p) and ModifiedPyr_C (k = p + q - 2) in a collapsed direction."""
    v = ModeValues()
    lo = wp.pow(0.5 * (1.0 - x), float(k))
    v[0] = lo
    for r in range(1, n):
        v[r] = lo * 0.5 * (1.0 + x) * jacobi_p(r - 1, alpha, x)
    return v


@wp.func
def modified_b_row(p: int, n: int, x: float) -> ModeValues:
    """phi^B_{p,r}(x) for r = 0..n-1 (p = 0: Modified_A; p >= 1: ((1-x)/2)^p [(1+x)/2 P^(2p-1,1)_{r-1}])."""
    if p == 0:
        return modified_a_values(n, x)
    return collapsed_row(p, 2.0 * float(p) - 1.0, n, x)


@wp.func
def modified_pyr_c_row(p: int, q: int, n: int, x: float) -> ModeValues:
    """ModifiedPyr_C phi_{p,q,r}(x) for r = 0..n-1."""
    if p <= 1 or q <= 1:
        return modified_b_row(wp.max(p, q), n, x)
    return collapsed_row(p + q - 2, 2.0 * float(p + q) - 3.0, n, x)


@wp.func
def collapse_ratio(num: float, den: float) -> float:
    """2 num / den - 1 with the denominator clamped away from 0 (Nektar++ kNekZeroTol), and the
    result held to [-1, 1], where it lies inside the element: one rounding error next to a
    collapsed vertex (num ~ 1e-7 over den ~ 0) would otherwise give eta ~ 1e5, whose high
    powers overflow float32 and turn into NaN against the vanishing collapse factor."""
    d = den
    if wp.abs(d) < 1.0e-12:
        d = 1.0e-12
    return wp.clamp(2.0 * num / d - 1.0, -1.0, 1.0)


@wp.func
def eval_hex(coeffs: wp.array(dtype=wp.float32), off: int, m: wp.vec3i, xi: wp.vec3) -> float:
    a = modified_a_values(m[0], xi[0])
    b = modified_a_values(m[1], xi[1])
    g = modified_a_values(m[2], xi[2])
    total = float(0.0)
    for k in range(m[2]):
        plane = float(0.0)
        for j in range(m[1]):
            row = float(0.0)
            base = off + m[0] * (j + m[1] * k)
            for i in range(m[0]):
                row += a[i] * coeffs[base + i]
            plane += b[j] * row
        total += g[k] * plane
    return total


@wp.func
def eval_prism(coeffs: wp.array(dtype=wp.float32), off: int, m: wp.vec3i, xi: wp.vec3) -> float:
    eta1 = collapse_ratio(1.0 + xi[0], 1.0 - xi[2])
    a = modified_a_values(m[0], eta1)
    b = modified_a_values(m[1], xi[1])
    total = float(0.0)
    idx = off
    for p in range(m[0]):
        nr = m[2] - p
        c3 = modified_b_row(p, nr, xi[2])
        for q in range(m[1]):
            s = float(0.0)
            for r in range(nr):
                s += c3[r] * coeffs[idx + r]
            total += a[p] * b[q] * s
            if p == 0 and nr > 1:
                # singular edge: mode (0, q, 1) also carries phi_1(eta1) phi_q(xi2) (1+xi3)/2
                total += coeffs[idx + 1] * a[1] * b[q] * 0.5 * (1.0 + xi[2])
            idx += nr
    return total


@wp.func
def eval_tet(coeffs: wp.array(dtype=wp.float32), off: int, m: wp.vec3i, xi: wp.vec3) -> float:
    eta1 = collapse_ratio(1.0 + xi[0], -xi[1] - xi[2])
    eta2 = collapse_ratio(1.0 + xi[1], 1.0 - xi[2])
    eta3 = xi[2]
    a = modified_a_values(m[0], eta1)
    total = float(0.0)
    idx = off
    t01 = float(0.0)  # sum_r c_(0,1,r) phi^C_{0,1,r}(eta3), for the vertex-3 correction
    for p in range(m[0]):
        nq = m[1] - p
        b = modified_b_row(p, nq, eta2)
        for q in range(nq):
            nr = m[2] - p - q
            c3 = modified_b_row(p + q, nr, eta3)
            s = float(0.0)
            for r in range(nr):
                s += c3[r] * coeffs[idx + r]
            total += a[p] * b[q] * s
            if p == 0 and q == 1:
                t01 = s
            idx += nr
    if m[0] > 1 and m[1] > 1 and m[2] > 1:
        c1 = coeffs[off + 1]  # mode (0, 0, 1): vertex 3
        top = 0.5 * (1.0 + eta3)
        b0 = modified_b_row(0, 2, eta2)
        b1 = modified_b_row(1, 1, eta2)
        total += c1 * top * (a[0] * b0[1] + a[1] * b1[0])
        total += a[1] * b0[1] * (t01 + c1 * top)
    return total


@wp.func
def eval_pyr(coeffs: wp.array(dtype=wp.float32), off: int, m: wp.vec3i, xi: wp.vec3) -> float:
    eta1 = collapse_ratio(1.0 + xi[0], 1.0 - xi[2])
    eta2 = collapse_ratio(1.0 + xi[1], 1.0 - xi[2])
    eta3 = xi[2]
    a = modified_a_values(m[0], eta1)
    b = modified_a_values(m[1], eta2)
    total = float(0.0)
    idx = off
    for p in range(m[0]):
        for q in range(m[1]):
            nr = m[2] - wp.max(p, q)
            if nr > 0:
                c3 = modified_pyr_c_row(p, q, nr, eta3)
                s = float(0.0)
                for r in range(nr):
                    s += c3[r] * coeffs[idx + r]
                total += a[p] * b[q] * s
                idx += nr
    if m[0] > 1 and m[1] > 1 and m[2] > 1:
        c1 = coeffs[off + 1]  # mode (0, 0, 1): the apex
        total += c1 * 0.5 * (1.0 + eta3) * (a[0] * b[1] + a[1] * b[0] + a[1] * b[1])
    return total


@wp.func
def eval_element(shape: int, coeffs: wp.array(dtype=wp.float32), off: int, m: wp.vec3i, xi: wp.vec3) -> float:
    if shape == PRISM:
        return eval_prism(coeffs, off, m, xi)
    if shape == TET:
        return eval_tet(coeffs, off, m, xi)
    if shape == PYR:
        return eval_pyr(coeffs, off, m, xi)
    return eval_hex(coeffs, off, m, xi)


# ------------------------------------------------------------------ specialised per order
# The generic evaluators above loop to runtime mode counts and index their basis vectors with
# runtime indices: on the GPU those vectors live in local memory and the loops' integer work
# bounds the sample kernel (H100 ncu: issue-bound on integer ALU). A mesh whose hexahedra and
# prisms all carry N modes per direction (the usual case: one order) gets evaluators with N
# fixed at compile time: every loop unrolls (the module's max_unroll >= N) and every index is
# a constant. Other elements of the same mesh still go through eval_element.

STATIC_MODES = range(2, 12)  # N with a specialisation: orders 1..10
_STATIC = {}


def static_modes(shape, modes) -> int:
    """N if every hexahedron and prism has modes (N, N, N) with N in STATIC_MODES (and there is at
    least one), else 0 (eval_element for all)."""
    shape = np.asarray(shape)
    modes = np.asarray(modes)
    sel = (shape == HEX) | (shape == PRISM)
    if not sel.any():
        return 0
    m = modes[sel]
    n = int(m[0, 0])
    if n not in STATIC_MODES or not (m == n).all():
        return 0
    return n


def static_evaluator(N: int):
    """eval_element with hexahedra and prisms of modes (N, N, N) unrolled (cached per N)."""
    if N in _STATIC:
        return _STATIC[N]

    @wp.func
    def modified_a_static(x: float) -> ModeValues:
        """modified_a_values(N, x) with the loop unrolled."""
        v = ModeValues()
        v[0] = 0.5 * (1.0 - x)
        v[1] = 0.5 * (1.0 + x)
        bubble = 0.25 * (1.0 - x) * (1.0 + x)
        pm2 = float(0.0)
        pm1 = float(1.0)
        for p in range(2, wp.static(N)):
            pk = jacobi11_next(p - 2, x, pm1, pm2)  # unrolled: p is a constant, its branches fold
            v[p] = bubble * pk
            pm2 = pm1
            pm1 = pk
        return v

    @wp.func
    def eval_hex_static(coeffs: wp.array(dtype=wp.float32), off: int, xi: wp.vec3) -> float:
        a = modified_a_static(xi[0])
        b = modified_a_static(xi[1])
        g = modified_a_static(xi[2])
        total = float(0.0)
        for k in range(wp.static(N)):
            plane = float(0.0)
            for j in range(wp.static(N)):
                row = float(0.0)
                base = off + wp.static(N) * (j + wp.static(N) * k)
                for i in range(wp.static(N)):
                    row += a[i] * coeffs[base + i]
                plane += b[j] * row
            total += g[k] * plane
        return total

    @wp.func
    def eval_prism_static(coeffs: wp.array(dtype=wp.float32), off: int, xi: wp.vec3) -> float:
        """eval_prism with m = (N, N, N): row p of the collapsed direction has N - p modes."""
        eta1 = collapse_ratio(1.0 + xi[0], 1.0 - xi[2])
        a = modified_a_static(eta1)
        b = modified_a_static(xi[1])
        top = 0.5 * (1.0 + xi[2])
        total = float(0.0)
        idx = off
        for p in range(wp.static(N)):
            c3 = modified_b_row(p, wp.static(N) - p, xi[2])
            s_p = float(0.0)
            for q in range(wp.static(N)):
                s = float(0.0)
                for r in range(wp.static(N)):  # unrolled: r and p are constants, the test folds
                    if r < wp.static(N) - p:
                        s += c3[r] * coeffs[idx + r]
                s_p += b[q] * s
                if p == 0:
                    # singular edge: mode (0, q, 1) also carries phi_1(eta1) phi_q(xi2) (1+xi3)/2
                    total += coeffs[idx + 1] * a[1] * b[q] * top
                idx += wp.static(N) - p
            total += a[p] * s_p
        return total

    @wp.func
    def evaluate(shape: int, coeffs: wp.array(dtype=wp.float32), off: int, m: wp.vec3i, xi: wp.vec3) -> float:
        if m[0] == wp.static(N) and m[1] == wp.static(N) and m[2] == wp.static(N):
            if shape == HEX:
                return eval_hex_static(coeffs, off, xi)
            if shape == PRISM:
                return eval_prism_static(coeffs, off, xi)
        return eval_element(shape, coeffs, off, m, xi)

    _STATIC[N] = evaluate
    return evaluate


@wp.func
def restriction_weight(shape: int, xi: wp.vec3) -> float:
    """w with f * w^2 polynomial along a straight line: pyramids are rational, 1/(1-xi3)^2."""
    if shape == PYR:
        return 0.5 * (1.0 - xi[2])
    return 1.0


@wp.func
def polynomial_degree(shape: int, m: wp.vec3i) -> int:
    """Degree along a straight line in reference space of the (weighted) expansion."""
    d0 = wp.max(m[0] - 1, 1)
    d1 = wp.max(m[1] - 1, 1)
    d2 = wp.max(m[2] - 1, 1)
    if shape == TET:
        return wp.max(wp.max(d0, d1), d2)
    if shape == PRISM:
        return wp.max(d0, d2) + d1
    if shape == PYR:
        return d0 + d1 + d2 + 2
    return d0 + d1 + d2


@wp.func
def num_faces(shape: int) -> int:
    if shape == HEX:
        return 6
    if shape == TET:
        return 4
    return 5


@wp.func
def face_plane(shape: int, f: int) -> wp.vec4:
    """Face f of the reference element as (n, c), inside where n . xi <= c. Faces 0..2 are
    xi_k = -1; then hexahedra xi_0, xi_1, xi_2 = 1; prisms xi_1 = 1, xi_0 + xi_2 = 0;
    tetrahedra xi_0 + xi_1 + xi_2 = -1; pyramids xi_0 + xi_2 = 0, xi_1 + xi_2 = 0: the device's
    copy of shapes.FACE_PLANES (tests/engine/test_adjacency.py checks the two agree)."""
    n = wp.vec3(0.0, 0.0, 0.0)
    c = float(1.0)
    if f < 3:
        n[f] = -1.0
    elif shape == HEX:
        n[f - 3] = 1.0
    elif shape == PRISM:
        if f == 3:
            n = wp.vec3(0.0, 1.0, 0.0)
        else:
            n = wp.vec3(1.0, 0.0, 1.0)
            c = 0.0
    elif shape == TET:
        n = wp.vec3(1.0, 1.0, 1.0)
        c = -1.0
    else:  # pyramid
        c = 0.0
        if f == 3:
            n = wp.vec3(1.0, 0.0, 1.0)
        else:
            n = wp.vec3(0.0, 1.0, 1.0)
    return wp.vec4(n[0], n[1], n[2], c)


@wp.func
def reference_clip(shape: int, xo: wp.vec3, xd: wp.vec3) -> wp.vec4:
    """(hit, t0, t1, exit face) of the line xo + t xd inside the reference element (a convex
    polytope): Cyrus-Beck clipping against its faces, each moved out by CLIP_TOL. Two elements
    that share a face see it through their own rounded maps, so a ray running inside that face
    can land a rounding error outside both; with the margin it is inside both, and the
    traversal counts the overlap once."""
    t0 = float(-1.0e30)
    t1 = float(1.0e30)
    hit = float(1.0)
    exit_face = int(-1)
    for f in range(num_faces(shape)):
        p = face_plane(shape, f)
        n = wp.vec3(p[0], p[1], p[2])
        num = p[3] + CLIP_TOL - wp.dot(n, xo)
        den = wp.dot(n, xd)
        if wp.abs(den) < 1.0e-30:
            if num < 0.0:
                hit = 0.0
        else:
            t = num / den
            if den > 0.0:
                if t < t1:
                    t1 = t
                    exit_face = f
            else:
                t0 = wp.max(t0, t)
    if t1 <= t0:
        hit = 0.0
    return wp.vec4(hit, t0, t1, float(exit_face))
