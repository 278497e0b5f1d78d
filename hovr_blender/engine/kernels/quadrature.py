"""Integrating one element segment (render contract §3): the transfer function, the methods'
quadratures and the segment classification of Nelson, Kirby and Haimes (2014).

- riemann / trapezoid: the named baselines, step h (march);
- classified (Algorithm 1): bound f on the segment, classify density and colour as empty /
  piecewise-smooth / smooth; skip empty segments, trapezoid with step h on piecewise-smooth
  ones (without h: each segment's own step, from a bound of the rule's error, auto_steps),
  adaptive Gauss-Kronrod (G7/K15) on smooth ones (absorption only when the colour is 0);
- split: like classified, but piecewise-smooth segments are cut at the exact crossings of the
  transfer function's breakpoints (next_cut), so every piece is smooth and gets Gauss-Kronrod.

What a ray has integrated so far travels through these functions as a RayIntegral.
"""
from __future__ import annotations

import warp as wp

from ..methods import METHOD_IDS
from .args import MeshArgs, QuadArgs, TransferArgs
from .tolerances import ROOT_RTOL
from .restriction import (clenshaw, clenshaw_and_integral, clenshaw_integral, clenshaw_with_slope, eval_field,
                          restriction_at, series_weights)

wp.set_module_options({"enable_backward": False})

METHOD_RIEMANN = METHOD_IDS["riemann"]
METHOD_TRAPEZOID = METHOD_IDS["trapezoid"]
METHOD_CLASSIFIED = METHOD_IDS["classified"]
METHOD_SPLIT = METHOD_IDS["split"]


@wp.func
def samples_segments(method: int) -> int:
    """1 for the methods that integrate each segment's series, else 0: engine/methods.py's
    samples_segments (SAMPLING_METHODS) on the device."""
    if method == METHOD_CLASSIFIED or method == METHOD_SPLIT:
        return 1
    return 0


INNER_SPECTRAL = 0
INNER_TRAPEZOID = 1

GK_STACK = 32  # adaptive Gauss-Kronrod depth-first stack
GK_MAX_DEPTH = 24
GK_MAX_PANELS = 4096  # per segment piece: bounds a ray's work where the estimate never converges
SCAN_PER_DEGREE = 2  # split: cells per degree of the restriction in the search for crossings

PanelEnds = wp.types.vector(length=GK_STACK, dtype=wp.float32)  # the panel stack's ends
PanelDepths = wp.types.vector(length=GK_STACK, dtype=wp.int32)  # ... and bisection depths
NodeValues = wp.types.vector(length=15, dtype=wp.float32)  # one value per Kronrod node


@wp.struct
class RayIntegral:
    """A ray's integrals up to where it got: the integrate kernel carries one through the ray's
    segments of the round (RayState holds it between rounds)."""

    color: wp.vec3  # C
    transmittance: wp.float32  # T
    restriction_evals: wp.float32  # evaluations of a segment's restriction (stats)
    depth: wp.float32  # the t where 1 - T first reaches 0.5 (-1 until then)
    # the accepted Gauss-Kronrod panels' error estimates and curved segments' tails, summed
    # (0 for methods without one)
    error: wp.float32
    # (t, f) at the far end of the last segment searched for isosurfaces (t -1e30: none), where
    # the next one's roots start from (isosurface.segment_events)
    surface_end: wp.vec2


# ------------------------------------------------------------------ transfer function


@wp.func
def ramp_segment(s_arr: wp.array(dtype=wp.float32), s: float, hint: int) -> wp.vec2:
    """(k, w): s lies between breakpoints k and k + 1 at fraction w, clamped at both ends.
    `hint`: a k to try first (the last lookup's, along a ray the value moves little)."""
    n = s_arr.shape[0]
    if n == 1 or s <= s_arr[0]:
        return wp.vec2(0.0, 0.0)
    if s >= s_arr[n - 1]:
        return wp.vec2(float(n - 2), 1.0)
    k = int(0)
    if hint >= 0 and hint < n - 1:
        if s_arr[hint] <= s and s <= s_arr[hint + 1]:
            k = hint
    while s_arr[k + 1] < s:
        k += 1
    return wp.vec2(float(k), (s - s_arr[k]) / (s_arr[k + 1] - s_arr[k]))


@wp.func
def tf_density_at(tf: TransferArgs, s: float, hint: int) -> wp.vec2:
    """(tau(s), the breakpoint segment it came from)."""
    if tf.density_s.shape[0] == 1:
        return wp.vec2(tf.density_tau[0], 0.0)
    kw = ramp_segment(tf.density_s, s, hint)
    k = int(kw[0])
    return wp.vec2(tf.density_tau[k] + kw[1] * (tf.density_tau[k + 1] - tf.density_tau[k]), kw[0])


@wp.func
def tf_color_at(tf: TransferArgs, s: float, hint: int) -> wp.vec4:
    """(kappa(s), the breakpoint segment it came from)."""
    if tf.color_s.shape[0] == 1:
        c = tf.color_rgb[0]
        return wp.vec4(c[0], c[1], c[2], 0.0)
    kw = ramp_segment(tf.color_s, s, hint)
    k = int(kw[0])
    c = tf.color_rgb[k] + kw[1] * (tf.color_rgb[k + 1] - tf.color_rgb[k])
    return wp.vec4(c[0], c[1], c[2], kw[0])


@wp.func
def tf_density(tf: TransferArgs, s: float) -> float:
    return tf_density_at(tf, s, -1)[0]


@wp.func
def tf_color(tf: TransferArgs, s: float) -> wp.vec3:
    c = tf_color_at(tf, s, -1)
    return wp.vec3(c[0], c[1], c[2])


@wp.func
def density_max_on(tf: TransferArgs, lo: float, hi: float) -> float:
    """max tau over [lo, hi]: a piecewise-linear maximum sits at an end or a breakpoint."""
    r = wp.max(tf_density(tf, lo), tf_density(tf, hi))
    for k in range(tf.density_s.shape[0]):
        s = tf.density_s[k]
        if s > lo and s < hi:
            r = wp.max(r, tf.density_tau[k])
    return r


@wp.func
def color_max_on(tf: TransferArgs, lo: float, hi: float) -> float:
    c0 = tf_color(tf, lo)
    c1 = tf_color(tf, hi)
    r = wp.max(wp.max(wp.max(wp.abs(c0[0]), wp.abs(c0[1])), wp.abs(c0[2])), wp.max(wp.max(wp.abs(c1[0]), wp.abs(c1[1])), wp.abs(c1[2])))
    for k in range(tf.color_s.shape[0]):
        s = tf.color_s[k]
        if s > lo and s < hi:
            q = tf.color_rgb[k]
            r = wp.max(r, wp.max(wp.max(wp.abs(q[0]), wp.abs(q[1])), wp.abs(q[2])))
    return r


@wp.func
def breakpoint_inside(s_arr: wp.array(dtype=wp.float32), lo: float, hi: float) -> int:
    for k in range(s_arr.shape[0]):
        s = s_arr[k]
        if s > lo and s < hi:
            return 1
    return 0


@wp.func
def level(tf: TransferArgs, k: int) -> float:
    """Breakpoint k of density then colour (the levels where the integrand has a kink)."""
    nd = tf.density_s.shape[0]
    if k < nd:
        return tf.density_s[k]
    return tf.color_s[k - nd]


# ------------------------------------------------------------------------ marching


@wp.func
def depth_update(depth: float, t0: float, t1: float, T0: float, T1: float) -> float:
    """First t with T = 0.5, interpolated as if extinction were constant on [t0, t1]."""
    if depth < 0.0 and T0 > 0.5 and T1 <= 0.5:
        return t0 + (t1 - t0) * wp.log(T0 / 0.5) / wp.max(wp.log(T0 / wp.max(T1, 1.0e-30)), 1.0e-30)
    return depth


@wp.func
def march(mesh: MeshArgs, tf: TransferArgs, q: QuadArgs, trapezoid: int, e: int, xo: wp.vec3, xd: wp.vec3,
          evaluate: int, coeffs: wp.array(dtype=wp.float32), base: int, deg: int, a: float, b: float, lo: float,
          hi: float, n: int, state_in: RayIntegral):
    """[lo, hi] (inside segment [a, b], the series' span) in n equal steps (fixed_steps or
    auto_steps): left Riemann sum (trapezoid = 0, samples t_0..t_n-1) or the trapezoid rule for
    both integrals (trapezoid = 1, samples t_0..t_n). Samples evaluate the element (evaluate = 1;
    xi = xo + t xd) or the restriction coeffs. Returns the new state and (element evaluations,
    restriction evaluations)."""
    state = state_in
    w = (hi - lo) / float(n)
    col = state.color
    T = state.transmittance
    depth = state.depth
    tau0 = float(0.0)
    g0 = wp.vec3(0.0, 0.0, 0.0)
    nev = int(0)
    hint_d = int(-1)
    hint_c = int(-1)
    for i in range(n + trapezoid):
        t = lo + float(i) * w
        s = float(0.0)
        if evaluate == 1:
            s = eval_field(mesh, e, xo + t * xd)
        else:
            s = restriction_at(coeffs, base, deg, a, b, t)
        nev += 1
        td = tf_density_at(tf, s, hint_d)
        tc = tf_color_at(tf, s, hint_c)
        hint_d = int(td[1])
        hint_c = int(tc[3])
        tau = td[0]
        g = tau * wp.vec3(tc[0], tc[1], tc[2])
        if trapezoid == 0:
            col += T * w * g
            T1 = T * wp.exp(-tau * w)
            depth = depth_update(depth, t, t + w, T, T1)
            T = T1
        elif i > 0:
            T1 = T * wp.exp(-0.5 * w * (tau0 + tau))
            col += 0.5 * w * (T * g0 + T1 * g)
            depth = depth_update(depth, t - w, t, T, T1)
            T = T1
        tau0 = tau
        g0 = g
        if T < q.min_transmittance:
            break
    state.color = col
    state.transmittance = T
    state.depth = depth
    if evaluate == 1:
        return state, wp.vec2(float(nev), 0.0)
    return state, wp.vec2(0.0, float(nev))


@wp.func
def fixed_steps(q: QuadArgs, a: float, b: float) -> int:
    """ceil((b - a) / h) steps of the fixed step h, at least 1 and at most q.max_steps (in floating
    point: (b - a) / h of a tiny h overflows a 32-bit int)."""
    return int(wp.clamp(wp.ceil((b - a) / q.h), 1.0, float(q.max_steps)))


@wp.func
def series_bounds(coeffs: wp.array(dtype=wp.float32), base: int, deg: int, d0: float, d1: float,
                  d2: float) -> wp.vec3:
    """Bounds of |u|, |u'| and |u''| on s in [-1, 1] for the series u = coeffs[base ..] - (d0 T_0 + d1 T_1 +
    d2 T_2): sum |c_k|; the derivative's own Chebyshev coefficients (d_k-1 = d_k+1 + 2 k c_k), summed;
    sum k^2 (k^2 - 1) / 3 |c_k| (|T_k''| peaks at the ends)."""
    d_next = float(0.0)  # the derivative's coefficients d_k+1 and d_k
    d_k = float(0.0)
    m0 = float(0.0)
    m1 = float(0.0)
    m2 = float(0.0)
    k = deg
    while k >= 0:
        c = coeffs[base + k]
        if k == 0:
            c -= d0
        elif k == 1:
            c -= d1
        elif k == 2:
            c -= d2
        m0 += wp.abs(c)
        if k >= 1:
            d_prev = d_next + 2.0 * float(k) * c
            if k == 1:
                m1 += 0.5 * wp.abs(d_prev)  # the derivative's constant term is d_0 / 2
            else:
                m1 += wp.abs(d_prev)
            d_next = d_k
            d_k = d_prev
            kk = float(k * k)
            m2 += kk * (kk - 1.0) / 3.0 * wp.abs(c)
        k -= 1
    return wp.vec3(m0, m1, m2)


@wp.func
def slope_bounds(coeffs: wp.array(dtype=wp.float32), base: int, deg: int, a: float, b: float) -> wp.vec2:
    """(M1, M2): bounds of |df/dt| and |d2f/dt2| on the segment [a, b]. For a pyramid's f = g / w^2
    (w linear, its ends after the series: series_weights) through f = m + u / w^2, u = g - m w^2 with m
    the value at the middle, so the bounds follow the variation, not the offset (pyramid_segment_bounds);
    near the apex (w -> 0) they grow without limit and auto_steps falls to its smallest step."""
    ws = series_weights(coeffs, base, deg)
    wa = ws[0]
    wb = ws[1]
    sc = 2.0 / (b - a)
    if wa == 1.0 and wb == 1.0:
        u = series_bounds(coeffs, base, deg, 0.0, 0.0, 0.0)
        return wp.vec2(u[1] * sc, u[2] * sc * sc)
    alpha = 0.5 * (wa + wb)  # w = alpha + beta s, w^2 = (alpha^2 + beta^2 / 2) T_0 + 2 alpha beta T_1 + beta^2 / 2 T_2
    beta = 0.5 * (wb - wa)
    w_min = wp.max(wp.min(wa, wb), 1.0e-6)
    m = clenshaw(coeffs, base, deg, 0.0) / wp.max(alpha * alpha, 1.0e-12)
    u = series_bounds(coeffs, base, deg, m * (alpha * alpha + 0.5 * beta * beta), m * 2.0 * alpha * beta, m * 0.5 * beta * beta)
    r = wp.abs(beta) / w_min  # |w'| / w
    m1 = (u[1] + 2.0 * u[0] * r) / (w_min * w_min)
    m2 = (u[2] + 4.0 * u[1] * r + 6.0 * u[0] * r * r) / (w_min * w_min)
    return wp.vec2(m1 * sc, m2 * sc * sc)


@wp.func
def slope_max_on(s_arr: wp.array(dtype=wp.float32), v: wp.array(dtype=wp.float32), lo: float, hi: float) -> float:
    """The steepest |slope| of the piecewise-linear (s_arr, v) over the pieces meeting [lo, hi], at
    most 1e30 (breakpoints 1e-9 apart, a ramp's step, can round to one value in float32)."""
    r = float(0.0)
    for k in range(s_arr.shape[0] - 1):
        if s_arr[k + 1] >= lo and s_arr[k] <= hi:
            r = wp.max(r, wp.abs(v[k + 1] - v[k]) / wp.max(s_arr[k + 1] - s_arr[k], 1.0e-30))
    return wp.min(r, 1.0e30)


@wp.func
def color_slope_max_on(tf: TransferArgs, lo: float, hi: float) -> float:
    """slope_max_on of the colour, the steepest channel."""
    r = float(0.0)
    for k in range(tf.color_s.shape[0] - 1):
        if tf.color_s[k + 1] >= lo and tf.color_s[k] <= hi:
            dc = tf.color_rgb[k + 1] - tf.color_rgb[k]
            gap = wp.max(tf.color_s[k + 1] - tf.color_s[k], 1.0e-30)
            r = wp.max(r, wp.max(wp.max(wp.abs(dc[0]), wp.abs(dc[1])), wp.abs(dc[2])) / gap)
    return wp.min(r, 1.0e30)


@wp.func
def breakpoints_inside(s_arr: wp.array(dtype=wp.float32), lo: float, hi: float) -> float:
    """How many breakpoints lie in (lo, hi)."""
    c = float(0.0)
    for k in range(s_arr.shape[0]):
        if s_arr[k] > lo and s_arr[k] < hi:
            c += 1.0
    return c


@wp.func
def step_error_terms(tf: TransferArgs, coeffs: wp.array(dtype=wp.float32), base: int, deg: int, a: float, b: float,
                     lo: float, hi: float, emitting: int) -> wp.vec3:
    """classified's trapezoid rule on the piecewise-smooth segment [a, b] (f in [lo, hi]): its error
    with step h (emission plus T times optical depth, as a Gauss-Kronrod panel's) is at most
    T (min(x h^2, y h) + z h^2), T the transmittance at the segment's start; returns (x, y, z).

    tau and kappa are piecewise linear in f, so along the ray the integrands are smooth but for a
    kink where f crosses a breakpoint. A kink of slope jump J costs a step at most J h^2 / 8, and
    never more than h times the integrand's range (a near-vertical ramp); between kinks the rule's
    error is (b - a) h^2 / 12 times the integrand's second derivative. Both are bounded from the
    series' derivative bounds (slope_bounds) and the transfer function's values and slopes over
    [lo, hi], one crossing per breakpoint inside it."""
    m = slope_bounds(coeffs, base, deg, a, b)
    m1 = m[0]
    s_tau = slope_max_on(tf.density_s, tf.density_tau, lo, hi)
    tau_max = density_max_on(tf, lo, hi)
    s_col = float(0.0)
    col_max = float(0.0)
    kinks = breakpoints_inside(tf.density_s, lo, hi)
    if emitting == 1:
        s_col = color_slope_max_on(tf, lo, hi)
        col_max = color_max_on(tf, lo, hi)
        kinks += breakpoints_inside(tf.color_s, lo, hi)
    # |d(tau kappa)/df| and the two integrands' slopes in f (emission tau kappa T, optical depth tau)
    s_emit = s_tau * col_max + tau_max * s_col
    s_both = s_emit + s_tau
    # between kinks: |(T tau kappa)''| + |tau''| with T' = -tau T and tau'' = kappa'' = 0 in f
    second = s_both * m[1] + 2.0 * s_tau * s_col * m1 * m1 + 2.0 * tau_max * s_emit * m1 \
        + s_tau * m1 * tau_max * col_max + tau_max * tau_max * tau_max * col_max
    # per kink: s_both m1 h^2 / 4 (the slope jumps by at most twice the slope), or h times the range
    return wp.vec3(kinks * s_both * m1 / 4.0, kinks * tau_max * (1.0 + col_max), (b - a) * second / 12.0)


@wp.func
def auto_steps(q: QuadArgs, terms: wp.vec3, a: float, b: float, T: float) -> wp.vec2:
    """classified without a fixed step: (n, bound) for a piecewise-smooth segment [a, b] whose
    step_error_terms are `terms` and whose transmittance at the start is T: the fewest steps whose
    error bound is at most q.step_error, no step below q.h_min; and the bound at that step."""
    ell = b - a
    target = q.step_error
    x = T * terms[0]
    y = T * terms[1]
    z = T * terms[2]
    h = ell
    if x + z > 0.0:
        h = wp.sqrt(target / (x + z))
        if y > 0.0 and z > 0.0:
            h = wp.max(h, wp.min(0.5 * target / y, wp.sqrt(0.5 * target / z)))
        elif y > 0.0:
            h = wp.max(h, target / y)
    step = q.h_min  # also where h is NaN (0 times an overflowed slope)
    if h > q.h_min:
        step = h
    n = int(wp.clamp(wp.ceil(ell / step), 1.0, float(q.max_steps)))
    hs = ell / float(n)
    bound = wp.min(x * hs * hs, y * hs) + z * hs * hs
    if wp.isnan(bound):  # only from 0 times an overflowed factor: that term is 0
        bound = 0.0
    return wp.vec2(float(n), bound)


@wp.func
def linear_piece(s_arr: wp.array(dtype=wp.float32), vals: wp.array(dtype=wp.float32), s: float) -> wp.vec4:
    """The piece of a piecewise-linear function around s: (value at s = v0 + slope * s: v0,
    slope, and the piece's ends in s). Outside the breakpoints it is constant to infinity."""
    n = s_arr.shape[0]
    if n == 1:
        return wp.vec4(vals[0], 0.0, -1.0e30, 1.0e30)
    if s <= s_arr[0]:
        return wp.vec4(vals[0], 0.0, -1.0e30, s_arr[0])
    if s >= s_arr[n - 1]:
        return wp.vec4(vals[n - 1], 0.0, s_arr[n - 1], 1.0e30)
    k = int(0)
    while s_arr[k + 1] < s:
        k += 1
    slope = (vals[k + 1] - vals[k]) / (s_arr[k + 1] - s_arr[k])
    return wp.vec4(vals[k] - slope * s_arr[k], slope, s_arr[k], s_arr[k + 1])


@wp.func
def piece_ends(s_arr: wp.array(dtype=wp.float32), s: float) -> wp.vec2:
    """The breakpoints around s (-1e30 / 1e30 beyond the first / last)."""
    n = s_arr.shape[0]
    if s <= s_arr[0]:
        return wp.vec2(-1.0e30, s_arr[0])
    if s >= s_arr[n - 1]:
        return wp.vec2(s_arr[n - 1], 1.0e30)
    k = int(0)
    while s_arr[k + 1] < s:
        k += 1
    return wp.vec2(s_arr[k], s_arr[k + 1])


@wp.struct
class Panel:
    """One Gauss-Kronrod panel's sums (gauss_kronrod_panel): the emission's K15 and G7 sums (to
    be scaled by T half) and the optical depth across the panel by each rule."""

    emission: wp.vec3
    emission_gauss: wp.vec3
    depth: wp.float32
    depth_gauss: wp.float32


@wp.func
def node_emission(tf: TransferArgs, s: float, tau: float, inner: float, hint: int):
    """tau kappa(s) exp(-inner) at a node (inner: the optical depth from the panel's start), and
    the colour lookup's breakpoint segment (the next lookup's hint)."""
    tc = tf_color_at(tf, s, hint)
    return tau * wp.exp(-inner) * wp.vec3(tc[0], tc[1], tc[2]), int(tc[3])


@wp.func
def gauss_kronrod_panel(tf: TransferArgs, q: QuadArgs, coeffs: wp.array(dtype=wp.float32), base: int, deg: int,
                        a: float, b: float, l: float, r: float, half: float, mid: float, unweighted: int,
                        half_seg: float, mid_seg: float, emitting: int, nev: float, hint_d: int, hint_c: int):
    """The panel [l, r] (half width, middle) of segment [a, b] (half_seg, mid_seg), as
    gauss_kronrod_smooth says: its Panel, and nev (restriction evaluations) and the lookups'
    hints carried on."""
    svals = NodeValues()
    fvals = NodeValues()  # the series' antiderivative at the nodes (unweighted only)
    nev += 15.0
    for j in range(15):
        t = mid + half * q.gk_x[j]
        if unweighted == 1:
            vf = clenshaw_and_integral(coeffs, base, deg, wp.clamp((t - mid_seg) / half_seg, -1.0, 1.0))
            svals[j] = vf[0]
            fvals[j] = half_seg * vf[1]
        else:
            svals[j] = restriction_at(coeffs, base, deg, a, b, t)
    # the transfer function's pieces at the panel's middle value (node 7 is the middle)
    fm = svals[7]
    pd = linear_piece(tf.density_s, tf.density_tau, fm)
    pr = piece_ends(tf.color_s, fm)
    lin = unweighted
    for j in range(15):
        if svals[j] < wp.max(pd[2], pr[0]) or svals[j] > wp.min(pd[3], pr[1]):
            lin = 0
    ek = wp.vec3(0.0, 0.0, 0.0)
    eg = wp.vec3(0.0, 0.0, 0.0)
    dk = float(0.0)
    dg = float(0.0)
    if lin == 1:
        # tau = pd0 + pd1 f, so int_l^t tau = pd0 (t - l) + pd1 (F(t) - F(l)), F' = f
        # held to [-1, 1] like every evaluation of the series: on a segment a few ulps long,
        # the rounded l and r can map to |s| = 2, where a degree-30 series' noise grows by
        # 2^30 (H100: one pixel's optical depth of -inf, a NaN image)
        f_l = half_seg * clenshaw_integral(coeffs, base, deg, wp.clamp((l - mid_seg) / half_seg, -1.0, 1.0))
        f_r = half_seg * clenshaw_integral(coeffs, base, deg, wp.clamp((r - mid_seg) / half_seg, -1.0, 1.0))
        nev += 2.0
        dk = pd[0] * (r - l) + pd[1] * (f_r - f_l)
        dg = dk
        if emitting == 1:
            for j in range(15):
                t = mid + half * q.gk_x[j]
                sv = svals[j]
                inner = pd[0] * (t - l) + pd[1] * (fvals[j] - f_l)
                g, hint_c = node_emission(tf, sv, pd[0] + pd[1] * sv, inner, hint_c)
                ek += q.gk_wk[j] * g
                eg += q.gk_wg[j] * g
    else:
        taus = NodeValues()
        for j in range(15):
            td = tf_density_at(tf, svals[j], hint_d)
            taus[j] = td[0]
            hint_d = int(td[1])
            dk += q.gk_wk[j] * taus[j]
            dg += q.gk_wg[j] * taus[j]
        dk = dk * half
        dg = dg * half
        if emitting == 1:
            run = float(0.0)
            for j in range(15):
                inner = float(0.0)
                if q.inner == 0:
                    for i in range(15):
                        inner += q.gk_s[j, i] * taus[i]
                    inner = inner * half
                else:
                    # trapezoid over the nodes; first node from the panel start with tau_0
                    if j == 0:
                        run = taus[0] * half * (q.gk_x[0] + 1.0)
                    else:
                        run += 0.5 * half * (q.gk_x[j] - q.gk_x[j - 1]) * (taus[j] + taus[j - 1])
                    inner = run
                g, hint_c = node_emission(tf, svals[j], taus[j], inner, hint_c)
                ek += q.gk_wk[j] * g
                eg += q.gk_wg[j] * g
    p = Panel()
    p.emission = ek
    p.emission_gauss = eg
    p.depth = dk
    p.depth_gauss = dg
    return p, nev, hint_d, hint_c


@wp.func
def gauss_kronrod_smooth(
    tf: TransferArgs, q: QuadArgs, coeffs: wp.array(dtype=wp.float32), base: int, deg: int, a: float, b: float, lo: float, hi: float, emitting: int, state: RayIntegral
) -> RayIntegral:
    """Adaptive G7/K15 over [lo, hi] (inside segment [a, b]) where kappa and tau are smooth.

    Depth-first, left half first, so panels finish front to back and each panel starts
    from the exact transmittance of everything before it. Where every node's value lies on
    the transfer function's piece at the panel's middle (the usual case: the pieces are cut
    at breakpoint crossings) and f is the series itself (no pyramid weight), tau is linear in
    f and the optical depth to each node is exact, from the series' antiderivative; the
    emission alone is a quadrature, accepted when its G7/K15 difference is below tol.
    Otherwise the optical depth to each node comes from the spectral integration matrix (or
    the paper's trapezoid rule over the nodes) and the panel's error adds T times the G7/K15
    difference of its optical depth. Loops are not unrolled: the nodes' values go through a
    local array, which keeps this kernel's registers down."""
    col = state.color
    T = state.transmittance
    nev = state.restriction_evals
    depth_t = state.depth
    err_sum = state.error
    stack_l = PanelEnds()
    stack_r = PanelEnds()
    stack_d = PanelDepths()
    stack_l[0] = lo
    stack_r[0] = hi
    stack_d[0] = 0
    top = int(1)
    hint_d = int(-1)  # the breakpoint segments of the last lookups (between breakpoints: all of them)
    hint_c = int(-1)
    unweighted = int(0)  # f is the series (w = 1): its antiderivative gives exact optical depths
    ws = series_weights(coeffs, base, deg)
    if ws[0] == 1.0 and ws[1] == 1.0:
        unweighted = 1
    half_seg = 0.5 * (b - a)
    mid_seg = 0.5 * (a + b)
    panels = int(0)
    while top > 0:
        top -= 1
        l = stack_l[top]
        r = stack_r[top]
        depth = stack_d[top]
        half = 0.5 * (r - l)
        mid = 0.5 * (r + l)
        p, nev, hint_d, hint_c = gauss_kronrod_panel(tf, q, coeffs, base, deg, a, b, l, r, half, mid, unweighted,
                                                     half_seg, mid_seg, emitting, nev, hint_d, hint_c)
        ek = p.emission * (T * half)
        eg = p.emission_gauss * (T * half)
        diff = ek - eg
        err = wp.max(wp.max(wp.abs(diff[0]), wp.abs(diff[1])), wp.abs(diff[2])) + T * wp.abs(p.depth - p.depth_gauss)
        panels += 1
        # a panel is accepted when converged, at the depth limit, or when the segment's panel
        # budget is spent or the estimate is not a number (NaN never compares below tol, and
        # 2^GK_MAX_DEPTH panels of one segment would hold the ray for minutes)
        if err <= q.tol or depth >= GK_MAX_DEPTH or top + 2 > GK_STACK or panels >= GK_MAX_PANELS or wp.isnan(err):
            col += ek
            T1 = T * wp.exp(-p.depth)
            depth_t = depth_update(depth_t, l, r, T, T1)
            err_sum += err
            T = T1
            if T < q.min_transmittance:
                break
        else:
            stack_l[top] = mid
            stack_r[top] = r
            stack_d[top] = depth + 1
            stack_l[top + 1] = l
            stack_r[top + 1] = mid
            stack_d[top + 1] = depth + 1
            top += 2
    out = RayIntegral()
    out.color = col
    out.transmittance = T
    out.restriction_evals = nev
    out.depth = depth_t
    out.error = err_sum
    out.surface_end = state.surface_end
    return out


# ------------------------------------------------------------------- breakpoint cuts


@wp.func
def level_crossing(coeffs: wp.array(dtype=wp.float32), base: int, deg: int, a: float, b: float, t0: float, t1: float, f0: float, f1: float,
                   lvl: float) -> wp.vec2:
    """(t, evaluations): t in [t0, t1] where the restriction crosses `lvl` (f0, f1 on opposite
    sides). Illinois regula falsi: bracketing like bisection, superlinear on a monotone piece."""
    lo = t0
    hi = t1
    flo = f0 - lvl
    fhi = f1 - lvl
    nev = float(0.0)
    side = int(0)
    m = 0.5 * (lo + hi)
    for it in range(48):
        m = 0.5 * (lo + hi)
        if fhi != flo:
            m = wp.clamp((lo * fhi - hi * flo) / (fhi - flo), lo, hi)
        fm = restriction_at(coeffs, base, deg, a, b, m) - lvl
        nev += 1.0
        if fm == 0.0:
            break
        if (fm < 0.0) == (flo < 0.0):
            lo = m
            flo = fm
            if side == -1:
                fhi = 0.5 * fhi
            side = -1
        else:
            hi = m
            fhi = fm
            if side == 1:
                flo = 0.5 * flo
            side = 1
        if hi - lo <= ROOT_RTOL * (wp.abs(hi) + wp.abs(lo)) + 1.0e-30:
            m = 0.5 * (lo + hi)
            break
    return wp.vec2(m, nev)


@wp.func
def value_and_slope_sign(coeffs: wp.array(dtype=wp.float32), base: int, deg: int, s: float) -> wp.vec2:
    """(f, a quantity with the sign of df/ds) at s in [-1, 1], for f = g / w^2 (w linear)."""
    ws = series_weights(coeffs, base, deg)
    wa = ws[0]
    wb = ws[1]
    w = wp.max(wa + 0.5 * (s + 1.0) * (wb - wa), 1.0e-6)
    gs = clenshaw_with_slope(coeffs, base, deg, s)
    return wp.vec2(gs[0] / (w * w), gs[1] * w - gs[0] * (wb - wa))


@wp.func
def first_crossing(tf: TransferArgs, coeffs: wp.array(dtype=wp.float32), base: int, deg: int, a: float, b: float, lo: float, hi: float, f_lo: float,
                   f_hi: float, t_after: float) -> wp.vec2:
    """(t, evaluations): the first t in (t_after, hi] where f crosses a breakpoint level on the
    monotone piece [lo, hi] (f(lo) = f_lo, f(hi) = f_hi); hi itself if none. f meets the levels
    between f_lo and f_hi in their order from f_lo, so they are solved for in that order until one
    crosses beyond t_after (those before it were crossed at or before t_after: the cut just made)."""
    nev = float(0.0)
    up = float(1.0)
    if f_hi < f_lo:
        up = -1.0
    passed = f_lo  # the levels solved for so far lie between f_lo and this
    n_levels = tf.density_s.shape[0] + tf.color_s.shape[0]
    for attempt in range(n_levels):
        # the nearest level beyond `passed` toward f_hi, strictly between f_lo and f_hi
        nearest = float(0.0)
        found = int(0)
        for k in range(n_levels):
            lvl = level(tf, k)
            if (f_lo - lvl) * (f_hi - lvl) < 0.0 and up * (lvl - passed) > 0.0:
                if found == 0 or up * (lvl - nearest) < 0.0:
                    nearest = lvl
                    found = 1
        if found == 0:
            break
        bc = level_crossing(coeffs, base, deg, a, b, lo, hi, f_lo, f_hi, nearest)
        nev += bc[1]
        if bc[0] > t_after:
            return wp.vec2(wp.min(bc[0], hi), nev)
        passed = nearest
    return wp.vec2(hi, nev)


@wp.func
def level_near(tf: TransferArgs, lo: float, hi: float) -> int:
    """1 if a breakpoint level lies in [lo, hi]."""
    for k in range(tf.density_s.shape[0] + tf.color_s.shape[0]):
        lvl = level(tf, k)
        if lvl >= lo and lvl <= hi:
            return 1
    return 0


@wp.func
def next_cut(tf: TransferArgs, coeffs: wp.array(dtype=wp.float32), base: int, deg: int, a: float, b: float, t_from: float) -> wp.vec2:
    """(t, evaluations): the first breakpoint crossing of f beyond t_from on [a, b], or b.
    The segment is scanned in SCAN_PER_DEGREE * deg + 4 equal cells. Where f = g (no pyramid
    weight), M = sum k^2 |c_k| bounds |g'| (Markov), so a cell whose end values stay farther than
    M h / 2 from every level cannot cross one: it costs one evaluation. Any other cell whose
    slope changes sign is split at the critical point (bisection on the slope's sign), so each
    piece is monotone and a level is crossed there at most once, found by a sign change at its
    ends. (Two critical points in one cell are missed: a polynomial's extrema that close hide
    only a sliver of crossing.)"""
    nev = float(0.0)
    n_cells = SCAN_PER_DEGREE * deg + 4
    eps = 1.0e-7 * (b - a)
    t_after = t_from + eps
    half = 0.5 * (b - a)
    mid = 0.5 * (a + b)
    margin = float(1.0e30)  # M h / 2, or no filter (pyramids)
    ws = series_weights(coeffs, base, deg)
    if ws[0] == ws[1]:
        w2 = ws[0] * ws[0]
        lip = float(0.0)
        for k in range(1, deg + 1):
            lip += float(k * k) * wp.abs(coeffs[base + k])
        margin = lip / (w2 * float(n_cells)) * 1.0001
    s_from = wp.clamp((t_from - mid) / half, -1.0, 1.0)
    i = wp.min(int((s_from + 1.0) * 0.5 * float(n_cells)), n_cells - 1)
    su = s_from
    fu = value_and_slope_sign(coeffs, base, deg, su)
    nev += 1.0
    while i < n_cells:
        sv = -1.0 + 2.0 * float(i + 1) / float(n_cells)
        fv = value_and_slope_sign(coeffs, base, deg, sv)
        nev += 1.0
        if sv > su and level_near(tf, wp.min(fu[0], fv[0]) - margin, wp.max(fu[0], fv[0]) + margin) == 1:
            # a critical point inside: bisect the slope's sign to it
            sc = sv
            fc = fv
            if fu[1] * fv[1] < 0.0:
                lo = su
                hi = sv
                glo = fu[1]
                # to the roots' own tolerance in t (level_crossing's): beyond it the halving
                # only rounds, which float32 reaches after about 20 of the 40 steps
                for it in range(40):
                    if half * (hi - lo) <= ROOT_RTOL * (wp.abs(mid + half * lo) + wp.abs(mid + half * hi)) + 1.0e-30:
                        break
                    m = 0.5 * (lo + hi)
                    gm = value_and_slope_sign(coeffs, base, deg, m)
                    nev += 1.0
                    if (gm[1] < 0.0) == (glo < 0.0):
                        lo = m
                        glo = gm[1]
                    else:
                        hi = m
                sc = 0.5 * (lo + hi)
                fc = value_and_slope_sign(coeffs, base, deg, sc)
                nev += 1.0
            # the monotone pieces [su, sc] and [sc, sv]
            r = first_crossing(tf, coeffs, base, deg, a, b, mid + half * su, mid + half * sc, fu[0], fc[0], t_after)
            nev += r[1]
            if r[0] < mid + half * sc:
                return wp.vec2(r[0], nev)
            if sc < sv:
                r = first_crossing(tf, coeffs, base, deg, a, b, mid + half * sc, mid + half * sv, fc[0], fv[0], t_after)
                nev += r[1]
                if r[0] < mid + half * sv:
                    return wp.vec2(r[0], nev)
        su = sv
        fu = fv
        i += 1
    return wp.vec2(b, nev)
