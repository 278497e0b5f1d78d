"""The field along one element segment as a Chebyshev series in t.

On an affine element the field along a ray is a polynomial of degree D (element.
polynomial_degree; for pyramids f w^2 with w linear along the ray), so D + 1 samples at
Chebyshev-Lobatto points of the segment give it exactly ("the restriction"); its coefficients
bound it (|f - c_0| <= sum |c_k|) and every later sample is an O(D) Clenshaw evaluation. On a
curved element the same samples give an interpolant, whose tail is the error estimate.

The traverse kernel writes the samples (write_*), the integrate kernel turns them into
coefficients (chebyshev_from_samples) and evaluates them.
"""
from __future__ import annotations

import warp as wp

from . import element as el_k
from . import geometry as geo
from .args import MAX_SAMPLES, MeshArgs, Segments

wp.set_module_options({"enable_backward": False})

vecr = wp.types.vector(length=MAX_SAMPLES, dtype=wp.float32)
CURVED_TAIL_RTOL = 1.0e-6  # a curved interpolant is refined (degree doubled) above this tail


@wp.func
def lobatto_t(a: float, b: float, j: int, deg: int) -> float:
    """The j-th Chebyshev-Lobatto point of [a, b] (j = 0 at b, j = deg at a)."""
    return 0.5 * (a + b) + 0.5 * (b - a) * wp.cos(wp.pi * float(j) / float(deg))


@wp.func
def chebyshev_from_samples(segs: Segments, slot: int, deg: int) -> vecr:
    """Chebyshev coefficients c_0..c_deg of the interpolant through the segment's samples
    f_j = f(cos(pi j / deg)); the pyramid weights w(t0), w(t1) in the last two slots. T_k at
    each node by the three-term recurrence: one cosine per node."""
    c = vecr()
    base = slot * MAX_SAMPLES
    fd = float(deg)
    for j in range(deg + 1):
        x = wp.cos(wp.pi * float(j) / fd)
        w = 2.0 / fd
        if j == 0 or j == deg:
            w = 1.0 / fd
        fj = w * segs.samples[base + j]
        tkm = float(1.0)
        tk = x
        c[0] = c[0] + fj
        for k in range(1, deg + 1):
            c[k] = c[k] + fj * tk
            tkn = 2.0 * x * tk - tkm
            tkm = tk
            tk = tkn
    c[0] = 0.5 * c[0]
    c[deg] = 0.5 * c[deg]
    c[MAX_SAMPLES - 2] = segs.samples[base + MAX_SAMPLES - 2]
    c[MAX_SAMPLES - 1] = segs.samples[base + MAX_SAMPLES - 1]
    return c


@wp.func
def clenshaw(c: vecr, deg: int, s: float) -> float:
    b1 = float(0.0)
    b2 = float(0.0)
    k = deg
    while k >= 1:
        b0 = c[k] + 2.0 * s * b1 - b2
        b2 = b1
        b1 = b0
        k -= 1
    return c[0] + s * b1 - b2


@wp.func
def clenshaw_with_slope(c: vecr, deg: int, s: float) -> wp.vec2:
    """(g(s), g'(s)) of the series in one pass (the recurrence differentiated in s)."""
    b1 = float(0.0)
    b2 = float(0.0)
    d1 = float(0.0)
    d2 = float(0.0)
    k = deg
    while k >= 1:
        b0 = c[k] + 2.0 * s * b1 - b2
        d0 = 2.0 * b1 + 2.0 * s * d1 - d2
        b2 = b1
        b1 = b0
        d2 = d1
        d1 = d0
        k -= 1
    return wp.vec2(c[0] + s * b1 - b2, b1 + s * d1 - d2)


@wp.func
def restriction_at(c: vecr, deg: int, a: float, b: float, t: float) -> float:
    """f(t) = g(s) / w(s)^2 (w = 1 but for pyramids), s the position of t in [a, b]."""
    s = wp.clamp((2.0 * t - a - b) / (b - a), -1.0, 1.0)
    wa = c[MAX_SAMPLES - 2]
    wb = c[MAX_SAMPLES - 1]
    w = wp.max(wa + 0.5 * (s + 1.0) * (wb - wa), 1.0e-6)
    return clenshaw(c, deg, s) / (w * w)


@wp.func
def segment_bounds(c: vecr, deg: int) -> wp.vec2:
    """(lo, hi) enclosing f on the whole segment: |g - c_0| <= sum |c_k| (with a float32
    rounding margin), divided by w^2 in interval arithmetic (w linear and positive)."""
    rad = float(0.0)
    for k in range(1, deg + 1):
        rad += wp.abs(c[k])
    rad = rad * 1.000001 + 1.0e-6 * wp.abs(c[0])
    glo = c[0] - rad
    ghi = c[0] + rad
    w2lo = wp.max(wp.min(c[MAX_SAMPLES - 2], c[MAX_SAMPLES - 1]), 1.0e-6)
    w2hi = wp.max(c[MAX_SAMPLES - 2], c[MAX_SAMPLES - 1])
    w2lo = w2lo * w2lo
    w2hi = w2hi * w2hi
    return wp.vec2(wp.min(glo / w2lo, glo / w2hi), wp.max(ghi / w2lo, ghi / w2hi))


# ------------------------------------------------------------------ writing samples


@wp.func
def eval_field(mesh: MeshArgs, e: int, xi: wp.vec3) -> float:
    """Field of element e at reference point xi (any shape; element.py)."""
    return el_k.eval_element(mesh.shape[e], mesh.coeffs, mesh.coeff_offset[e], mesh.modes[e], xi)


@wp.func
def restriction_degree(mesh: MeshArgs, e: int) -> int:
    return el_k.polynomial_degree(mesh.shape[e], mesh.modes[e])


@wp.func
def curved_base_degree(mesh: MeshArgs, e: int) -> int:
    """First Chebyshev degree for a curved segment: the field's degree plus the map's."""
    deg = wp.min(el_k.polynomial_degree(mesh.shape[e], mesh.modes[e]) + mesh.geo_degree[e], MAX_SAMPLES - 5)
    return wp.max(deg, 2)


@wp.func
def write_samples(mesh: MeshArgs, e: int, o: wp.vec3, d: wp.vec3, a: float, b: float, curved: int, r_a: wp.vec4,
                  dv_a: wp.vec4, segs: Segments, slot: int) -> wp.vec3:
    """The field along segment [a, b] of element e at Chebyshev-Lobatto points, into the slot.

    Affine element: f w^2 at restriction_degree + 1 points (xi = A o + b + t A d), and w at
    both ends: exact for the element's polynomial (w = 1 but for pyramids).
    Curved element: f at points each located by Newton started one step ahead of its
    neighbour (from the solution r_a at a). The degree starts at the field's plus the map's
    and doubles (up to the buffer) while the last two coefficients are not below
    CURVED_TAIL_RTOL of the samples' size: doubling keeps every old point (they are the even
    points of the finer set), so only the new ones are solved for.
    Returns (degree, tail estimate |c_deg| + |c_deg-1| (curved; 0 affine), field evaluations)."""
    base = slot * MAX_SAMPLES
    sh = mesh.shape[e]
    A = mesh.ref_a[e]
    xo = A * o + mesh.ref_b[e]
    xd = A * d
    deg = int(0)
    if curved == 1:
        deg = curved_base_degree(mesh, e)
    else:
        deg = restriction_degree(mesh, e)
    evals = int(0)
    tail = float(0.0)
    for attempt in range(3):
        r = r_a
        dv = dv_a
        t_prev = a
        scale = float(0.0)
        for jj in range(deg + 1):
            j = deg - jj  # from a (j = deg) to b (j = 0), each curved solve one step ahead of the last
            t = lobatto_t(a, b, j, deg)
            if attempt == 0 or j % 2 == 1:
                xi = xo + t * xd
                w = float(1.0)
                if curved == 1:
                    r, Jinv = geo.invert_point(mesh, e, o + t * d, geo.ahead(r, dv, t - t_prev))
                    v = Jinv * d
                    dv = wp.vec4(v[0], v[1], v[2], 0.0)
                    if r[3] <= 0.0:
                        r[3] = -1.0
                    t_prev = t
                    xi = wp.vec3(r[0], r[1], r[2])
                else:
                    w = el_k.restriction_weight(sh, xi)
                segs.samples[base + j] = eval_field(mesh, e, xi) * w * w
                evals += 1
            scale = wp.max(scale, wp.abs(segs.samples[base + j]))
        if curved == 0:
            break
        # the last two Chebyshev coefficients: T_deg(x_j) = (-1)^j, T_deg-1(x_j) = (-1)^j x_j
        cd = float(0.0)
        cd1 = float(0.0)
        for j in range(deg + 1):
            wj = 1.0
            if j == 0 or j == deg:
                wj = 0.5
            if j % 2 == 1:
                wj = -wj
            fj = wj * segs.samples[base + j]
            cd += fj
            cd1 += fj * wp.cos(wp.pi * float(j) / float(deg))
        tail = (0.5 * wp.abs(cd) + wp.abs(cd1)) * 2.0 / float(deg)
        if tail <= CURVED_TAIL_RTOL * scale + 1.0e-30 or 2 * deg > MAX_SAMPLES - 5:
            break
        # spread the samples to the even slots of the doubled set
        k = deg
        while k >= 1:
            segs.samples[base + 2 * k] = segs.samples[base + k]
            k -= 1
        deg = 2 * deg
    wa = float(1.0)
    wb = float(1.0)
    if curved == 0:
        wa = el_k.restriction_weight(sh, xo + a * xd)
        wb = el_k.restriction_weight(sh, xo + b * xd)
    segs.samples[base + MAX_SAMPLES - 2] = wa
    segs.samples[base + MAX_SAMPLES - 1] = wb
    return wp.vec3(float(deg), tail, float(evals))
