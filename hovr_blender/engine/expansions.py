"""Spectral/hp expansions of all four 3-D shapes, on the host (numpy, float64).

THE CONTRACT (implemented by this module, used by importers, the reference and the tests;
the Warp kernels implement the same polynomials independently and are tested against it).
Conventions are those of docs/spec/formats.md §2.8-2.12 (Nektar++):

Shapes: HEX = 0, PRISM = 1, TET = 2, PYR = 3; reference coordinates xi in [-1, 1]^3 with the
vertex numbering of §2.8 (VERTICES).

A "modal expansion" of shape s with modes (P0, P1, P2) is Nektar++'s MODIFIED family
(hex A,A,A; prism A,A,B; tet A,B,C; pyramid A,A,PyrC), coefficients in Nektar++'s storage
order (§2.10: hex direction 0 fastest; prism/tet/pyramid r fastest), with the collapsed-
vertex corrections of §2.10 applied. The same form holds the field (coeffs shape (K,)) and
the geometry map x(xi) (coeffs shape (K, 3)): one evaluator serves both.

Functions (all vectorised over leading point dimensions; xi (..., 3)):
    num_coeffs(shape, modes) -> int
    mode_triples(shape, modes) -> (K, 3) int      the (p, q, r) of each stored coefficient
    collapse(shape, xi) -> eta (..., 3)           denominators clamped at 1e-12 as Nektar++
    uncollapse(shape, eta) -> xi (..., 3)         the cube of collapsed coordinates onto the shape
    eval_modal(shape, modes, coeffs, xi) -> (...,) or (..., C)
    eval_modal_grad(shape, modes, coeffs, xi) -> (..., 3) or (..., C, 3)   d/dxi
    fit_points(shape, modes) -> xi (M, 3), M >= K  unisolvent points inside the shape
    fit_modal(shape, modes, values) -> coeffs     values at fit_points (..., or (M, C));
                                                  exact for functions in the space
    gll_lagrange_hex_to_modal(modes, nodal) -> coeffs   GLL_Lagrange tensor hex (§2.9) -> modal
    inside(shape, xi, tol=1e-10) -> bool (...)
    invert_map(shape, gmodes, gcoeffs, x, xi0=None, tol=1e-12, max_iter=50)
        -> (xi (..., 3), converged (...), inside (...))   damped Newton on x(xi) = x
"""
from __future__ import annotations

from functools import lru_cache

import numpy as np
from numpy.polynomial import legendre

from .shapes import CENTROIDS, HEX, NAMES, PRISM, PYR, TET, VERTICES

# More in the contract:
#   shapes.VERTICES[shape] -> (nv, 3) reference vertex coordinates (§2.8)
#   affine_fit(shape, gmodes, gcoeffs) -> (A (3,3), b (3,), ok): xi = A x + b when the map
#       x(xi) is affine (checked at fit points to 1e-12 relative), else ok = False
# Extras (not needed by the contract's users, handy for importers and tests):
#   basis_matrix(shape, modes, xi, corrected=True) -> (..., K) every mode at xi
#   vertex_mode_indices(shape, modes) -> (nv,) storage index of each vertex's mode
#   shapes.CENTROIDS[shape] -> (3,) reference centroid
# One-dimensional Modified_A modes, GLL points and tensor-product fits (the hexahedron's basis,
# used by the built-in datasets and the reference): modified_a, modified_a_derivative, gll_points,
# fit_tensor_coefficients, eval_tensor.

ZERO_TOL = 1e-12  # Nektar++ kNekZeroTol: collapsed-coordinate denominators are clamped to it
_CHUNK = 1 << 22  # basis-matrix entries per evaluation chunk (bounds memory, keeps numpy vectorised)


MODIFIED_A = 0  # the one basis id VolumeMesh.basis holds: Nektar++ Modified_A


def modified_a(n: int, x) -> np.ndarray:
    """(..., n) values of Modified_A modes 0..n-1 at x (vertex modes first)."""
    x = np.asarray(x, dtype=np.float64)
    out = np.empty(x.shape + (n,), dtype=np.float64)
    out[..., 0] = 0.5 * (1.0 - x)
    if n > 1:
        out[..., 1] = 0.5 * (1.0 + x)
    bubble = 0.25 * (1.0 - x) * (1.0 + x)
    for p in range(2, n):
        # P^(1,1)_{p-2} = 2/p * d/dx P_{p-1} (Legendre): independent of the kernels' recurrence
        out[..., p] = bubble * (2.0 / p) * legendre.Legendre.basis(p - 1).deriv()(x)
    return out


def gll_points(n: int) -> np.ndarray:
    """n Gauss-Lobatto-Legendre points on [-1, 1] (n >= 2)."""
    if n < 2:
        return np.zeros(1)
    interior = legendre.Legendre.basis(n - 1).deriv().roots()
    return np.concatenate([[-1.0], np.sort(interior.real), [1.0]])


def fit_tensor_coefficients(func, modes) -> np.ndarray:
    """Coefficients c[i + n0 (j + n1 k)] of the tensor expansion interpolating func(xi1, xi2, xi3)
    at GLL points; exact when func is in the space (e.g. a polynomial of degree < n per direction)."""
    n0, n1, n2 = (int(m) for m in modes)
    pts = [gll_points(n) for n in (n0, n1, n2)]
    X = np.meshgrid(*pts, indexing="ij")
    vals = np.asarray(func(*X), dtype=np.float64)  # (n0, n1, n2)
    V = [modified_a(n, p) for n, p in zip((n0, n1, n2), pts)]
    c = np.einsum("ai,ijk->ajk", np.linalg.inv(V[0]), vals)
    c = np.einsum("bj,ajk->abk", np.linalg.inv(V[1]), c)
    c = np.einsum("ck,abk->abc", np.linalg.inv(V[2]), c)
    return np.ascontiguousarray(c.transpose(2, 1, 0)).ravel()  # direction 0 fastest


def eval_tensor(coeffs: np.ndarray, modes, xi) -> np.ndarray:
    """Hexahedral tensor expansions (Modified_A, direction 0 fastest) at reference points xi
    (..., 3): one expansion (coeffs (K,)) at every point, or one per leading index (coeffs
    (..., K) against xi (..., S, 3): row r's expansion at its S points)."""
    n0, n1, n2 = (int(m) for m in modes)
    xi = np.asarray(xi, dtype=np.float64)
    c = np.asarray(coeffs, dtype=np.float64)
    a, b, g = (modified_a(n, xi[..., k]) for k, n in enumerate((n0, n1, n2)))
    if c.ndim == 1:
        return np.einsum("...i,...j,...k,kji->...", a, b, g, c.reshape(n2, n1, n0))
    return np.einsum("...si,...sj,...sk,...kji->...s", a, b, g, c.reshape(c.shape[:-1] + (n2, n1, n0)), optimize=True)


def _check_shape(shape) -> int:
    shape = int(shape)
    if shape not in NAMES:
        raise ValueError(f"unknown shape id {shape}")
    return shape


def _check_modes(shape, modes) -> tuple[int, int, int]:
    m = tuple(int(v) for v in np.asarray(modes).ravel())
    if len(m) != 3 or min(m) < 1:
        raise ValueError(f"modes must be three positive counts, got {modes!r}")
    # Nektar++ asserts these (Std{Prism,Tet,Pyr}Exp): the collapsed direction carries the top order
    if shape == PRISM and m[0] > m[2]:
        raise ValueError(f"prism modes {m}: direction 0 exceeds direction 2")
    if shape in (TET, PYR) and (m[0] > m[2] or m[1] > m[2]):
        raise ValueError(f"{NAMES[shape]} modes {m}: directions 0/1 exceed direction 2")
    return m


def num_coeffs(shape, modes) -> int:
    shape = _check_shape(shape)
    a, b, c = _check_modes(shape, modes)
    if shape == HEX:
        return a * b * c
    if shape == PRISM:
        return b * (a * (a + 1) // 2 + a * (c - a))
    if shape == TET:
        return sum(max(c - p - q, 0) for p in range(a) for q in range(max(b - p, 0)))
    return sum(c - max(p, q) for p in range(a) for q in range(b))


@lru_cache(maxsize=None)
def _triples(shape: int, modes: tuple[int, int, int]) -> np.ndarray:
    a, b, c = modes
    if shape == HEX:
        t = [(i, j, k) for k in range(c) for j in range(b) for i in range(a)]
    elif shape == PRISM:
        t = [(p, q, r) for p in range(a) for q in range(b) for r in range(c - p)]
    elif shape == TET:
        t = [(p, q, r) for p in range(a) for q in range(b - p) for r in range(c - p - q)]
    else:
        t = [(p, q, r) for p in range(a) for q in range(b) for r in range(c - max(p, q))]
    out = np.array(t, dtype=np.int64).reshape(-1, 3)
    out.setflags(write=False)
    return out


def mode_triples(shape, modes) -> np.ndarray:
    shape = _check_shape(shape)
    return _triples(shape, _check_modes(shape, modes)).copy()


# ---------------------------------------------------------------------------------------------
# collapsed coordinates


def _clamped(d):
    return np.where(np.abs(d) < ZERO_TOL, np.where(d < 0, -ZERO_TOL, ZERO_TOL), d)


def collapse(shape, xi) -> np.ndarray:
    shape = _check_shape(shape)
    xi = np.asarray(xi, dtype=np.float64)
    eta = xi.copy()
    x0, x1, x2 = xi[..., 0], xi[..., 1], xi[..., 2]
    if shape == PRISM:
        eta[..., 0] = 2.0 * (1.0 + x0) / _clamped(1.0 - x2) - 1.0
    elif shape == TET:
        eta[..., 0] = 2.0 * (1.0 + x0) / _clamped(-x1 - x2) - 1.0
        eta[..., 1] = 2.0 * (1.0 + x1) / _clamped(1.0 - x2) - 1.0
    elif shape == PYR:
        eta[..., 0] = 2.0 * (1.0 + x0) / _clamped(1.0 - x2) - 1.0
        eta[..., 1] = 2.0 * (1.0 + x1) / _clamped(1.0 - x2) - 1.0
    return eta


def uncollapse(shape, eta) -> np.ndarray:
    """xi (..., 3) of collapsed coordinates eta (..., 3): the cube [-1, 1]^3 onto the shape."""
    return _uncollapse(_check_shape(shape), eta)


def _uncollapse(shape, eta) -> np.ndarray:
    eta = np.asarray(eta, dtype=np.float64)
    xi = eta.copy()
    s = 0.5 * (1.0 - eta[..., 2])
    if shape in (PRISM, PYR):
        xi[..., 0] = (1.0 + eta[..., 0]) * s - 1.0
    if shape == PYR:
        xi[..., 1] = (1.0 + eta[..., 1]) * s - 1.0
    if shape == TET:
        xi[..., 1] = (1.0 + eta[..., 1]) * s - 1.0
        xi[..., 0] = (1.0 + eta[..., 0]) * 0.5 * (-xi[..., 1] - xi[..., 2]) - 1.0
    return xi


# ---------------------------------------------------------------------------------------------
# one-dimensional factors


def jacobi_polynomials(n: int, a: float, b: float, x) -> list:
    """[P^(a,b)_0 .. P^(a,b)_n](x), standard normalisation (three-term recurrence, as Polylib)."""
    out = [np.ones_like(x)]
    if n >= 1:
        out.append(0.5 * (a - b + (a + b + 2.0) * x))
    for k in range(2, n + 1):
        c = 2.0 * k + a + b
        a1 = 2.0 * k * (k + a + b) * (c - 2.0)
        a2 = (c - 1.0) * (a * a - b * b)
        a3 = (c - 2.0) * (c - 1.0) * c
        a4 = 2.0 * (k + a - 1.0) * (k + b - 1.0) * c
        out.append(((a2 + a3 * x) * out[-1] - a4 * out[-2]) / a1)
    return out


class _Jac:
    """Cached Jacobi families at one set of points: value and derivative of P^(a,b)_n."""

    def __init__(self, x, nmax):
        self.x, self.nmax, self.cache = x, nmax, {}

    def _fam(self, a, b):
        if (a, b) not in self.cache:
            self.cache[(a, b)] = jacobi_polynomials(self.nmax, float(a), float(b), self.x)
        return self.cache[(a, b)]

    def __call__(self, n, a, b):
        val = self._fam(a, b)[n]
        # d/dx P^(a,b)_n = (n + a + b + 1)/2 P^(a+1,b+1)_{n-1}
        der = 0.5 * (n + a + b + 1) * self._fam(a + 1, b + 1)[n - 1] if n > 0 else np.zeros_like(self.x)
        return val, der


def _mod_a(n: int, x):
    """Modified_A values (N, n) and derivatives (N, n)."""
    val = modified_a(n, x)
    der = np.empty_like(val)
    der[:, 0] = -0.5
    if n > 1:
        der[:, 1] = 0.5
    if n > 2:
        # phi_p = (1-x^2)/4 (2/p) L'_{p-1}; with Legendre's equation phi_p' = -(p-1)/2 L_{p-1}
        leg = legendre.legvander(x, n - 2)
        for p in range(2, n):
            der[:, p] = -0.5 * (p - 1) * leg[:, p - 1]
    return val, der


def modified_a_derivative(n: int, x) -> np.ndarray:
    """(N, n) derivatives of Modified_A modes 0..n-1 at x (N,)."""
    return _mod_a(n, np.asarray(x, dtype=np.float64).reshape(-1))[1]


def _w_power(k, m, dm, w):
    """value, derivative and value / w of w^k m(x), w = (1-x)/2, k >= 1."""
    wk1 = w ** (k - 1)
    return wk1 * w * m, -0.5 * k * wk1 * m + wk1 * w * dm, wk1 * m


def _mod_b(p: int, r: int, x, jac: _Jac):
    """Modified_B mode (p, r) at x: value, derivative, value / ((1-x)/2) (the last one is what the
    chain rule through the collapse needs; it is a polynomial except for (0, 1), which every shape
    replaces by its corrected mode, so zeros stand in for it)."""
    w, v = 0.5 * (1.0 - x), 0.5 * (1.0 + x)
    if p == 0 and r == 0:
        return w, np.full_like(x, -0.5), np.ones_like(x)
    if p == 0 and r == 1:
        return v, np.full_like(x, 0.5), np.zeros_like(x)
    if p == 0:
        J, dJ = jac(r - 2, 1, 1)
        return _w_power(1, v * J, 0.5 * J + v * dJ, w)
    if r == 0:
        return _w_power(p, np.ones_like(x), np.zeros_like(x), w)
    J, dJ = jac(r - 1, 2 * p - 1, 1)
    return _w_power(p, v * J, 0.5 * J + v * dJ, w)


def _mod_pyr_c(p: int, q: int, r: int, x, jac: _Jac):
    if p <= 1 or q <= 1:
        return _mod_b(max(p, q), r, x, jac)
    w, v = 0.5 * (1.0 - x), 0.5 * (1.0 + x)
    if r == 0:
        return _w_power(p + q - 2, np.ones_like(x), np.zeros_like(x), w)
    J, dJ = jac(r - 1, 2 * p + 2 * q - 3, 1)
    return _w_power(p + q - 2, v * J, 0.5 * J + v * dJ, w)


def _columns(keys, func):
    """Evaluate func(key) -> (val, der, red) once per distinct key; (N, nk) arrays and key index."""
    uniq = sorted(set(keys))
    pos = {k: i for i, k in enumerate(uniq)}
    cols = [func(k) for k in uniq]
    stack = [np.stack([c[i] for c in cols], axis=1) for i in range(3)]
    return stack[0], stack[1], stack[2], np.array([pos[k] for k in keys], dtype=np.int64)


# ---------------------------------------------------------------------------------------------
# the basis matrix and its gradient


def modal_basis(shape: int, modes, X, grad: bool, corrected: bool = True):
    """B (N, K) of every stored mode at points X (N, 3) and, with grad, dB/dxi (N, K, 3).
    Derivatives through the collapse use the reduced factors (value / collapse factor), so no
    division by (1 - xi3) or (-xi2 - xi3) occurs and the gradient is finite at the singularity."""
    t = _triples(shape, modes)
    p, q, r = t[:, 0], t[:, 1], t[:, 2]
    P0, P1, P2 = modes
    x0, x1, x2 = X[:, 0], X[:, 1], X[:, 2]
    G = None
    if shape == HEX:
        a, da = _mod_a(P0, x0)
        b, db = _mod_a(P1, x1)
        c, dc = _mod_a(P2, x2)
        B = a[:, p] * b[:, q] * c[:, r]
        if grad:
            G = np.stack([da[:, p] * b[:, q] * c[:, r], a[:, p] * db[:, q] * c[:, r], a[:, p] * b[:, q] * dc[:, r]], -1)
        return B, G

    eta = collapse(shape, X)
    e0, e1 = eta[:, 0], eta[:, 1]
    jac = _Jac(x2, P2)
    if shape == PRISM:
        F1, dF1 = _mod_a(P0, e0)
        F2, dF2 = _mod_a(P1, x1)
        H, dH, rH, h = _columns(list(zip(p.tolist(), r.tolist())), lambda k: _mod_b(k[0], k[1], x2, jac))
        B = F1[:, p] * F2[:, q] * H[:, h]
        if grad:
            g0 = dF1[:, p] * F2[:, q] * rH[:, h]
            g1 = F1[:, p] * dF2[:, q] * H[:, h]
            g2 = F2[:, q] * (dF1[:, p] * (0.5 * (1.0 + e0))[:, None] * rH[:, h] + F1[:, p] * dH[:, h])
            G = np.stack([g0, g1, g2], -1)
        if corrected:
            # singular edge 4-5: mode (0, q, 1) = phiA_q(xi2) (1 + xi3)/2, independent of eta1
            cols = np.nonzero((p == 0) & (r == 1))[0]
            up = 0.5 * (1.0 + x2)[:, None]
            B[:, cols] = F2[:, q[cols]] * up
            if grad:
                G[:, cols, 0] = 0.0
                G[:, cols, 1] = dF2[:, q[cols]] * up
                G[:, cols, 2] = 0.5 * F2[:, q[cols]]
        return B, G

    if shape == TET:
        F1, dF1 = _mod_a(P0, e0)
        jac2 = _Jac(e1, P1)
        Gv, dG, rG, g = _columns(list(zip(p.tolist(), q.tolist())), lambda k: _mod_b(k[0], k[1], e1, jac2))
        H, dH, rH, h = _columns(list(zip((p + q).tolist(), r.tolist())), lambda k: _mod_b(k[0], k[1], x2, jac))
        B = F1[:, p] * Gv[:, g] * H[:, h]
        if grad:
            a1 = (0.5 * (1.0 + e0))[:, None]
            a2 = (0.5 * (1.0 + e1))[:, None]
            t01 = dF1[:, p] * rG[:, g] * rH[:, h]  # d/deta1 term divided by both collapse factors
            g0 = t01
            g1 = a1 * t01 + F1[:, p] * dG[:, g] * rH[:, h]
            g2 = a1 * t01 + a2 * F1[:, p] * dG[:, g] * rH[:, h] + F1[:, p] * Gv[:, g] * dH[:, h]
            G = np.stack([g0, g1, g2], -1)
        if corrected:
            # vertex 3: mode (0,0,1) = (1 + xi3)/2
            top = np.nonzero((p == 0) & (q == 0) & (r == 1))[0]
            B[:, top] = 0.5 * (1.0 + x2)[:, None]
            if grad:
                G[:, top] = [0.0, 0.0, 0.5]
            # edge 2-3: modes (0,1,r) = phiB_{0,1}(eta2) phiC_{0,1,r}(eta3), independent of eta1
            cols = np.nonzero((p == 0) & (q == 1))[0]
            gc, hc = g[cols], h[cols]
            B[:, cols] = Gv[:, gc] * H[:, hc]
            if grad:
                a2 = (0.5 * (1.0 + e1))[:, None]
                G[:, cols, 0] = 0.0
                G[:, cols, 1] = dG[:, gc] * rH[:, hc]
                G[:, cols, 2] = a2 * dG[:, gc] * rH[:, hc] + Gv[:, gc] * dH[:, hc]
        return B, G

    # pyramid
    F1, dF1 = _mod_a(P0, e0)
    F2, dF2 = _mod_a(P1, e1)
    # ModifiedPyr_C depends on max(p, q) when p or q <= 1, else on p + q only
    keys = [("B", max(pp, qq), rr) if min(pp, qq) <= 1 else ("P", pp + qq, rr) for pp, qq, rr in t.tolist()]

    def pyr_col(k):
        return _mod_b(k[1], k[2], x2, jac) if k[0] == "B" else _mod_pyr_c(2, k[1] - 2, k[2], x2, jac)

    H, dH, rH, h = _columns(keys, pyr_col)
    B = F1[:, p] * F2[:, q] * H[:, h]
    if grad:
        g0 = dF1[:, p] * F2[:, q] * rH[:, h]
        g1 = F1[:, p] * dF2[:, q] * rH[:, h]
        g2 = ((0.5 * (1.0 + e0))[:, None] * g0 + (0.5 * (1.0 + e1))[:, None] * g1
              + F1[:, p] * F2[:, q] * dH[:, h])
        G = np.stack([g0, g1, g2], -1)
    if corrected:
        # apex: mode (0,0,1) = (1 + xi3)/2
        top = np.nonzero((p == 0) & (q == 0) & (r == 1))[0]
        B[:, top] = 0.5 * (1.0 + x2)[:, None]
        if grad:
            G[:, top] = [0.0, 0.0, 0.5]
    return B, G


def _points(xi):
    xi = np.asarray(xi, dtype=np.float64)
    if xi.shape[-1:] != (3,):
        raise ValueError(f"reference points need a trailing dimension of 3, got shape {xi.shape}")
    return xi.shape[:-1], xi.reshape(-1, 3)


def basis_matrix(shape, modes, xi, corrected: bool = True) -> np.ndarray:
    """(..., K): every stored mode at xi. corrected=False drops the collapsed-vertex corrections
    (wrong: only for showing what they fix)."""
    shape = _check_shape(shape)
    modes = _check_modes(shape, modes)
    lead, X = _points(xi)
    return modal_basis(shape, modes, X, False, corrected)[0].reshape(lead + (-1,))


def _evaluate(shape, modes, coeffs, xi, grad: bool):
    shape = _check_shape(shape)
    modes = _check_modes(shape, modes)
    k = num_coeffs(shape, modes)
    c = np.asarray(coeffs, dtype=np.float64)
    if c.ndim == 0 or c.shape[0] != k:
        raise ValueError(f"{NAMES[shape]} modes {modes} need {k} coefficients, got array of shape {c.shape}")
    vector = c.ndim > 1
    c2 = c.reshape(k, -1)
    lead, X = _points(xi)
    n, nc = X.shape[0], c2.shape[1]
    out = np.empty((n, nc, 3) if grad else (n, nc))
    step = max(1, _CHUNK // (k * (4 if grad else 1)))
    for i0 in range(0, n, step):
        B, G = modal_basis(shape, modes, X[i0:i0 + step], grad)
        if grad:
            out[i0:i0 + step] = np.matmul(G.transpose(0, 2, 1), c2).transpose(0, 2, 1)
        else:
            out[i0:i0 + step] = B @ c2
    tail = (c.shape[1:] if vector else ()) + ((3,) if grad else ())
    return out.reshape(lead + tail)


def eval_modal(shape, modes, coeffs, xi) -> np.ndarray:
    return _evaluate(shape, modes, coeffs, xi, grad=False)


def eval_modal_grad(shape, modes, coeffs, xi) -> np.ndarray:
    return _evaluate(shape, modes, coeffs, xi, grad=True)


# ---------------------------------------------------------------------------------------------
# fitting


def _radau_like(n):
    """n points on [-1, 1): GLL points of n + 1 without +1, so no two collapse onto one xi."""
    return gll_points(n + 1)[:-1]


@lru_cache(maxsize=None)
def _fit(shape: int, modes: tuple[int, int, int]):
    """Fit points and the least-squares solve matrix. The modes are tensor polynomials in the
    collapsed coordinates eta (degree < P per direction; pyramid's ModifiedPyr_C reaches
    min(P0, P1) + P2 - 4 in eta3), so a tensor grid in eta one point richer than that is
    unisolvent and well conditioned; the collapsed end (eta = +1) is left out."""
    P0, P1, P2 = modes
    if shape == HEX:
        axes = [gll_points(P0 + 1), gll_points(P1 + 1), gll_points(P2 + 1)]
    elif shape == PRISM:
        axes = [gll_points(P0 + 1), gll_points(P1 + 1), _radau_like(P2 + 1)]
    elif shape == TET:
        axes = [gll_points(P0 + 1), _radau_like(P1 + 1), _radau_like(P2 + 1)]
    else:
        axes = [gll_points(P0 + 1), gll_points(P1 + 1), _radau_like(max(P2, min(P0, P1) + P2 - 3) + 1)]
    eta = np.stack(np.meshgrid(*axes, indexing="ij"), axis=-1).reshape(-1, 3)
    pts = _uncollapse(shape, eta)
    B = modal_basis(shape, modes, pts, False)[0]
    solve = np.linalg.pinv(B)
    for a in (pts, B, solve):
        a.setflags(write=False)
    return pts, B, solve


def fit_points(shape, modes) -> np.ndarray:
    shape = _check_shape(shape)
    return _fit(shape, _check_modes(shape, modes))[0].copy()


def fit_modal(shape, modes, values) -> np.ndarray:
    shape = _check_shape(shape)
    pts, _, solve = _fit(shape, _check_modes(shape, modes))
    v = np.asarray(values, dtype=np.float64)
    if v.shape[0] != pts.shape[0]:
        raise ValueError(f"{v.shape[0]} values for {pts.shape[0]} fit points")
    return np.tensordot(solve, v, axes=(1, 0))


def gll_lagrange_hex_to_modal(modes, nodal) -> np.ndarray:
    """Nodal values at the tensor GLL points (node (i, j, k), i fastest, §2.10) -> Modified_A
    coefficients of the same polynomial (direction 0 fastest)."""
    n0, n1, n2 = _check_modes(HEX, modes)
    v = np.asarray(nodal, dtype=np.float64)
    if v.shape[0] != n0 * n1 * n2:
        raise ValueError(f"{v.shape[0]} nodal values for GLL_Lagrange modes {(n0, n1, n2)}")
    cols = v.reshape(n0 * n1 * n2, -1)
    out = np.empty_like(cols)
    for j in range(cols.shape[1]):
        grid = cols[:, j].reshape(n2, n1, n0).transpose(2, 1, 0)  # -> [i, j, k]
        out[:, j] = fit_tensor_coefficients(lambda a, b, c, g=grid: g, (n0, n1, n2))
    return out.reshape(v.shape)


# ---------------------------------------------------------------------------------------------
# reference-domain geometry


def inside(shape, xi, tol=1e-10) -> np.ndarray:
    shape = _check_shape(shape)
    xi = np.asarray(xi, dtype=np.float64)
    x0, x1, x2 = xi[..., 0], xi[..., 1], xi[..., 2]
    lo = (x0 >= -1 - tol) & (x1 >= -1 - tol) & (x2 >= -1 - tol)
    if shape == HEX:
        return lo & (x0 <= 1 + tol) & (x1 <= 1 + tol) & (x2 <= 1 + tol)
    if shape == PRISM:
        return lo & (x1 <= 1 + tol) & (x0 + x2 <= tol)
    if shape == TET:
        return lo & (x0 + x1 + x2 <= -1 + tol)
    return lo & (x0 + x2 <= tol) & (x1 + x2 <= tol)


_BOUND_GRID = 4096  # Chebyshev points per direction for the 1-D maxima of mode_max_bounds


@lru_cache(maxsize=64)
def mode_max_bounds(shape, modes) -> np.ndarray:
    """B (K,) with B[m] >= max |phi_m| over the element: certified, not sampled.

    Every stored mode (corrections included, as modal_basis builds them) is a product of 1-D
    factors in the collapsed coordinates (eta1, eta2 or xi2, xi3), which range over the whole
    cube independently, so its maximum is the product of the factors' maxima. A factor of
    degree D sampled at M Chebyshev points is bounded by the sample maximum / cos(pi D / 2M)
    (Ehlich and Zeller 1964); with M = 4096 and D <= 48 that factor is below 1.0002."""
    shape = _check_shape(shape)
    modes = _check_modes(shape, modes)
    M = _BOUND_GRID
    x = np.cos((2 * np.arange(M) + 1) * np.pi / (2 * M))
    grow = (1.0 / np.cos(np.pi * 48 / (2 * M))) * (1.0 + 1e-12)
    t = _triples(shape, modes)
    p, q, r = t[:, 0], t[:, 1], t[:, 2]
    P0, P1, P2 = modes

    def amax(n):  # max |Modified_A_k| for k < n
        return np.abs(_mod_a(n, x)[0]).max(axis=0) * grow

    jac = _Jac(x, max(modes) + 2)

    def bmax(keys, func):
        cache = {}
        for k in keys:
            if k not in cache:
                cache[k] = np.abs(func(k)[0]).max() * grow
        return np.array([cache[k] for k in keys])

    top = grow  # (1 + x)/2 on [-1, 1]
    if shape == HEX:
        return amax(P0)[p] * amax(P1)[q] * amax(P2)[r]
    if shape == PRISM:
        B = amax(P0)[p] * amax(P1)[q] * bmax(list(zip(p.tolist(), r.tolist())), lambda k: _mod_b(k[0], k[1], x, jac))
        cols = (p == 0) & (r == 1)
        B[cols] = amax(P1)[q[cols]] * top
        return B
    if shape == TET:
        G = bmax(list(zip(p.tolist(), q.tolist())), lambda k: _mod_b(k[0], k[1], x, jac))
        H = bmax(list(zip((p + q).tolist(), r.tolist())), lambda k: _mod_b(k[0], k[1], x, jac))
        B = amax(P0)[p] * G * H
        B[(p == 0) & (q == 0) & (r == 1)] = top
        cols = (p == 0) & (q == 1)
        B[cols] = G[cols] * H[cols]
        return B
    keys = [("B", max(pp, qq), rr) if min(pp, qq) <= 1 else ("P", pp + qq, rr) for pp, qq, rr in t.tolist()]
    H = bmax(keys, lambda k: _mod_b(k[1], k[2], x, jac) if k[0] == "B" else _mod_pyr_c(2, k[1] - 2, k[2], x, jac))
    B = amax(P0)[p] * amax(P1)[q] * H
    B[(p == 0) & (q == 0) & (r == 1)] = top
    return B


def vertex_mode_indices(shape, modes) -> np.ndarray:
    """Storage index of the mode belonging to each vertex (§2.8 order); modes >= 2 per direction."""
    shape = _check_shape(shape)
    modes = _check_modes(shape, modes)
    if min(modes) < 2:
        raise ValueError("vertex modes need at least 2 modes per direction")
    t = _triples(shape, modes)
    look = {tuple(v): i for i, v in enumerate(t.tolist())}
    per_shape = {
        HEX: [(0, 0, 0), (1, 0, 0), (1, 1, 0), (0, 1, 0), (0, 0, 1), (1, 0, 1), (1, 1, 1), (0, 1, 1)],
        PRISM: [(0, 0, 0), (1, 0, 0), (1, 1, 0), (0, 1, 0), (0, 0, 1), (0, 1, 1)],
        TET: [(0, 0, 0), (1, 0, 0), (0, 1, 0), (0, 0, 1)],
        PYR: [(0, 0, 0), (1, 0, 0), (1, 1, 0), (0, 1, 0), (0, 0, 1)],
    }[shape]
    return np.array([look[v] for v in per_shape], dtype=np.int64)


def _axis_vertices(shape):
    """Indices of the vertices at xi = -1 + 2 e_d from vertex 0 (one per reference axis)."""
    V = VERTICES[shape]
    return [int(np.nonzero((V == -1 + 2 * np.eye(3)[d]).all(axis=1))[0][0]) for d in range(3)]


def _vertex_affine(shape, modes, g):
    """x = v0 + J (xi + 1) through vertex 0 and the three axis vertices."""
    V = eval_modal(shape, modes, g, VERTICES[shape])
    J = 0.5 * (V[_axis_vertices(shape)] - V[0]).T  # columns dx/dxi_d
    return V, J


def affine_fit(shape, gmodes, gcoeffs):
    """(A, b, ok). Without ok, A and b are the map through vertex 0 and the axis vertices (a seed
    for Newton), or zeros for a degenerate element."""
    shape = _check_shape(shape)
    gmodes = _check_modes(shape, gmodes)
    g = np.asarray(gcoeffs, dtype=np.float64).reshape(-1, 3)
    V, J = _vertex_affine(shape, gmodes, g)
    extent = float(np.abs(V - V.mean(axis=0)).max())
    det = np.linalg.det(J)
    if not np.all(np.isfinite(J)) or extent == 0.0 or abs(det) <= 1e-12 * extent**3:
        return np.zeros((3, 3)), np.zeros(3), False
    A = np.linalg.inv(J)
    b = -A @ V[0] - 1.0
    pts, B, _ = _fit(shape, gmodes)  # the difference of two maps in the space vanishes iff it does here
    dev = np.abs(B @ g - (V[0] + (pts + 1.0) @ J.T)).max()
    ok = bool(dev <= 1e-12 * (extent + np.abs(V).max()))
    return A, b, ok


_BOX = 0.5  # Newton may leave the element by this much (in eta) before it is held back


def hold_inside(shape, xi):
    """Clamp Newton iterates to a slightly enlarged element: a box in the collapsed coordinates,
    xi3 <= 1 (beyond the collapse the collapsed shapes fold over)."""
    if shape == HEX:
        return np.clip(xi, -1 - _BOX, 1 + _BOX)
    eta = collapse(shape, xi)
    eta[:, 2] = np.clip(eta[:, 2], -1 - _BOX, 1.0)
    eta[:, 0] = np.clip(eta[:, 0], -1 - _BOX, 1 + _BOX)
    eta[:, 1] = np.clip(eta[:, 1], -1 - _BOX, 1.0 if shape == TET else 1 + _BOX)
    return _uncollapse(shape, eta)


def _solve3(J, r):
    det = np.linalg.det(J)
    good = np.isfinite(det) & (np.abs(det) > 1e-300)
    out = np.zeros_like(r)
    if good.any():
        out[good] = np.linalg.solve(J[good], r[good][..., None])[..., 0]
    if (~good).any():  # singular Jacobian: least-norm step instead of failing the batch
        Jb = np.nan_to_num(J[~good])
        out[~good] = (np.linalg.pinv(Jb) @ np.nan_to_num(r[~good])[..., None])[..., 0]
    return out


def invert_map(shape, gmodes, gcoeffs, x, xi0=None, tol=1e-12, max_iter=50):
    shape = _check_shape(shape)
    gmodes = _check_modes(shape, gmodes)
    g = np.asarray(gcoeffs, dtype=np.float64).reshape(-1, 3)
    lead, X = _points(x)
    n = X.shape[0]

    def xmap(xi):
        return _evaluate(shape, gmodes, g, xi, False)

    if xi0 is None:
        # best of: the vertex-affine guess and a fixed grid of interior seeds
        A, b, _ = affine_fit(shape, gmodes, g)
        cand = hold_inside(shape, X @ A.T + b)
        best = np.linalg.norm(xmap(cand) - X, axis=1)
        grid = np.array([-0.6, 0.0, 0.6])
        seeds = _uncollapse(shape, np.stack(np.meshgrid(grid, grid, grid, indexing="ij"), -1).reshape(-1, 3))
        seeds = np.vstack([CENTROIDS[shape], seeds])
        xs = xmap(seeds)
        d = np.linalg.norm(X[:, None, :] - xs[None, :, :], axis=2)
        j = d.argmin(axis=1)
        use = d[np.arange(n), j] < best
        xi = cand
        xi[use] = seeds[j[use]]
    else:
        xi = hold_inside(shape, np.broadcast_to(np.asarray(xi0, dtype=np.float64), lead + (3,)).reshape(-1, 3).copy())

    # Newton steps below round-off are as good as it gets: eps * |coefficients| * |J^-1|
    cmag = np.abs(g).sum(axis=0).max()
    conv = np.zeros(n, dtype=bool)
    active = np.arange(n)
    for _ in range(max_iter):
        if active.size == 0:
            break
        xa = xi[active]
        B, G = modal_basis(shape, gmodes, xa, True)
        val = B @ g
        J = np.matmul(G.transpose(0, 2, 1), g).transpose(0, 2, 1)  # (m, 3 coords, 3 xi)
        r = X[active] - val
        step = _solve3(J, r)
        with np.errstate(all="ignore"):
            noise = 64 * np.finfo(float).eps * cmag * np.abs(np.linalg.pinv(np.nan_to_num(J))).sum(axis=2).max(axis=1)
        small = np.abs(step).max(axis=1) <= np.maximum(tol, noise)
        if small.any():
            idx = active[small]
            xi[idx] = hold_inside(shape, xa[small] + step[small])
            conv[idx] = True
        rest = ~small
        xa, step, rn, idx = xa[rest], step[rest], np.linalg.norm(r[rest], axis=1), active[rest]
        accepted = np.zeros(idx.size, dtype=bool)
        alpha = 1.0
        for _ls in range(12):  # damping: halve until the residual drops
            todo = ~accepted
            if not todo.any():
                break
            cand = hold_inside(shape, xa[todo] + alpha * step[todo])
            rc = np.linalg.norm(X[idx[todo]] - xmap(cand), axis=1)
            ok = rc < rn[todo]
            sel = np.nonzero(todo)[0][ok]
            xi[idx[sel]] = cand[ok]
            accepted[sel] = True
            alpha *= 0.5
        active = idx[accepted]  # no descent possible: stuck at the clamp or at a fold, give up
    xi_out = xi.reshape(lead + (3,))
    ins = conv & inside(shape, xi, max(1e-10, 10 * tol))
    return xi_out, conv.reshape(lead), ins.reshape(lead)
