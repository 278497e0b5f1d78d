"""The ray kernel: one thread per pixel, render contract §3-4.

Per ray: front-to-back element segments from a BVH over element boxes (a window of the
WINDOW nearest candidates per pass, so any number of elements along a ray works without a
per-ray list; curved elements are located lazily and cached, see the kernel), then per
segment the quadrature of the chosen method:

- riemann / trapezoid: the named baselines, step h, evaluating the element field;
- classified (Nelson, Kirby, Haimes 2014, Algorithm 1): bound the field on the segment,
  classify density and colour as empty / piecewise-smooth / smooth, then skip empty
  segments, use the trapezoid rule with step h on piecewise-smooth ones, and adaptive
  Gauss-Kronrod (G7/K15) on smooth ones (absorption only when the colour is zero);
- split: like classified, but piecewise-smooth segments are cut at the exact breakpoint
  crossings, so every piece is smooth and gets adaptive Gauss-Kronrod: no step h at all.

On an affine element the field along a ray is a polynomial in t of degree
D = sum(modes - 1). classified and split recover it exactly from D + 1 field evaluations
at Chebyshev-Lobatto points (the "restriction"); bounds come from its Chebyshev
coefficients (|f - c0| <= sum |c_k|, never excludes a true value) and every later sample
is an O(D) Clenshaw evaluation instead of an O(n^3) element evaluation.

Curved and non-affine elements: Newton inversion of the map (exact Jacobian, tensor
Legendre form) locates the ray's stretch in the element and samples the field along it.

The kernel is built per specialisation (render_kernel(curved)): meshes of affine elements
get a kernel with the curved machinery compiled out.
"""
from __future__ import annotations

import warp as wp

from . import element as el_k

wp.set_module_options({"enable_backward": False})

MAX_MODES = 15  # modes per direction (degree 14)
MAX_RESTRICTION = 48  # >= 3 * (MAX_MODES - 1) + 1 Chebyshev samples
WINDOW = 8  # element intervals gathered per BVH pass
GK_STACK = 32  # adaptive Gauss-Kronrod depth-first stack
GK_MAX_DEPTH = 24

METHOD_RIEMANN = 0
METHOD_TRAPEZOID = 1
METHOD_CLASSIFIED = 2
METHOD_SPLIT = 3

INNER_SPECTRAL = 0
INNER_TRAPEZOID = 1

# per-pixel counters (stats)
STAT_FIELD_EVALS = 0  # full element field evaluations
STAT_RESTRICTION_EVALS = 1  # O(D) evaluations of the exact 1-D restriction
STAT_SEGMENTS = 2  # element segments met
STAT_EMPTY = 3  # segments skipped as empty (classified/split)
STAT_SMOOTH = 4  # segments integrated as smooth
STAT_PIECEWISE = 5  # segments integrated as piecewise-smooth
STAT_LOCATES = 6  # curved elements located along the ray (Newton sampling of the box interval)
NUM_STATS = 7
LOCATE_CACHE = 32  # curved locations a ray remembers across BVH passes

vecm = wp.types.vector(length=16, dtype=wp.float32)
vecr = wp.types.vector(length=MAX_RESTRICTION, dtype=wp.float32)
vecw = wp.types.vector(length=WINDOW, dtype=wp.float32)
vecwi = wp.types.vector(length=WINDOW, dtype=wp.int32)
vecl = wp.types.vector(length=LOCATE_CACHE, dtype=wp.float32)
vecli = wp.types.vector(length=LOCATE_CACHE, dtype=wp.int32)
vecs = wp.types.vector(length=GK_STACK, dtype=wp.float32)
vecsi = wp.types.vector(length=GK_STACK, dtype=wp.int32)
vec15 = wp.types.vector(length=15, dtype=wp.float32)
# ray state: (C.r, C.g, C.b, T, restriction evaluations so far, depth, error estimate)
# depth: t where 1 - T first reaches 0.5 (-1 until then); error: sum of accepted
# Gauss-Kronrod panel estimates (the methods' own a-posteriori error, 0 without one)
vecst = wp.types.vector(length=7, dtype=wp.float32)


@wp.struct
class MeshArgs:
    bvh: wp.uint64
    shape: wp.array(dtype=wp.int32)  # element.HEX / PRISM / TET / PYR
    ref_a: wp.array(dtype=wp.mat33)  # xi = ref_a x + ref_b (affine elements)
    ref_b: wp.array(dtype=wp.vec3)
    modes: wp.array(dtype=wp.vec3i)
    basis: wp.array(dtype=wp.int32)
    coeff_offset: wp.array(dtype=wp.int32)
    coeffs: wp.array(dtype=wp.float32)
    field_lo: wp.array(dtype=wp.float32)  # certified range of each element's field
    field_hi: wp.array(dtype=wp.float32)
    # curved / non-affine elements: (x - centre) w^2 as tensor Legendre coefficients of
    # degree geo_degree per direction (engine/tensor_geometry.py), and boxes
    affine: wp.array(dtype=wp.int32)
    geo_degree: wp.array(dtype=wp.int32)
    geo_offset: wp.array(dtype=wp.int32)
    geo_coeffs: wp.array(dtype=wp.vec3)
    geo_centre: wp.array(dtype=wp.vec3)
    box_lo: wp.array(dtype=wp.vec3)
    box_hi: wp.array(dtype=wp.vec3)


@wp.struct
class CameraArgs:
    o0: wp.vec3
    ou: wp.vec3
    ov: wp.vec3
    d0: wp.vec3
    du: wp.vec3
    dv: wp.vec3
    width: wp.int32
    height: wp.int32
    t_min: wp.float32
    t_max: wp.float32
    # Blender's clip planes measured along the view axis (zero axis: unused): per ray,
    # t in [clip_near / c, clip_far / c] with c = dot(d, clip_axis)
    clip_axis: wp.vec3
    clip_near: wp.float32
    clip_far: wp.float32


@wp.struct
class TransferArgs:
    color_s: wp.array(dtype=wp.float32)
    color_rgb: wp.array(dtype=wp.vec3)
    density_s: wp.array(dtype=wp.float32)
    density_tau: wp.array(dtype=wp.float32)


@wp.struct
class QuadArgs:
    method: wp.int32
    inner: wp.int32
    h: wp.float32
    tol: wp.float32
    min_transmittance: wp.float32
    background: wp.vec3
    gk_x: wp.array(dtype=wp.float32)  # 15 Kronrod nodes on [-1, 1], ascending
    gk_wk: wp.array(dtype=wp.float32)
    gk_wg: wp.array(dtype=wp.float32)  # zero at non-Gauss nodes
    gk_s: wp.array2d(dtype=wp.float32)  # spectral integration matrix on the nodes


# ----------------------------------------------------------------------------- bases


@wp.func
def eval_field(mesh: MeshArgs, e: int, xi: wp.vec3) -> float:
    """Field of element e at reference point xi (any shape; element.py)."""
    return el_k.eval_element(mesh.shape[e], mesh.coeffs, mesh.coeff_offset[e], mesh.modes[e], xi)


# ------------------------------------------------------------------ transfer function


@wp.func
def ramp_segment(s_arr: wp.array(dtype=wp.float32), s: float) -> wp.vec2:
    """(k, w): s lies between breakpoints k and k + 1 at fraction w, clamped at both ends."""
    n = s_arr.shape[0]
    if n == 1 or s <= s_arr[0]:
        return wp.vec2(0.0, 0.0)
    if s >= s_arr[n - 1]:
        return wp.vec2(float(n - 2), 1.0)
    k = int(0)
    while s_arr[k + 1] < s:
        k += 1
    return wp.vec2(float(k), (s - s_arr[k]) / (s_arr[k + 1] - s_arr[k]))


@wp.func
def tf_density(tf: TransferArgs, s: float) -> float:
    kw = ramp_segment(tf.density_s, s)
    k = int(kw[0])
    if tf.density_s.shape[0] == 1:
        return tf.density_tau[0]
    return tf.density_tau[k] + kw[1] * (tf.density_tau[k + 1] - tf.density_tau[k])


@wp.func
def tf_color(tf: TransferArgs, s: float) -> wp.vec3:
    kw = ramp_segment(tf.color_s, s)
    k = int(kw[0])
    if tf.color_s.shape[0] == 1:
        return tf.color_rgb[0]
    return tf.color_rgb[k] + kw[1] * (tf.color_rgb[k + 1] - tf.color_rgb[k])


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


# ------------------------------------------------------------------------- geometry


@wp.func
def element_interval(mesh: MeshArgs, e: int, o: wp.vec3, d: wp.vec3) -> wp.vec3:
    """(hit, t_enter, t_exit) of the ray in affine element e: clipping in reference space."""
    A = mesh.ref_a[e]
    return el_k.reference_interval(mesh.shape[e], A * o + mesh.ref_b[e], A * d)


@wp.func
def chebyshev_from_lobatto(f: vecr, deg: int) -> vecr:
    """Chebyshev coefficients c_0..c_deg of the interpolant through f_j = f(cos(pi j / deg))."""
    c = vecr()
    fd = float(deg)
    for k in range(deg + 1):
        acc = float(0.0)
        for j in range(deg + 1):
            wj = float(1.0)
            if j == 0 or j == deg:
                wj = 0.5
            acc += wj * f[j] * wp.cos(wp.pi * float((j * k) % (2 * deg)) / fd)
        acc = acc * 2.0 / fd
        if k == 0 or k == deg:
            acc = acc * 0.5
        c[k] = acc
    return c


# ------------------------------------------------------------ curved elements
# A non-affine element is located along the ray by Newton inversion of x(xi) at samples,
# with the entry and exit found by regula falsi on the inside/outside margin; the field along
# the ray is then interpolated at Chebyshev points (no longer exact: its tail is the error
# estimate). The map comes as a tensor Legendre polynomial (engine/tensor_geometry.py), so
# x and its Jacobian cost one pass over the coefficients, with no collapse to avoid.

CURVED_SAMPLES = 16  # samples of the box interval when looking for the element
# Tolerances sized for float32; the float64 twin gets kernels/precision.FLOAT64_CONSTANTS.
INSIDE_TOL = 1.0e-5  # reference-space margin still counted as inside (float32 noise in xi)
NEWTON_STEP_TOL = 1.0e-5  # Newton stops after a step below this (quadratic: xi then ~1e-10 off)
ROOT_RTOL = 1.0e-7  # relative bracket width where boundary and level crossings stop
MAX_GEO = 17  # Legendre values per direction (tensor_geometry.MAX_DEGREE + 1)
vecg = wp.types.vector(length=MAX_GEO, dtype=wp.float32)


@wp.func
def legendre_with_derivative(D: int, x: float):
    """L_0..L_D at x and their derivatives (L'_{k+1} = L'_{k-1} + (2k + 1) L_k)."""
    v = vecg()
    dv = vecg()
    v[0] = 1.0
    if D >= 1:
        v[1] = x
        dv[1] = 1.0
    for k in range(1, D):
        fk = float(k)
        v[k + 1] = ((2.0 * fk + 1.0) * x * v[k] - fk * v[k - 1]) / (fk + 1.0)
        dv[k + 1] = dv[k - 1] + (2.0 * fk + 1.0) * v[k]
    return v, dv


@wp.func
def geometry_with_jacobian(mesh: MeshArgs, e: int, xi_in: wp.vec3):
    """x(xi) and dx/dxi (columns d/dxi_k) of curved element e, in one pass."""
    sh = mesh.shape[e]
    xi = xi_in
    if sh == el_k.PYR:
        xi[2] = wp.min(xi[2], 0.9999)  # the apex: x w^2 is polynomial, x is not defined there
    D = mesh.geo_degree[e]
    n = D + 1
    a, da = legendre_with_derivative(D, xi[0])
    b, db = legendre_with_derivative(D, xi[1])
    c, dc = legendre_with_derivative(D, xi[2])
    x = wp.vec3(0.0, 0.0, 0.0)
    g1 = wp.vec3(0.0, 0.0, 0.0)
    g2 = wp.vec3(0.0, 0.0, 0.0)
    g3 = wp.vec3(0.0, 0.0, 0.0)
    idx = mesh.geo_offset[e]
    for k in range(n):
        p = wp.vec3(0.0, 0.0, 0.0)
        p1 = wp.vec3(0.0, 0.0, 0.0)
        p2 = wp.vec3(0.0, 0.0, 0.0)
        for j in range(n):
            s = wp.vec3(0.0, 0.0, 0.0)
            sd = wp.vec3(0.0, 0.0, 0.0)
            for i in range(n):
                cc = mesh.geo_coeffs[idx]
                idx += 1
                s += a[i] * cc
                sd += da[i] * cc
            p += b[j] * s
            p1 += b[j] * sd
            p2 += db[j] * s
        x += c[k] * p
        g1 += c[k] * p1
        g2 += c[k] * p2
        g3 += dc[k] * p
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
def centroid(shape: int) -> wp.vec3:
    if shape == el_k.PRISM:
        return wp.vec3(-1.0 / 3.0, 0.0, -1.0 / 3.0)
    if shape == el_k.TET:
        return wp.vec3(-0.5, -0.5, -0.5)
    if shape == el_k.PYR:
        return wp.vec3(-0.2, -0.2, -0.6)
    return wp.vec3(0.0, 0.0, 0.0)


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
def reference_margin(shape: int, xi: wp.vec3) -> float:
    """Signed distance-like margin to the reference element's faces (> 0 inside)."""
    return reference_margin_and_face(shape, xi)[0]


@wp.func
def reference_margin_and_face(shape: int, xi: wp.vec3) -> wp.vec4:
    """(margin, gradient of the nearest face's margin in xi): the margin's slope along a
    reference-space velocity v is the dot product of that gradient with v."""
    m = xi[0] + 1.0
    g = wp.vec3(1.0, 0.0, 0.0)
    if xi[1] + 1.0 < m:
        m = xi[1] + 1.0
        g = wp.vec3(0.0, 1.0, 0.0)
    if xi[2] + 1.0 < m:
        m = xi[2] + 1.0
        g = wp.vec3(0.0, 0.0, 1.0)
    if shape == el_k.HEX:
        for k in range(3):
            if 1.0 - xi[k] < m:
                m = 1.0 - xi[k]
                g = wp.vec3(0.0, 0.0, 0.0)
                g[k] = -1.0
    elif shape == el_k.PRISM:
        if 1.0 - xi[1] < m:
            m = 1.0 - xi[1]
            g = wp.vec3(0.0, -1.0, 0.0)
        if -(xi[0] + xi[2]) < m:
            m = -(xi[0] + xi[2])
            g = wp.vec3(-1.0, 0.0, -1.0)
    elif shape == el_k.TET:
        if -1.0 - (xi[0] + xi[1] + xi[2]) < m:
            m = -1.0 - (xi[0] + xi[1] + xi[2])
            g = wp.vec3(-1.0, -1.0, -1.0)
    else:
        if -(xi[0] + xi[2]) < m:
            m = -(xi[0] + xi[2])
            g = wp.vec3(-1.0, 0.0, -1.0)
        if -(xi[1] + xi[2]) < m:
            m = -(xi[1] + xi[2])
            g = wp.vec3(0.0, -1.0, -1.0)
    return wp.vec4(m, g[0], g[1], g[2])


@wp.func
def curved_inside(mesh: MeshArgs, e: int, o: wp.vec3, d: wp.vec3, t: float, xi0: wp.vec3):
    """(xi, margin + INSIDE_TOL) at ray parameter t: > 0 inside; -1 where Newton fails; and
    (dxi/dt, dmargin/dt) there, for warm starts one step ahead and Newton on the margin."""
    r, Jinv = invert_point(mesh, e, o + t * d, xi0)
    if r[3] <= 0.0:  # a warm start from a bad neighbour: retry from the element's centre
        r, Jinv = invert_point(mesh, e, o + t * d, centroid(mesh.shape[e]))
    xi = wp.vec3(r[0], r[1], r[2])
    v = Jinv * d
    m = float(-1.0)
    slope = float(0.0)
    if r[3] > 0.0:
        mf = reference_margin_and_face(mesh.shape[e], xi)
        m = mf[0] + INSIDE_TOL
        slope = wp.dot(wp.vec3(mf[1], mf[2], mf[3]), v)
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
                      m_in: float, xi_in: wp.vec3) -> float:
    """Where the ray crosses element e's boundary between t_out (margin m_out <= 0) and t_in
    (margin m_in > 0). The margin is smooth across one face and its slope is known
    (curved_inside), so Newton steps on it are taken while they stay inside the bracket,
    with Illinois regula falsi otherwise (a failed Newton solve's margin of -1 only slows it).
    Returns an inside point within 1e-7 relative of the crossing."""
    a = t_out
    fa = m_out
    b = t_in
    fb = m_in
    g = xi_in
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
    return b


@wp.func
def curved_interval(mesh: MeshArgs, e: int, o: wp.vec3, d: wp.vec3, t_from: float) -> wp.vec3:
    """(hit, t0, t1): the first stretch of the ray beyond t_from inside curved element e.
    Found on CURVED_SAMPLES samples of the box interval, ends located to 1e-7 relative;
    a stretch thinner than the sample spacing can be missed (re-entries are found on the
    traversal's next pass, which asks again beyond the current t)."""
    bi = box_interval(mesh, e, o, d)
    ta = wp.max(bi[0], t_from)
    tb = bi[1]
    if tb <= ta:
        return wp.vec3(0.0, 0.0, 0.0)
    sh = mesh.shape[e]
    xi = centroid(sh)
    n_samples = int(CURVED_SAMPLES)  # a local int: Warp retypes a global cast in place (float64 twin)
    dt = (tb - ta) / float(n_samples)
    prev_t = ta
    prev_xi = xi
    prev_m = float(-1.0)
    prev_r = wp.vec4(xi[0], xi[1], xi[2], -1.0)
    prev_dv = wp.vec4(0.0, 0.0, 0.0, 0.0)
    t_enter = float(0.0)
    entered = int(0)
    best_m = float(-1.0e30)
    best_t = ta
    best_xi = xi
    for i in range(n_samples + 1):
        t = ta + float(i) * dt
        r, dv = curved_inside(mesh, e, o, d, t, ahead(prev_r, prev_dv, t - prev_t))
        xi_t = wp.vec3(r[0], r[1], r[2])
        if r[3] > best_m:
            best_m = r[3]
            best_t = t
            best_xi = xi_t
        if entered == 0:
            if r[3] > 0.0:
                t_enter = t
                if i > 0:
                    t_enter = boundary_crossing(mesh, e, o, d, prev_t, prev_m, t, r[3], xi_t)
                entered = 1
        else:
            if r[3] <= 0.0:
                return wp.vec3(1.0, t_enter, boundary_crossing(mesh, e, o, d, t, r[3], prev_t, prev_m, prev_xi))
        prev_t = t
        prev_xi = xi_t
        prev_m = r[3]
        prev_r = r
        prev_dv = dv
    if entered == 1:
        return wp.vec3(1.0, t_enter, tb)
    if best_m > -0.25:
        # no sample inside, but the margin came close: a clip shorter than the spacing may
        # hide next to the best sample; ternary-search the margin's peak there
        lo = wp.max(ta, best_t - dt)
        hi = wp.min(tb, best_t + dt)
        g = best_xi
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
            gp = wp.vec3(rp[0], rp[1], rp[2])
            t_in = boundary_crossing(mesh, e, o, d, wp.max(ta, best_t - dt), -1.0, tp, rp[3], gp)
            t_out = boundary_crossing(mesh, e, o, d, wp.min(tb, best_t + dt), -1.0, tp, rp[3], gp)
            return wp.vec3(1.0, t_in, t_out)
    return wp.vec3(0.0, 0.0, 0.0)


@wp.func
def curved_samples(mesh: MeshArgs, e: int, o: wp.vec3, d: wp.vec3, a: float, b: float, deg: int) -> vecr:
    """Chebyshev interpolant of f(t) on [a, b] from deg + 1 Newton-located Lobatto samples;
    slot MAX-3 keeps |c_deg| + |c_deg-1| (the interpolant's error estimate), MAX-2/-1 w = 1."""
    f = vecr()
    mid = 0.5 * (a + b)
    half = 0.5 * (b - a)
    fd = float(deg)
    r = wp.vec4(0.0, 0.0, 0.0, -1.0)
    c0 = centroid(mesh.shape[e])
    r[0] = c0[0]
    r[1] = c0[1]
    r[2] = c0[2]
    dv = wp.vec4(0.0, 0.0, 0.0, 0.0)
    t_prev = a
    for jj in range(deg + 1):
        j = deg - jj  # from a to b, each Newton solve starting one step ahead of its neighbour
        t = mid + half * wp.cos(wp.pi * float(j) / fd)
        r, Jinv = invert_point(mesh, e, o + t * d, ahead(r, dv, t - t_prev))
        v = Jinv * d
        dv = wp.vec4(v[0], v[1], v[2], 0.0)
        if r[3] <= 0.0:
            r[3] = -1.0
        t_prev = t
        f[j] = eval_field(mesh, e, wp.vec3(r[0], r[1], r[2]))
    c = chebyshev_from_lobatto(f, deg)
    c[MAX_RESTRICTION - 3] = wp.abs(c[deg]) + wp.abs(c[deg - 1])
    c[MAX_RESTRICTION - 2] = 1.0
    c[MAX_RESTRICTION - 1] = 1.0
    return c


@wp.func
def curved_base_degree(mesh: MeshArgs, e: int) -> int:
    """First Chebyshev degree for a curved segment: the field's degree plus the map's."""
    deg = wp.min(el_k.polynomial_degree(mesh.shape[e], mesh.modes[e]) + mesh.geo_degree[e], MAX_RESTRICTION - 5)
    return wp.max(deg, 2)


@wp.func
def curved_restriction(mesh: MeshArgs, e: int, o: wp.vec3, d: wp.vec3, a: float, b: float) -> vecr:
    """The field along a curved segment: f(x^-1(o + t d)) is no polynomial, so it is
    interpolated at the field's degree plus the map's, and again at twice that (up to the
    vector's room) when the last two coefficients are not below 1e-6 of the sum.
    Slot MAX-4 keeps the degree used."""
    deg = curved_base_degree(mesh, e)
    c = curved_samples(mesh, e, o, d, a, b, deg)
    total = float(0.0)
    for k in range(deg + 1):
        total += wp.abs(c[k])
    if c[MAX_RESTRICTION - 3] > 1.0e-6 * total + 1.0e-30 and deg < MAX_RESTRICTION - 5:
        deg = wp.min(2 * deg, MAX_RESTRICTION - 5)
        c = curved_samples(mesh, e, o, d, a, b, deg)
    c[MAX_RESTRICTION - 4] = float(deg)
    return c


# ----------------------------------------------------------------- 1-D restriction


@wp.func
def restriction_degree(mesh: MeshArgs, e: int) -> int:
    return el_k.polynomial_degree(mesh.shape[e], mesh.modes[e])


@wp.func
def chebyshev_restriction(mesh: MeshArgs, e: int, xo: wp.vec3, xd: wp.vec3, a: float, b: float, deg: int) -> vecr:
    """Chebyshev coefficients c_0..c_deg on [a, b] of g(t) = f(t) w(t)^2, exact from deg + 1
    Lobatto samples (w = 1 except for pyramids, whose expansion is rational with w linear).
    The last two slots keep w(a), w(b) so restriction_at can divide it out again."""
    c = vecr()
    f = vecr()
    mid = 0.5 * (a + b)
    half = 0.5 * (b - a)
    sh = mesh.shape[e]
    fd = float(deg)
    for j in range(deg + 1):
        s = wp.cos(wp.pi * float(j) / fd)
        xi = xo + (mid + half * s) * xd
        w = el_k.restriction_weight(sh, xi)
        f[j] = eval_field(mesh, e, xi) * w * w
    c = chebyshev_from_lobatto(f, deg)
    c[MAX_RESTRICTION - 2] = el_k.restriction_weight(sh, xo + a * xd)
    c[MAX_RESTRICTION - 1] = el_k.restriction_weight(sh, xo + b * xd)
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
def restriction_at(c: vecr, deg: int, a: float, b: float, t: float) -> float:
    s = wp.clamp((2.0 * t - a - b) / (b - a), -1.0, 1.0)
    wa = c[MAX_RESTRICTION - 2]
    wb = c[MAX_RESTRICTION - 1]
    w = wp.max(wa + 0.5 * (s + 1.0) * (wb - wa), 1.0e-6)
    return clenshaw(c, deg, s) / (w * w)


# ------------------------------------------------------------------------ sampling


@wp.func
def sample_field(
    mesh: MeshArgs, e: int, xo: wp.vec3, xd: wp.vec3, use_restriction: int, c: vecr, deg: int, a: float, b: float, t: float
) -> float:
    if use_restriction == 1:
        return restriction_at(c, deg, a, b, t)
    return eval_field(mesh, e, xo + t * xd)


@wp.func
def depth_update(depth: float, t0: float, t1: float, T0: float, T1: float) -> float:
    """First t with T = 0.5, interpolated as if extinction were constant on [t0, t1]."""
    if depth < 0.0 and T0 > 0.5 and T1 <= 0.5:
        return t0 + (t1 - t0) * wp.log(T0 / 0.5) / wp.max(wp.log(T0 / wp.max(T1, 1.0e-30)), 1.0e-30)
    return depth


@wp.func
def march_riemann(
    mesh: MeshArgs,
    tf: TransferArgs,
    q: QuadArgs,
    e: int,
    xo: wp.vec3,
    xd: wp.vec3,
    use_restriction: int,
    c: vecr,
    deg: int,
    a: float,
    b: float,
    state: vecst,
) -> vecst:
    """Left Riemann sum with n = ceil((b - a) / h) equal steps; state = (C.rgb, T)."""
    n = wp.max(1, int(wp.ceil((b - a) / q.h)))
    w = (b - a) / float(n)
    col = wp.vec3(state[0], state[1], state[2])
    T = state[3]
    nev = state[4]
    depth = state[5]
    for i in range(n):
        t0 = a + float(i) * w
        s = sample_field(mesh, e, xo, xd, use_restriction, c, deg, a, b, t0)
        nev += float(use_restriction)
        tau = tf_density(tf, s)
        col += T * tau * w * tf_color(tf, s)
        T1 = T * wp.exp(-tau * w)
        depth = depth_update(depth, t0, t0 + w, T, T1)
        T = T1
        if T < q.min_transmittance:
            break
    return vecst(col[0], col[1], col[2], T, nev, depth, state[6])


@wp.func
def march_trapezoid(
    mesh: MeshArgs,
    tf: TransferArgs,
    q: QuadArgs,
    e: int,
    xo: wp.vec3,
    xd: wp.vec3,
    use_restriction: int,
    c: vecr,
    deg: int,
    a: float,
    b: float,
    state: vecst,
) -> vecst:
    """Trapezoid rule for both integrals with n = ceil((b - a) / h) equal steps."""
    n = wp.max(1, int(wp.ceil((b - a) / q.h)))
    w = (b - a) / float(n)
    col = wp.vec3(state[0], state[1], state[2])
    T = state[3]
    nev = state[4]
    depth = state[5]
    s0 = sample_field(mesh, e, xo, xd, use_restriction, c, deg, a, b, a)
    nev += float(use_restriction)
    tau0 = tf_density(tf, s0)
    g0 = tau0 * tf_color(tf, s0)
    for i in range(n):
        t1 = a + float(i + 1) * w
        s1 = sample_field(mesh, e, xo, xd, use_restriction, c, deg, a, b, t1)
        nev += float(use_restriction)
        tau1 = tf_density(tf, s1)
        g1 = tau1 * tf_color(tf, s1)
        T1 = T * wp.exp(-0.5 * w * (tau0 + tau1))
        col += 0.5 * w * (T * g0 + T1 * g1)
        depth = depth_update(depth, t1 - w, t1, T, T1)
        T = T1
        tau0 = tau1
        g0 = g1
        if T < q.min_transmittance:
            break
    return vecst(col[0], col[1], col[2], T, nev, depth, state[6])


@wp.func
def gauss_kronrod_smooth(
    tf: TransferArgs, q: QuadArgs, c: vecr, deg: int, a: float, b: float, lo: float, hi: float, emitting: int, state: vecst
) -> vecst:
    """Adaptive G7/K15 over [lo, hi] (inside segment [a, b]) where kappa and tau are smooth.

    Depth-first, left half first, so panels finish front to back and each panel starts
    from the exact transmittance of everything before it. Inside a panel the optical depth
    to each node comes from the spectral integration matrix (or the paper's trapezoid
    rule over the nodes). A panel is accepted when the G7/K15 difference of its emission
    plus T times that of its optical depth is below tol."""
    col = wp.vec3(state[0], state[1], state[2])
    T = state[3]
    nev = state[4]
    depth_t = state[5]
    err_sum = state[6]
    stack_l = vecs()
    stack_r = vecs()
    stack_d = vecsi()
    stack_l[0] = lo
    stack_r[0] = hi
    stack_d[0] = 0
    top = int(1)
    while top > 0:
        top -= 1
        l = stack_l[top]
        r = stack_r[top]
        depth = stack_d[top]
        half = 0.5 * (r - l)
        mid = 0.5 * (r + l)
        taus = vec15()
        svals = vec15()
        nev += 15.0
        for j in range(15):
            svals[j] = restriction_at(c, deg, a, b, mid + half * q.gk_x[j])
            taus[j] = tf_density(tf, svals[j])
        dk = float(0.0)
        dg = float(0.0)
        for j in range(15):
            dk += q.gk_wk[j] * taus[j]
            dg += q.gk_wg[j] * taus[j]
        dk = dk * half
        dg = dg * half
        ek = wp.vec3(0.0, 0.0, 0.0)
        eg = wp.vec3(0.0, 0.0, 0.0)
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
                g = taus[j] * wp.exp(-inner) * tf_color(tf, svals[j])
                ek += q.gk_wk[j] * g
                eg += q.gk_wg[j] * g
            ek = ek * (T * half)
            eg = eg * (T * half)
        diff = ek - eg
        err = wp.max(wp.max(wp.abs(diff[0]), wp.abs(diff[1])), wp.abs(diff[2])) + T * wp.abs(dk - dg)
        if err <= q.tol or depth >= GK_MAX_DEPTH or top + 2 > GK_STACK:
            col += ek
            T1 = T * wp.exp(-dk)
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
    return vecst(col[0], col[1], col[2], T, nev, depth_t, err_sum)


@wp.func
def bisect_crossing(c: vecr, deg: int, a: float, b: float, t0: float, t1: float, f0: float, level: float) -> wp.vec2:
    """(t, evaluations): t in [t0, t1] where the restriction crosses `level` (sign change at the
    ends). Illinois regula falsi: bracketing like bisection, superlinear on a monotone piece."""
    lo = t0
    hi = t1
    flo = f0 - level
    fhi = restriction_at(c, deg, a, b, t1) - level
    nev = float(1.0)
    side = int(0)
    m = 0.5 * (lo + hi)
    for it in range(48):
        m = 0.5 * (lo + hi)
        if fhi != flo:
            m = wp.clamp((lo * fhi - hi * flo) / (fhi - flo), lo, hi)
        fm = restriction_at(c, deg, a, b, m) - level
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
def chebyshev_derivative(c: vecr, deg: int) -> vecr:
    """Chebyshev coefficients of df/ds (degree deg - 1): dc_{k-1} = dc_{k+1} + 2 k c_k."""
    dc = vecr()
    k = deg
    while k >= 1:
        nxt = float(0.0)
        if k + 1 <= deg - 1:
            nxt = dc[k + 1]
        dc[k - 1] = nxt + 2.0 * float(k) * c[k]
        k -= 1
    dc[0] = 0.5 * dc[0]
    return dc


@wp.func
def slope_sign_term(c: vecr, dc: vecr, deg: int, s: float) -> float:
    """A quantity with the sign of df/ds for f = g / w^2 (w linear): g' w - 2 g w'."""
    wa = c[MAX_RESTRICTION - 2]
    wb = c[MAX_RESTRICTION - 1]
    w = wa + 0.5 * (s + 1.0) * (wb - wa)
    return clenshaw(dc, deg - 1, s) * w - 2.0 * clenshaw(c, deg, s) * 0.5 * (wb - wa)


@wp.func
def critical_points(c: vecr, deg: int, a: float, b: float) -> vecr:
    """Interior t in (a, b) where df/dt changes sign, ascending; the last slot holds their
    count and the one before it the number of derivative evaluations spent.

    Found by a sign scan of f' at 4 deg + 4 points and bisection: exact for quadratics,
    and for higher degrees it misses only pairs of critical points closer than the scan."""
    out = vecr()
    n = int(0)
    nev = int(0)
    if deg >= 2:
        dc = chebyshev_derivative(c, deg)
        nscan = 4 * deg + 4
        s0 = float(-1.0)
        g0 = slope_sign_term(c, dc, deg, s0)
        nev += nscan + 1
        for i in range(nscan):
            s1 = -1.0 + 2.0 * float(i + 1) / float(nscan)
            g1 = slope_sign_term(c, dc, deg, s1)
            if g0 * g1 < 0.0 and n < MAX_RESTRICTION - 2:
                lo = s0
                hi = s1
                glo = g0
                for it in range(40):
                    m = 0.5 * (lo + hi)
                    gm = slope_sign_term(c, dc, deg, m)
                    nev += 1
                    if (gm < 0.0) == (glo < 0.0):
                        lo = m
                        glo = gm
                    else:
                        hi = m
                out[n] = 0.5 * (a + b) + 0.25 * (b - a) * (lo + hi)
                n += 1
            s0 = s1
            g0 = g1
    out[MAX_RESTRICTION - 1] = float(n)
    out[MAX_RESTRICTION - 2] = float(nev)
    return out


# --------------------------------------------------------------------------- kernel


_KERNELS = {}


def render_kernel(curved: bool):
    """The ray kernel, specialised at compile time: with `curved` False the Newton location
    and curved sampling are compiled out (meshes of affine elements only pay for what they use)."""
    key = bool(curved)
    if key not in _KERNELS:
        _KERNELS[key] = _make_render_kernel(key)
    return _KERNELS[key]


def _make_render_kernel(CURVED: bool):
    # The curved kernel inlines Newton solves at many call sites: unrolling its fixed loops
    # costs NVRTC time, not speed (H100, hump3D 1920x1080: compile 143 s -> 103 s with
    # max_unroll 4, frame 1.52 s either way; bench/results/h100/compile_unroll.json).
    opts = {"max_unroll": 4} if CURVED else {}

    @wp.kernel(enable_backward=False, module="unique", module_options=opts)
    def render(
        mesh: MeshArgs,
        cam: CameraArgs,
        tf: TransferArgs,
        q: QuadArgs,
        pixel_offset: wp.int32,
        rgba: wp.array(dtype=wp.vec4),
        aux: wp.array(dtype=wp.vec2),
        stats: wp.array2d(dtype=wp.int32),
    ):
        # one thread per pixel of a tile starting at pixel_offset (tiles let the host cancel)
        tid = wp.tid() + pixel_offset
        px = tid % cam.width
        py = tid // cam.width
        fw = float(cam.width)
        fh = float(cam.height)
        u = (2.0 * (float(px) + 0.5) / fw - 1.0) * (fw / fh)
        v = 1.0 - 2.0 * (float(py) + 0.5) / fh
        o = cam.o0 + u * cam.ou + v * cam.ov
        d = wp.normalize(cam.d0 + u * cam.du + v * cam.dv)

        state = vecst(0.0, 0.0, 0.0, 1.0, 0.0, -1.0, 0.0)
        n_field = int(0)
        n_restr = int(0)
        n_seg = int(0)
        n_empty = int(0)
        n_smooth = int(0)
        n_pw = int(0)
        n_locate = int(0)
        t_lo = cam.t_min
        t_hi = cam.t_max
        cax = wp.dot(d, cam.clip_axis)
        if cax > 0.0:
            t_lo = wp.max(t_lo, cam.clip_near / cax)
            t_hi = wp.min(t_hi, cam.clip_far / cax)
        t_cur = t_lo
        # Traversal. Each BVH pass gathers a window of the WINDOW smallest keys (t where an element
        # may start beyond t_cur): exact for affine elements, the box entry for curved ones until
        # they are located. Curved elements are located lazily, only when they reach the front of
        # the window, and remembered in a per-ray cache across passes, so each is located about
        # once. `thresh` is the smallest key left out of the window: the front is final only while
        # its key is not above it. A pass may skip curved elements whose stretch is behind t_cur;
        # re-entering one shows as a gap, and a gap (or the end) is only trusted after a full pass.
        full_at = float(-1.0e30)
        full = int(1)
        cache_e = vecli()
        cache_from = vecl()
        cache_t0 = vecl()
        cache_t1 = vecl()
        ncache = int(0)
        cnext = int(0)
        done = int(0)
        guard = int(0)
        while done == 0 and guard < 65536:
            guard += 1
            win_key = vecw()
            win_t1 = vecw()
            win_e = vecwi()
            win_res = vecwi()
            nwin = int(0)
            thresh = float(1.0e30)
            skipped = int(0)
            query = wp.bvh_query_ray(mesh.bvh, o, d)
            e = int(0)
            while wp.bvh_query_next(query, e):
                key = float(0.0)
                t1 = float(0.0)
                res = int(1)
                use = int(0)
                if mesh.affine[e] == 1:
                    iv = element_interval(mesh, e, o, d)
                    if iv[0] > 0.0:
                        key = wp.max(iv[1], t_cur)
                        t1 = wp.min(iv[2], t_hi)
                        use = 1
                else:
                    if wp.static(CURVED):
                        bx = box_interval(mesh, e, o, d)
                        key = wp.max(bx[0], t_cur)
                        t1 = wp.min(bx[1], t_hi)
                        res = 0
                        use = 1
                        slot = int(-1)
                        for s in range(ncache):
                            if cache_e[s] == e and cache_from[s] <= t_cur:
                                if slot < 0:
                                    slot = s
                                elif cache_from[s] > cache_from[slot]:
                                    slot = s
                        if slot >= 0:
                            if cache_t1[slot] < -1.0e29:
                                use = 0  # located before: nothing beyond a t_from <= t_cur
                            elif cache_t1[slot] <= t_cur:
                                if full == 0:  # its stretch is behind us
                                    use = 0
                                    skipped = 1
                            else:
                                key = wp.max(cache_t0[slot], t_cur)
                                t1 = wp.min(cache_t1[slot], t_hi)
                                res = 1
                if use == 1 and t1 > key:
                    if nwin == WINDOW and key >= win_key[WINDOW - 1]:
                        thresh = wp.min(thresh, key)
                    else:
                        if nwin == WINDOW:
                            thresh = wp.min(thresh, win_key[WINDOW - 1])
                        k = wp.min(nwin, WINDOW - 1)
                        while k > 0 and win_key[k - 1] > key:
                            win_key[k] = win_key[k - 1]
                            win_t1[k] = win_t1[k - 1]
                            win_e[k] = win_e[k - 1]
                            win_res[k] = win_res[k - 1]
                            k -= 1
                        win_key[k] = key
                        win_t1[k] = t1
                        win_e[k] = e
                        win_res[k] = res
                        nwin = wp.min(nwin + 1, WINDOW)
            if full == 1 or skipped == 0:
                full_at = t_cur
            full = 0
            action = int(0)  # 0: window used up, 1: regather (the front passed thresh), 2: full regather
            head = int(0)
            while head < nwin and done == 0:
                if win_key[head] > thresh:
                    action = 1
                    break
                el = win_e[head]
                if win_res[head] == 0:
                    if wp.static(CURVED):
                        # locate the nearest candidate, remember it, re-insert it at its true key
                        iv = curved_interval(mesh, el, o, d, t_cur)
                        n_locate += 1
                        cache_e[cnext] = el
                        cache_from[cnext] = t_cur
                        cache_t0[cnext] = -1.0e30
                        cache_t1[cnext] = -1.0e30
                        if iv[0] > 0.0:
                            cache_t0[cnext] = iv[1]
                            cache_t1[cnext] = iv[2]
                        cnext = (cnext + 1) % LOCATE_CACHE
                        ncache = wp.min(ncache + 1, LOCATE_CACHE)
                        k0 = wp.max(iv[1], t_cur)
                        k1 = wp.min(iv[2], t_hi)
                        if iv[0] > 0.0 and k1 > k0:
                            k = head
                            while k + 1 < nwin and win_key[k + 1] < k0:
                                win_key[k] = win_key[k + 1]
                                win_t1[k] = win_t1[k + 1]
                                win_e[k] = win_e[k + 1]
                                win_res[k] = win_res[k + 1]
                                k += 1
                            win_key[k] = k0
                            win_t1[k] = k1
                            win_e[k] = el
                            win_res[k] = 1
                        else:
                            head += 1
                    continue
                a = wp.max(win_key[head], t_cur)
                b = win_t1[head]
                head += 1
                if b <= a:
                    continue
                # a gap may hide a curved element re-entered there that this pass skipped
                if a > t_cur + 1.0e-6 * (wp.abs(t_cur) + 1.0) and full_at != t_cur:
                    action = 2
                    break
                t_cur = b
                n_seg += 1
                A = mesh.ref_a[el]
                xo = A * o + mesh.ref_b[el]
                xd = A * d
                curved = int(0)
                c = vecr()
                deg = int(0)
                if wp.static(CURVED):
                    curved = int(1) - mesh.affine[el]
                    if curved == 1:
                        # curved: every method samples the Chebyshev interpolant along the ray
                        c = curved_restriction(mesh, el, o, d, a, b)
                        deg = int(c[MAX_RESTRICTION - 4])
                        n_field += deg + 1
                        if deg != curved_base_degree(mesh, el):
                            n_field += curved_base_degree(mesh, el) + 1
                        state[6] = state[6] + c[MAX_RESTRICTION - 3]
                if q.method == METHOD_RIEMANN:
                    nsteps = wp.max(1, int(wp.ceil((b - a) / q.h)))
                    if curved == 0:
                        n_field += nsteps
                    state = march_riemann(mesh, tf, q, el, xo, xd, curved, c, deg, a, b, state)
                elif q.method == METHOD_TRAPEZOID:
                    nsteps = wp.max(1, int(wp.ceil((b - a) / q.h)))
                    if curved == 0:
                        n_field += nsteps + 1
                    state = march_trapezoid(mesh, tf, q, el, xo, xd, curved, c, deg, a, b, state)
                else:
                    lo = float(0.0)
                    hi = float(0.0)
                    if curved == 1:
                        # the interpolant is not exact: classify with the element's certified range
                        lo = mesh.field_lo[el]
                        hi = mesh.field_hi[el]
                    else:
                        deg = restriction_degree(mesh, el)
                        c = chebyshev_restriction(mesh, el, xo, xd, a, b, deg)
                        n_field += deg + 1
                        rad = float(0.0)
                        for k in range(1, deg + 1):
                            rad += wp.abs(c[k])
                        rad = rad * 1.000001 + 1.0e-6 * wp.abs(c[0])  # float32 rounding margin
                        glo = c[0] - rad
                        ghi = c[0] + rad
                        # f = g / w^2 with w linear and positive on the segment: interval division
                        w2lo = wp.max(wp.min(c[MAX_RESTRICTION - 2], c[MAX_RESTRICTION - 1]), 1.0e-6)
                        w2hi = wp.max(c[MAX_RESTRICTION - 2], c[MAX_RESTRICTION - 1])
                        w2lo = w2lo * w2lo
                        w2hi = w2hi * w2hi
                        lo = wp.min(glo / w2lo, glo / w2hi)
                        hi = wp.max(ghi / w2lo, ghi / w2hi)
                    dens_max = density_max_on(tf, lo, hi)
                    emitting = int(0)
                    if color_max_on(tf, lo, hi) > 0.0:
                        emitting = 1
                    if dens_max <= 0.0:
                        n_empty += 1
                        continue
                    piecewise = breakpoint_inside(tf.density_s, lo, hi)
                    if emitting == 1 and breakpoint_inside(tf.color_s, lo, hi) == 1:
                        piecewise = 1
                    if piecewise == 0:
                        n_smooth += 1
                        state = gauss_kronrod_smooth(tf, q, c, deg, a, b, a, b, emitting, state)
                    elif q.method == METHOD_CLASSIFIED:
                        n_pw += 1
                        nsteps = wp.max(1, int(wp.ceil((b - a) / q.h)))
                        n_restr += nsteps + 1
                        state = march_trapezoid(mesh, tf, q, el, xo, xd, 1, c, deg, a, b, state)
                    else:
                        # split: cut at every breakpoint crossing, then G-K each (smooth) piece.
                        # Between consecutive critical points f is monotone, so a level is crossed
                        # there at most once and a sign change at the piece ends finds it exactly.
                        n_pw += 1
                        bnd = critical_points(c, deg, a, b)
                        nb = int(bnd[MAX_RESTRICTION - 1])
                        n_restr += int(bnd[MAX_RESTRICTION - 2])
                        piece_start = a
                        ts = a
                        fs = restriction_at(c, deg, a, b, a)
                        for i in range(nb + 1):
                            te = b
                            if i < nb:
                                te = bnd[i]
                            fe = restriction_at(c, deg, a, b, te)
                            n_restr += 1
                            t_last = ts
                            more = int(1)
                            while more == 1:
                                best = te
                                found = int(0)
                                for kk in range(tf.density_s.shape[0] + tf.color_s.shape[0]):
                                    lvl = float(0.0)
                                    if kk < tf.density_s.shape[0]:
                                        lvl = tf.density_s[kk]
                                    else:
                                        lvl = tf.color_s[kk - tf.density_s.shape[0]]
                                    if (fs - lvl) * (fe - lvl) < 0.0:
                                        bc = bisect_crossing(c, deg, a, b, ts, te, fs, lvl)
                                        n_restr += int(bc[1])
                                        tc = bc[0]
                                        if tc > t_last + 1.0e-7 * (b - a) and tc < best:
                                            best = tc
                                            found = 1
                                if found == 1:
                                    if best > piece_start:
                                        state = gauss_kronrod_smooth(tf, q, c, deg, a, b, piece_start, best, emitting, state)
                                    piece_start = best
                                    t_last = best
                                else:
                                    more = 0
                                if state[3] < q.min_transmittance:
                                    more = 0
                            ts = te
                            fs = fe
                            if state[3] < q.min_transmittance:
                                break
                        if piece_start < b and state[3] >= q.min_transmittance:
                            state = gauss_kronrod_smooth(tf, q, c, deg, a, b, piece_start, b, emitting, state)
                if state[3] < q.min_transmittance:
                    done = 1
            if done == 0:
                if action == 2:
                    full = 1
                elif action == 0 and thresh >= 1.0e29:
                    if full_at == t_cur:
                        done = 1
                    else:
                        full = 1

        T = state[3]
        rgba[tid] = wp.vec4(state[0] + T * q.background[0], state[1] + T * q.background[1], state[2] + T * q.background[2], 1.0 - T)
        depth_out = state[5]
        if depth_out < 0.0:
            depth_out = t_hi
        aux[tid] = wp.vec2(depth_out, state[6])
        stats[tid, 0] = n_field
        stats[tid, 1] = n_restr + int(state[4])
        stats[tid, 2] = n_seg
        stats[tid, 3] = n_empty
        stats[tid, 4] = n_smooth
        stats[tid, 5] = n_pw
        stats[tid, 6] = n_locate

    return render
