"""The field along one element segment as a Chebyshev series in t.

On an affine element the field along a ray is a polynomial of degree D (element.
polynomial_degree; for pyramids f w^2 with w linear along the ray), so D + 1 samples at
Chebyshev-Lobatto points of the segment give it exactly ("the restriction"); its coefficients
bound it (|f - c_0| <= sum |c_k|) and every later sample is an O(D) Clenshaw evaluation. On a
curved element the same samples give an interpolant, whose tail is the error estimate.

The sample kernel writes the samples (sample_point, then the element's evaluator), the coefficients kernel turns them into the
series (chebyshev_coefficient, one thread per coefficient) in Segments.coeffs, and the
integrate kernel evaluates it there: a series is (array, base offset, degree), never a local
vector (a vector argument is copied at every call). Its coefficients c_0 .. c_deg sit at base ..
base + deg and the pyramid weights w(t0), w(t1) right after them (series_weights), so a series
takes deg + 3 values wherever it is kept: a round's segment buffer or a ray's cached segments
(Renderer.trace).
"""
from __future__ import annotations

import warp as wp

from . import element
from . import geometry
from .args import MAX_SAMPLES, MeshArgs, Segments
from .tolerances import CURVED_TAIL_RTOL  # a curved interpolant's tail against its samples' size

wp.set_module_options({"enable_backward": False})



@wp.func
def lobatto_t(a: float, b: float, j: int, deg: int) -> float:
    """The j-th Chebyshev-Lobatto point of [a, b] (j = 0 at b, j = deg at a)."""
    return 0.5 * (a + b) + 0.5 * (b - a) * wp.cos(wp.pi * float(j) / float(deg))


@wp.func
def chebyshev_coefficient(segs: Segments, slot: int, k: int, deg: int) -> float:
    """c_k of the interpolant through the slot's samples f_j = f(cos(pi j / deg)):
    (2 / deg) sum'' f_j cos(pi j k / deg), the cosines by their three-term recurrence in j
    (one cosine per coefficient); c_0 and c_deg halved."""
    base = slot * MAX_SAMPLES
    fd = float(deg)
    ca = wp.cos(wp.pi * float(k) / fd)
    cos_prev = ca  # cos(-a)
    cos_j = float(1.0)
    acc = float(0.0)
    for j in range(deg + 1):
        w = float(1.0)
        if j == 0 or j == deg:
            w = 0.5
        acc += w * segs.samples[base + j] * cos_j
        cos_next = 2.0 * ca * cos_j - cos_prev
        cos_prev = cos_j
        cos_j = cos_next
    acc = acc * 2.0 / fd
    if k == 0 or k == deg:
        acc = 0.5 * acc
    return acc


@wp.func
def clenshaw(coeffs: wp.array(dtype=wp.float32), base: int, deg: int, s: float) -> float:
    """The series coeffs[base .. base + deg] at s in [-1, 1]."""
    b1 = float(0.0)
    b2 = float(0.0)
    k = deg
    while k >= 1:
        b0 = coeffs[base + k] + 2.0 * s * b1 - b2
        b2 = b1
        b1 = b0
        k -= 1
    return coeffs[base] + s * b1 - b2


@wp.func
def clenshaw_with_slope(coeffs: wp.array(dtype=wp.float32), base: int, deg: int, s: float) -> wp.vec2:
    """(g(s), g'(s)) of the series in one pass (the recurrence differentiated in s)."""
    b1 = float(0.0)
    b2 = float(0.0)
    d1 = float(0.0)
    d2 = float(0.0)
    k = deg
    while k >= 1:
        b0 = coeffs[base + k] + 2.0 * s * b1 - b2
        d0 = 2.0 * b1 + 2.0 * s * d1 - d2
        b2 = b1
        b1 = b0
        d2 = d1
        d1 = d0
        k -= 1
    return wp.vec2(coeffs[base] + s * b1 - b2, b1 + s * d1 - d2)


@wp.func
def clenshaw_and_integral(coeffs: wp.array(dtype=wp.float32), base: int, deg: int, s: float) -> wp.vec2:
    """(the series at s, clenshaw_integral at s) in one pass: both recurrences share each
    coefficient's load, which is what a Gauss-Kronrod node with exact optical depth needs."""
    b1 = float(0.0)  # value recurrence
    b2 = float(0.0)
    i1 = float(0.0)  # antiderivative recurrence
    i2 = float(0.0)
    c_k = float(0.0)  # coeffs[k] and coeffs[k + 1] of the step before, loaded once
    c_kp = float(0.0)
    k = deg + 1
    while k >= 1:
        cm = coeffs[base + k - 1]
        g = float(0.0)
        if k == 1:
            g = cm - 0.5 * c_kp
        else:
            g = (cm - c_kp) / (2.0 * float(k))
        i0 = g + 2.0 * s * i1 - i2
        i2 = i1
        i1 = i0
        b0 = c_k + 2.0 * s * b1 - b2
        b2 = b1
        b1 = b0
        c_kp = c_k
        c_k = cm
        k -= 1
    return wp.vec2(c_k + s * b1 - b2, s * i1 - i2)


@wp.func
def clenshaw_integral(coeffs: wp.array(dtype=wp.float32), base: int, deg: int, s: float) -> float:
    """An antiderivative in s of the series coeffs[base .. base + deg]: sum_{k>=1} G_k T_k(s) with
    G_1 = c_0 - c_2 / 2 and G_k = (c_k-1 - c_k+1) / (2 k) (c_0 already halved)."""
    return clenshaw_and_integral(coeffs, base, deg, s)[1]


@wp.func
def series_weights(coeffs: wp.array(dtype=wp.float32), base: int, deg: int) -> wp.vec2:
    """(w(t0), w(t1)) of the series at coeffs[base ..] of degree deg: the pyramid weights at the
    segment's ends (1 but for pyramids), kept right after its coefficients."""
    return wp.vec2(coeffs[base + deg + 1], coeffs[base + deg + 2])


@wp.func
def restriction_at(coeffs: wp.array(dtype=wp.float32), base: int, deg: int, a: float, b: float, t: float) -> float:
    """f(t) = g(s) / w(s)^2 (w = 1 but for pyramids), s the position of t in [a, b]; the
    series at coeffs[base ..] with its weights w(a), w(b) (series_weights)."""
    s = wp.clamp((2.0 * t - a - b) / (b - a), -1.0, 1.0)
    ws = series_weights(coeffs, base, deg)
    wa = ws[0]
    wb = ws[1]
    w = wp.max(wa + 0.5 * (s + 1.0) * (wb - wa), 1.0e-6)
    return clenshaw(coeffs, base, deg, s) / (w * w)


@wp.func
def segment_bounds(coeffs: wp.array(dtype=wp.float32), base: int, deg: int, err: float) -> wp.vec2:
    """(lo, hi) enclosing f on the whole segment: |g - c_0| <= sum |c_k| (with a float32
    rounding margin), widened by `err` (the samples' rounding, mesh.field_err scaled by the
    Lebesgue constant of the points), divided by w^2 in interval arithmetic (w linear and
    positive)."""
    ws = series_weights(coeffs, base, deg)
    wa = ws[0]
    wb = ws[1]
    if wa == 1.0 and wb == 1.0:  # no pyramid weight: f = g
        rad = float(0.0)
        for k in range(1, deg + 1):
            rad += wp.abs(coeffs[base + k])
        rad = rad * 1.000001 + 1.0e-6 * wp.abs(coeffs[base]) + err
        return wp.vec2(coeffs[base] - rad, coeffs[base] + rad)
    return pyramid_segment_bounds(coeffs, base, deg, err, wa, wb)


@wp.func
def pyramid_segment_bounds(coeffs: wp.array(dtype=wp.float32), base: int, deg: int, err: float, wa: float,
                           wb: float) -> wp.vec2:
    """segment_bounds where f = g / w^2: f = m + (g - m w^2) / w^2 with m the value at the
    middle, so the interval division acts on the variation only and the bound moves with the
    field when a constant is added to it (a bound of g / w^2 itself grows with the field's offset).
    w = alpha + beta s, so w^2 = (alpha^2 + beta^2 / 2) T_0 + 2 alpha beta T_1 + beta^2 / 2 T_2."""
    alpha = 0.5 * (wa + wb)
    beta = 0.5 * (wb - wa)
    m = float(0.0)
    if alpha > 1.0e-3:
        m = clenshaw(coeffs, base, deg, 0.0) / (alpha * alpha)
    w2_1 = 2.0 * alpha * beta
    w2_2 = 0.5 * beta * beta
    centre = coeffs[base] - m * (alpha * alpha + w2_2)
    rad = float(0.0)
    for k in range(1, deg + 1):
        c = coeffs[base + k]
        if k == 1:
            c = c - m * w2_1
        if k == 2:
            c = c - m * w2_2
        rad += wp.abs(c)
    if deg < 2:
        rad += wp.abs(m * w2_2)
    if deg < 1:
        rad += wp.abs(m * w2_1)
    rad = rad * 1.000001 + 1.0e-6 * (wp.abs(coeffs[base]) + wp.abs(m) * (alpha * alpha + beta * beta)) + err
    glo = centre - rad
    ghi = centre + rad
    # w as restriction_at evaluates it: held to >= 1e-6 (both ends 0: a segment at the apex)
    w2lo = wp.max(wp.min(wa, wb), 1.0e-6)
    w2hi = wp.max(wp.max(wa, wb), 1.0e-6)
    w2lo = w2lo * w2lo
    w2hi = w2hi * w2hi
    return wp.vec2(wp.min(glo / w2lo, glo / w2hi) + m, wp.max(ghi / w2lo, ghi / w2hi) + m)


# ------------------------------------------------------------------ writing samples


@wp.func
def eval_field(mesh: MeshArgs, e: int, xi: wp.vec3) -> float:
    """Field of element e at reference point xi (any shape; element.py)."""
    return element.eval_element(mesh.shape[e], mesh.coeffs, mesh.coeff_offset[e], mesh.modes[e], xi)


@wp.func
def restriction_degree(mesh: MeshArgs, e: int) -> int:
    return element.polynomial_degree(mesh.shape[e], mesh.modes[e])


@wp.func
def curved_base_degree(mesh: MeshArgs, e: int) -> int:
    """First Chebyshev degree for a curved segment: half the field's degree plus the map's (the
    refine kernel doubles it where the tail says so; every old point is reused). Most segments
    are a small part of their element and pass at half: paper-scale curved at 240x135 on the CPU,
    field evaluations per ray 76.6 -> 41.2 and the error against the float64 reference no worse.
    Where the doubled degree would not fit MAX_SAMPLES, the full degree at once."""
    full = wp.min(element.polynomial_degree(mesh.shape[e], mesh.modes[e]) + mesh.geo_degree[e], MAX_SAMPLES - 5)
    half = (full + 1) // 2
    if 2 * half > MAX_SAMPLES - 5:
        half = full
    return wp.max(half, 2)


@wp.func
def hermite_start(segs: Segments, slot: int, t: float) -> wp.vec3:
    """Newton's start at t in a curved segment: the cubic Hermite curve through the solutions
    and reference velocities at both ends (kept in Newton's box)."""
    a = segs.t0[slot]
    L = segs.t1[slot] - a
    s = float(0.0)
    if L > 0.0:
        s = (t - a) / L
    s2 = s * s
    s3 = s2 * s
    xi = ((2.0 * s3 - 3.0 * s2 + 1.0) * segs.xi0[slot] + ((s3 - 2.0 * s2 + s) * L) * segs.v0[slot]
          + (3.0 * s2 - 2.0 * s3) * segs.xi1[slot] + ((s3 - s2) * L) * segs.v1[slot])
    for k in range(3):
        xi[k] = wp.clamp(xi[k], -1.5, 1.5)
    return xi


@wp.func
def sample_point(mesh: MeshArgs, o: wp.vec3, d: wp.vec3, segs: Segments, slot: int, j: int, deg: int,
                 curved: int):
    """Where the slot's sample j of deg + 1 (Chebyshev-Lobatto point t_j of [t0, t1]) lies in its
    element: (xi, w, dxi/dx there, Newton's iterations); the sample is f(xi) w^2.

    Affine element: xi = A o + b + t A d (w = 1 but for pyramids): deg + 1 samples are exact for
    the element's polynomial along the ray (restriction_degree).
    Curved element: the point located by Newton from the Hermite start (from the vertex-affine
    guess if that fails), w = 1: an interpolant whose tail the refine kernel checks."""
    e = segs.element[slot]
    t = lobatto_t(segs.t0[slot], segs.t1[slot], j, deg)
    w = float(1.0)
    xi = wp.vec3(0.0, 0.0, 0.0)
    A = wp.mat33()
    newton = int(0)
    if curved == 1:
        p = o + t * d
        start = hermite_start(segs, slot, t)
        for attempt in range(2):
            r, Jinv, its = geometry.invert_point(mesh, e, p, start)
            newton += its
            xi = wp.vec3(r[0], r[1], r[2])
            A = Jinv
            if r[3] > 0.0:
                break
            start = geometry.start_guess(mesh, e, p)
    else:
        A = mesh.ref_a[e]
        xi = A * (o + t * d) + mesh.ref_b[e]
        w = element.restriction_weight(mesh.shape[e], xi)
    return xi, w, A, newton


@wp.func
def sample_at(mesh: MeshArgs, o: wp.vec3, d: wp.vec3, segs: Segments, slot: int, j: int, deg: int,
              curved: int) -> float:
    """The slot's sample j (sample_point) through the generic evaluator."""
    xi, w, A, newton = sample_point(mesh, o, d, segs, slot, j, deg, curved)
    return eval_field(mesh, segs.element[slot], xi) * w * w


@wp.func
def end_weights(mesh: MeshArgs, o: wp.vec3, d: wp.vec3, segs: Segments, slot: int, curved: int) -> wp.vec2:
    """(w(t0), w(t1)): the pyramid weights of an affine segment (1 otherwise)."""
    if curved == 1:
        return wp.vec2(1.0, 1.0)
    e = segs.element[slot]
    A = mesh.ref_a[e]
    sh = mesh.shape[e]
    return wp.vec2(element.restriction_weight(sh, A * (o + segs.t0[slot] * d) + mesh.ref_b[e]),
                   element.restriction_weight(sh, A * (o + segs.t1[slot] * d) + mesh.ref_b[e]))


@wp.func
def refine_degree(segs: Segments, slot: int, allow: int) -> int:
    """A curved slot's tail |c_deg| + |c_deg-1| against CURVED_TAIL_RTOL of its samples' size:
    small enough (or the buffer full): keep it as the error estimate and return 0; else spread
    the samples to the even points of the doubled degree (every old point is one of those) and
    return 1: the sample kernel fills the odd ones."""
    base = slot * MAX_SAMPLES
    deg = segs.degree[slot]
    cd = float(0.0)
    cd1 = float(0.0)
    scale = float(0.0)
    for j in range(deg + 1):
        f = segs.samples[base + j]
        scale = wp.max(scale, wp.abs(f))
        wj = 1.0
        if j == 0 or j == deg:
            wj = 0.5
        if j % 2 == 1:
            wj = -wj
        # T_deg(x_j) = (-1)^j, T_deg-1(x_j) = (-1)^j x_j
        cd += wj * f
        cd1 += wj * f * wp.cos(wp.pi * float(j) / float(deg))
    tail = (0.5 * wp.abs(cd) + wp.abs(cd1)) * 2.0 / float(deg)
    segs.tail[slot] = tail
    if allow == 0 or tail <= CURVED_TAIL_RTOL * scale + 1.0e-30 or 2 * deg > MAX_SAMPLES - 5:
        return 0
    k = deg
    while k >= 1:
        segs.samples[base + 2 * k] = segs.samples[base + k]
        k -= 1
    segs.degree[slot] = 2 * deg
    return 1
