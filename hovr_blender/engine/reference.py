"""Float64 reference integrator: the image of render contract §3, to ~1e-12, for affine hexahedra.

Every pixel exact (up to rounding and a certified quadrature error) so the GPU paths can be
checked against it. Why it can be exact: on an affine element xi(t) = p + t q, so the tensor
field is a polynomial f(t) of degree D <= sum(modes - 1) along the ray. Per ray:

1. element intervals by the slab test in reference space against [-1, 1]^3, front to back;
2. on each interval f is recovered exactly as a Chebyshev series in s in [-1, 1]
   (t = tm + h s) from D+1 Chebyshev-point samples;
3. the interval is split at every s where f hits a transfer-function breakpoint, so that on
   each piece tau(f) and kappa(f) are *linear* in f;
4. the optical depth of a piece is then an exact polynomial antiderivative; the emission
   integral  h * int kappa tau exp(-depth) ds  is composite Gauss-Legendre on sub-pieces
   whose depth increment is at most ``depth_step``, done at two resolutions (m and 2m
   sub-pieces) so the difference certifies the error (``info["error_estimate"]``).

No early ray termination: T is exact however small. Inside one piece the emission integrand is
not sampled past depth ``depth_cut`` (60: exp(-60) ~ 1e-26, below float64 resolution of C).
Vectorised over rays with numpy; Python loops run over element blocks, (modes, basis) classes,
degree classes and the piece rank along a ray, never over rays.

Curved meshes and the other shapes have no closed-form reference: ``pixel_exact_reference``
renders them with the Renderer in float64 (``RenderOptions.pixel_exact()``), the reference of
every benchmark.
"""
from __future__ import annotations

import time

import numpy as np

from .expansions import MODIFIED_A, eval_tensor
from .camera import RayCamera
from .mesh import VolumeMesh
from .shapes import HEX
from .transfer_function import TransferFunction


class ReferenceError(ValueError):
    """A scene outside the reference's scope (non-hexahedral or non-affine elements)."""


# --------------------------------------------------------------------------- Chebyshev helpers


def cheb_eval(c: np.ndarray, s: np.ndarray) -> np.ndarray:
    """Clenshaw: row r of c (R, K) evaluated at s (R, Q) -> (R, Q)."""
    s = np.asarray(s, dtype=np.float64)
    b1 = np.zeros(s.shape)
    b2 = np.zeros(s.shape)
    for k in range(c.shape[1] - 1, 0, -1):
        b1, b2 = 2.0 * s * b1 - b2 + c[:, k, None], b1
    return s * b1 - b2 + c[:, 0, None]


def cheb_integral(c: np.ndarray) -> np.ndarray:
    """Antiderivative coefficients (R, K+1) of Chebyshev rows c (R, K), constant term 0."""
    r, k = c.shape
    a = np.zeros((r, k + 1))
    a[:, 1] += c[:, 0]  # int T0 = T1
    for j in range(1, k):  # int Tj = T_{j+1}/(2(j+1)) - T_{j-1}/(2(j-1)), int T1 = T2/4
        a[:, j + 1] += c[:, j] / (2.0 * (j + 1))
        if j >= 2:
            a[:, j - 1] -= c[:, j] / (2.0 * (j - 1))
    return a


def chebyshev_nodes(n: int) -> np.ndarray:
    return np.cos(np.pi * (2.0 * np.arange(n) + 1.0) / (2.0 * n))


def _values_to_chebyshev(n: int) -> np.ndarray:
    """(n, n) matrix V with c = f(nodes) @ V exact for polynomials of degree < n."""
    j = np.arange(n)
    V = np.cos(np.outer(np.pi * (2.0 * j + 1.0) / (2.0 * n), j)) * (2.0 / n)
    V[:, 0] *= 0.5
    return V


def _colleague_roots(c: np.ndarray) -> np.ndarray:
    """Complex roots (R, g) of Chebyshev rows c (R, g+1), g >= 2, c[:, g] != 0 (numpy's chebcompanion)."""
    r, k = c.shape
    g = k - 1
    mat = np.zeros((r, g, g))
    scl = np.array([1.0] + [np.sqrt(0.5)] * (g - 1))
    off = np.full(g - 1, 0.5)
    off[0] = np.sqrt(0.5)
    idx = np.arange(g - 1)
    mat[:, idx, idx + 1] = off
    mat[:, idx + 1, idx] = off
    mat[:, :, -1] -= (c[:, :-1] / c[:, -1:]) * (scl / scl[-1]) * 0.5
    return np.linalg.eigvals(mat)


# --------------------------------------------------------------------------- transfer function


def _segment_tables(s: np.ndarray, v: np.ndarray):
    """Per segment k = 0..K (searchsorted side='right'): value = ref + slope (f - s_ref)."""
    v = v.reshape(s.size, -1)
    K = s.size
    ref = np.concatenate([v[:1], v[:-1], v[-1:]])  # k=0 clamp low, k=K clamp high
    s_ref = np.concatenate([s[:1], s[:-1], s[-1:]])
    slope = np.zeros((K + 1, v.shape[1]))
    if K > 1:
        slope[1:K] = (v[1:] - v[:-1]) / (s[1:] - s[:-1])[:, None]
    return ref, slope, s_ref


# --------------------------------------------------------------------------- traversal


def _element_intervals(mesh: VolumeMesh, o, d, t_min, t_max, pairs_per_block=1 << 22):
    """Ray/element intervals by the reference-space slab test: (ray, elem, t0, t1) sorted front to back."""
    M = mesh.ref_from_world
    n = mesh.num_elements
    nr = o.shape[0]
    block = max(1, pairs_per_block // max(nr, 1))
    rays, elems, t0s, t1s = [], [], [], []
    for e0 in range(0, n, block):
        A = M[e0 : e0 + block, :, :3]
        b = M[e0 : e0 + block, :, 3]
        p = np.einsum("eij,rj->rei", A, o) + b
        q = np.einsum("eij,rj->rei", A, d)
        with np.errstate(divide="ignore", invalid="ignore"):
            ta = (-1.0 - p) / q
            tb = (1.0 - p) / q
        par = q == 0.0  # parallel to a slab: all or nothing
        inside = np.abs(p) <= 1.0
        lo = np.where(par, np.where(inside, -np.inf, np.inf), np.minimum(ta, tb))
        hi = np.where(par, np.where(inside, np.inf, -np.inf), np.maximum(ta, tb))
        t0 = np.maximum(lo.max(axis=-1), t_min)
        t1 = np.minimum(hi.min(axis=-1), t_max)
        r, e = np.nonzero(t1 > t0)
        rays.append(r)
        elems.append(e + e0)
        t0s.append(t0[r, e])
        t1s.append(t1[r, e])
    r, e, t0, t1 = (np.concatenate(a) for a in (rays, elems, t0s, t1s))
    order = np.lexsort((t0, r))
    r, e, t0, t1 = r[order], e[order], t0[order], t1[order]
    # Elements do not overlap: what overlaps at shared faces is rounding; give it to the front one.
    same = r[1:] == r[:-1]
    t0[1:][same] = np.maximum(t0[1:][same], t1[:-1][same])
    keep = t1 > t0
    return r[keep], e[keep], t0[keep], t1[keep]


def _degree(key) -> int:
    """Degree along a line of a tensor field with modes (n0, n1, n2) of basis key[3]."""
    if int(key[3]) != MODIFIED_A:
        raise ReferenceError(f"basis id {int(key[3])} is not supported by the reference")
    # Modified_A with one mode is (1 - x)/2, not a constant: degree max(n - 1, 1) per direction
    return int(sum(max(int(n) - 1, 1) for n in key[:3]))


def _interval_series(mesh: VolumeMesh, o, d, ray, elem, t0, t1):
    """Chebyshev coefficients (n_int, Dmax+1) of f(tm + h s) on every interval, and h."""
    tm, h = 0.5 * (t0 + t1), 0.5 * (t1 - t0)
    M = mesh.ref_from_world[elem]
    p = np.einsum("nij,nj->ni", M[:, :, :3], o[ray]) + M[:, :, 3]
    q = np.einsum("nij,nj->ni", M[:, :, :3], d[ray])
    modes = mesh.modes[elem]
    key = np.column_stack([modes, mesh.basis[elem]])
    groups = np.unique(key, axis=0)
    out = np.zeros((elem.size, max(_degree(k) for k in groups) + 1))
    for k in groups:
        sel = np.nonzero((key == k).all(axis=1))[0]
        n0, n1, n2, bid = (int(v) for v in k)
        n = _degree(k) + 1  # D + 1 samples determine a degree-D polynomial
        s = chebyshev_nodes(n)
        xi = p[sel, None, :] + (tm[sel, None] + h[sel, None] * s)[..., None] * q[sel, None, :]
        cidx = mesh.coeff_offset[elem[sel], None] + np.arange(n0 * n1 * n2)
        vals = eval_tensor(mesh.coeffs[cidx], (n0, n1, n2), xi)
        out[sel, :n] = vals @ _values_to_chebyshev(n)
    return out, h


# --------------------------------------------------------------------------- splitting


def _split_points(c: np.ndarray, breaks: np.ndarray, rtol: float):
    """Sorted split points (n_int, P) in [-1, 1] (NaN padded): ends plus every s with f(s) in breaks."""
    n_int, K = c.shape
    scale = np.abs(c).max(axis=1)
    big = np.abs(c) > rtol * scale[:, None]
    # effective degree: numerically-zero top coefficients dropped (x^2+y^2+z^2 stays a quadratic)
    deg = np.where(big.any(axis=1), K - 1 - np.argmax(big[:, ::-1], axis=1), 0)
    reach = np.abs(c[:, 1:]).sum(axis=1) * (1.0 + 1e-12) + 1e-300  # |f(s) - c0| <= reach
    nb = breaks.size
    roots = np.full((n_int, max(nb * int(deg.max(initial=0)), 1)), np.nan)
    for g in np.unique(deg):
        if g == 0:
            continue
        ii = np.nonzero(deg == g)[0]
        cc = c[ii, : g + 1]
        shift = breaks[None, :] - cc[:, :1]  # f(s) = beta  <=>  (f - c0)(s) = beta - c0
        ok = np.abs(shift) <= reach[ii, None]
        if g == 1:
            r = shift / cc[:, 1:2]
        elif g == 2:  # f - beta = A2 s^2 + A1 s + A0 in powers of s; stable quadratic formula
            A2 = 2.0 * cc[:, 2:3]
            A1 = np.broadcast_to(cc[:, 1:2], shift.shape)
            A0 = -cc[:, 2:3] - shift
            disc = A1 * A1 - 4.0 * A2 * A0
            # a tangent breakpoint may come out slightly negative: treat as a double root
            disc = np.where((disc < 0) & (disc > -1e-12 * (A1 * A1 + np.abs(4.0 * A2 * A0))), 0.0, disc)
            sq = np.sqrt(np.where(disc >= 0, disc, np.nan))
            qq = -0.5 * (A1 + np.copysign(sq, A1))
            with np.errstate(divide="ignore", invalid="ignore"):
                r = np.concatenate([qq / A2, np.where(qq != 0, A0 / qq, -A1 / (2.0 * A2))], axis=1)
            ok = np.concatenate([ok, ok], axis=1)
        else:
            r = np.full((ii.size, nb * g), np.nan)
            ri, bi = np.nonzero(ok)
            if ri.size:
                cb = cc[ri].copy()
                cb[:, 0] -= breaks[bi]
                z = _colleague_roots(cb)  # (pairs, g)
                # near-double roots come out as a pair with tiny imaginary parts: keep them (an
                # extra split is harmless, a missed one is not)
                z = np.where(np.abs(z.imag) <= 1e-7, z.real, np.nan)
                r.reshape(ii.size, nb, g)[ri, bi, :] = z
            ok = np.repeat(ok, g, axis=1)
        r = np.where(ok & (r > -1.0) & (r < 1.0), r, np.nan)
        roots[ii, : r.shape[1]] = r
    pts = np.concatenate([np.full((n_int, 1), -1.0), np.full((n_int, 1), 1.0), roots], axis=1)
    pts.sort(axis=1)  # NaN last
    return pts, deg


# --------------------------------------------------------------------------- emission quadrature


def _emission(pc, G, h, sa, se, tau_ref, slope, s_ref, col_ref, cslope, cs_ref, m, nodes):
    """Composite Gauss-Legendre of h int_sa^se kappa tau exp(-depth) ds, m sub-pieces per piece.

    pc: field series per piece; G: antiderivative of f - s_ref per piece; depth from sa, exact."""
    x, w = np.polynomial.legendre.leggauss(nodes)
    sp = np.repeat(np.arange(sa.size), m)
    j = np.arange(sp.size) - np.repeat(np.cumsum(m) - m, m)
    width = (se - sa)[sp] / m[sp]
    # offsets from sa kept apart from s: s - sa would lose digits on a short piece far from s = 0
    u = (j * width)[:, None] + (0.5 * (x + 1.0)) * width[:, None]
    s = sa[sp, None] + u
    f = cheb_eval(pc[sp], s)
    Gs = cheb_eval(G[sp], s)
    Ga = cheb_eval(G, sa[:, None])[:, 0][sp]
    depth = h[sp, None] * (tau_ref[sp, None] * u + slope[sp, None] * (Gs - Ga[:, None]))
    tau = tau_ref[sp, None] + slope[sp, None] * (f - s_ref[sp, None])
    wt = (0.5 * w) * (h[sp] * width)[:, None] * tau * np.exp(-depth)
    out = np.empty((sa.size, 3))
    for ch in range(3):
        kap = col_ref[sp, ch, None] + cslope[sp, ch, None] * (f - cs_ref[sp, None])
        out[:, ch] = np.bincount(sp, weights=(wt * kap).sum(axis=1), minlength=sa.size)
    return out


def _depth_from(G, h, sa, tau_ref, slope, s):
    return h * (tau_ref * (s - sa) + slope * (cheb_eval(G, s[:, None])[:, 0] - cheb_eval(G, sa[:, None])[:, 0]))


# --------------------------------------------------------------------------- driver


def _render_rays(mesh, tf, o, d, t_min, t_max, opts):
    nr = o.shape[0]
    C = np.zeros((2, nr, 3))  # coarse, fine
    total = np.zeros(nr)
    stats = {"intervals": 0, "pieces": 0, "subpieces": 0, "max_degree": 0}
    ray, elem, t0, t1 = _element_intervals(mesh, o, d, t_min, t_max)
    if ray.size == 0:
        return C, total, stats
    c, h = _interval_series(mesh, o, d, ray, elem, t0, t1)
    pts, deg = _split_points(c, tf.breakpoints, opts["degree_rtol"])
    stats["intervals"] = int(ray.size)
    stats["max_degree"] = int(deg.max())

    sa_all, sb_all = pts[:, :-1], pts[:, 1:]
    ii, jj = np.nonzero(sb_all > sa_all)  # row-major: pieces stay front to back per ray
    sa, sb = sa_all[ii, jj], sb_all[ii, jj]
    pc = c[ii]
    fmid = cheb_eval(pc, (0.5 * (sa + sb))[:, None])[:, 0]

    tref, tslope, tsref = opts["tau_tables"]
    kd = np.searchsorted(tf.density_s, fmid, side="right")
    tau_ref, slope, s_ref = tref[kd, 0], tslope[kd, 0], tsref[kd]
    active = (tau_ref != 0.0) | (slope != 0.0)  # tau == 0 on the whole piece otherwise
    ii, sa, sb, pc = ii[active], sa[active], sb[active], pc[active]
    tau_ref, slope, s_ref, fmid = tau_ref[active], slope[active], s_ref[active], fmid[active]
    stats["pieces"] = int(ii.size)
    if ii.size == 0:
        return C, total, stats
    cref, cslope_t, csref_t = opts["color_tables"]
    kc = np.searchsorted(tf.color_s, fmid, side="right")
    col_ref, cslope, cs_ref = cref[kc], cslope_t[kc], csref_t[kc]

    hp = h[ii]
    shifted = pc.copy()
    shifted[:, 0] -= s_ref  # tau = tau_ref + slope (f - s_ref): no large cancelling intercept
    G = cheb_integral(shifted)
    D = np.maximum(_depth_from(G, hp, sa, tau_ref, slope, sb), 0.0)

    # Past depth_cut inside a piece the integrand is below exp(-depth_cut): stop sampling there.
    se = sb.copy()
    far = np.nonzero(D > opts["depth_cut"])[0]
    if far.size:
        lo, hi = sa[far].copy(), sb[far].copy()
        for _ in range(60):  # depth is monotone in s (tau >= 0): bisection
            mid = 0.5 * (lo + hi)
            below = _depth_from(G[far], hp[far], sa[far], tau_ref[far], slope[far], mid) < opts["depth_cut"]
            lo, hi = np.where(below, mid, lo), np.where(below, hi, mid)
        se[far] = hi
    m = np.maximum(np.ceil(np.minimum(D, opts["depth_cut"]) / opts["depth_step"]), 1).astype(np.int64)
    nodes = max(opts["quad_nodes"], c.shape[1] + 8)  # kappa*tau has degree 2D: keep it (nearly) exact
    E = [
        _emission(pc, G, hp, sa, se, tau_ref, slope, s_ref, col_ref, cslope, cs_ref, mm, nodes)
        for mm in (m, 2 * m)
    ]
    stats["subpieces"] = int(3 * m.sum())

    # Composite front to back: transmittance before each piece from the exact depths of the
    # earlier pieces of its ray, summed in order (loop over the piece rank, not over rays).
    pr = ray[ii]
    first = np.searchsorted(pr, pr, side="left")
    rank = np.arange(pr.size) - first
    order = np.argsort(rank, kind="stable")
    bounds = np.concatenate([[0], np.cumsum(np.bincount(rank))])
    for k in range(bounds.size - 1):
        idx = order[bounds[k] : bounds[k + 1]]
        r = pr[idx]  # distinct rays: one piece of each at rank k
        att = np.exp(-total[r])[:, None]
        C[0, r] += E[0][idx] * att
        C[1, r] += E[1][idx] * att
        total[r] += D[idx]
    return C, total, stats


def reference_render(
    mesh: VolumeMesh,
    camera: RayCamera,
    tf: TransferFunction,
    background=(0.0, 0.0, 0.0),
    *,
    rays_per_chunk: int = 32768,
    quad_nodes: int = 20,
    depth_step: float = 1.0,
    depth_cut: float = 60.0,
    degree_rtol: float = 1e-12,
):
    """The contract image in float64: (rgba (H, W, 4), row 0 at the top; info dict).

    RGB = C + T background, alpha = 1 - T. ``info["error_estimate"]`` is the largest difference
    in C between the two quadrature resolutions (the returned image uses the finer one);
    ``info["error_map"]`` is the same per pixel (H, W)."""
    if np.any(mesh.shape != HEX):
        raise ReferenceError("the reference integrator handles hexahedra only")
    bg = np.asarray(background, dtype=np.float64).reshape(3)
    start = time.perf_counter()
    o, d = camera.rays()
    H, W = d.shape[:2]
    o, d = o.reshape(-1, 3), d.reshape(-1, 3)
    opts = {
        "degree_rtol": degree_rtol,
        "depth_step": float(depth_step),
        "depth_cut": float(depth_cut),
        "quad_nodes": int(quad_nodes),
        "tau_tables": _segment_tables(tf.density_s, tf.density_tau),
        "color_tables": _segment_tables(tf.color_s, tf.color_rgb),
    }
    rgba = np.empty((H * W, 4))
    err = np.empty(H * W)
    totals = {"intervals": 0, "pieces": 0, "subpieces": 0, "max_degree": 0}
    for r0 in range(0, H * W, rays_per_chunk):
        sl = slice(r0, min(r0 + rays_per_chunk, H * W))
        C, depth, st = _render_rays(mesh, tf, o[sl], d[sl], camera.t_min, camera.t_max, opts)
        T = np.exp(-depth)
        rgba[sl, :3] = C[1] + T[:, None] * bg
        rgba[sl, 3] = -np.expm1(-depth)
        err[sl] = np.abs(C[1] - C[0]).max(axis=1)
        for k in ("intervals", "pieces", "subpieces"):
            totals[k] += st[k]
        totals["max_degree"] = max(totals["max_degree"], st["max_degree"])
    info = {
        "method": "reference",
        "error_estimate": float(err.max()),
        "error_map": err.reshape(H, W),
        "time_s": time.perf_counter() - start,
        "rays": H * W,
        "quad_nodes": int(quad_nodes),
        "depth_step": float(depth_step),
        "depth_cut": float(depth_cut),
        **totals,
    }
    return rgba.reshape(H, W, 4), info


def pixel_exact_reference(mesh: VolumeMesh, camera: RayCamera, tf: TransferFunction, background=(0.0, 0.0, 0.0),
                          device: str = "cpu", renderer=None):
    """The reference image of any mesh (curved, all four shapes), where reference_render covers
    affine hexahedra only: the Renderer with RenderOptions.pixel_exact(), float64 from end to
    end. (rgba (H, W, 4) float64, the render's stats). Pass `renderer` (an engine.renderer.Renderer
    of this mesh) to reuse its upload."""
    from .renderer import Renderer
    from .view import RenderOptions

    r = renderer if renderer is not None else Renderer(mesh, device)
    res = r.render(camera, tf, background, RenderOptions.pixel_exact(device))
    return res.rgba.astype(np.float64), res.stats
