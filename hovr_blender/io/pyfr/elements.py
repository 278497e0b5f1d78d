"""PyFR's four 3-D element types as the engine holds them: reference frames, polynomial spaces,
shape points, and the exact change of basis from values at points to modal coefficients.

Facts from PyFR 3.1 (pyfr/shapes.py, pyfr/polys.py; docs/spec/formats.md §6):
- Reference elements, all in [-1, 1]: `hex` the cube; `tet` x + y + z <= -1 (the engine's own);
  `pri` the triangle x + y <= 0 times the line z; `pyr` the square base |x|, |y| <= 1 at z = -1
  with its apex at (0, 0, 1).
- The solution of order n at its solution points is the polynomial of PyFR's space through
  them: hex Q_n, pri P_n(triangle) x P_n(line), tet P_n; pyr the span of
  P_i(a) P_j(b) (1 - z)^(i + j) P_k^(2i+2j+2, 0)(z), a = 2x/(1 - z), b = 2y/(1 - z),
  k < n + 1 - max(i, j) (polynomial: (1 - z)^i P_i(a) is one in x and z).
- Shape points of order s: equispaced (`std_ele`), x fastest, interpolated in the same spaces.

The engine's spaces (engine/expansions.py): hex, pri and tet of order n are its expansions of
n + 1 modes (the prism's triangle is the engine's (xi1, xi3), so PyFR (x, y, z) -> xi =
(y, z, x), a cyclic and so orientation-keeping map); PyFR's pyramid of order n lies inside the
engine's pyramid of 2n + 1 modes (degree 2n, checked in tests/io/test_pyfr.py), through the
affine map xi = (x - (1 + z)/2, y - (1 + z)/2, z). Values at PyFR's points are therefore
converted exactly: interpolate in PyFR's space (its Vandermonde matrix at the file's points),
evaluate at the engine's fit points, fit the modal expansion (exact for a function in the space).
"""
from __future__ import annotations

from functools import lru_cache

import numpy as np

from ...engine import expansions as ex
from ...engine.shapes import HEX, MAX_MODES, PRISM, PYR, TET

ETYPES = {"hex": HEX, "pri": PRISM, "tet": TET, "pyr": PYR}  # PyFR's names of the 3-D types
NAMES = {"hex": "hexahedron", "pri": "prism", "tet": "tetrahedron", "pyr": "pyramid"}
UNISOLVENT_CONDITION = 1e10  # a point set whose Vandermonde matrix is worse is refused


class PointsError(ValueError):
    """Points that cannot carry a polynomial of the element's space (the caller names the file)."""


def npts(etype: str, order: int) -> int:
    """Points of PyFR's space of this order (pyfr/shapes.py npts_from_order)."""
    n = order + 1
    return {"hex": n ** 3, "pri": n * n * (n + 1) // 2, "tet": n * (n + 1) * (n + 2) // 6,
            "pyr": n * (n + 1) * (2 * n + 1) // 6}[etype]


def order_from_npts(etype: str, count: int) -> int | None:
    """The order whose space has `count` points, or None."""
    for order in range(MAX_MODES):
        if npts(etype, order) == count:
            return order
        if npts(etype, order) > count:
            return None
    return None


def modes(etype: str, order: int) -> tuple[int, int, int]:
    """The engine's modes that hold PyFR's space of this order."""
    m = 2 * order + 1 if etype == "pyr" else order + 1
    return (m, m, m)


def max_order(etype: str) -> int:
    return (MAX_MODES - 1) // 2 if etype == "pyr" else MAX_MODES - 1


def std_ele(etype: str, order: int) -> np.ndarray:
    """(npts, 3) PyFR's shape points of this order in its reference element, in its order."""
    p = np.linspace(-1.0, 1.0, order + 1)
    if etype == "hex":
        out = [(x, y, z) for z in p for y in p for x in p]
    elif etype == "pri":
        out = [(x, y, z) for z in p for i, y in enumerate(p) for x in p[: order + 1 - i]]
    elif etype == "tet":
        out = [(x, y, z) for i, z in enumerate(p) for j, y in enumerate(p[: order + 1 - i])
               for x in p[: order + 1 - i - j]]
    else:
        q = np.linspace(-1.0, 1.0, 2 * order + 1)
        out = [(x, y, z) for i, z in enumerate(q[::2]) for y in q[i: 2 * order + 1 - i: 2]
               for x in q[i: 2 * order + 1 - i: 2]]
    return np.array(out, dtype=np.float64).reshape(-1, 3)


def to_engine(etype: str, pts) -> np.ndarray:
    """The engine's reference coordinates xi of PyFR reference points (..., 3)."""
    p = np.asarray(pts, dtype=np.float64)
    if etype == "pri":
        return p[..., [1, 2, 0]]
    if etype == "pyr":
        shift = 0.5 * (1.0 + p[..., 2:])
        return np.concatenate([p[..., :2] - shift, p[..., 2:]], axis=-1)
    return p.copy()


def from_engine(etype: str, xi) -> np.ndarray:
    """PyFR reference coordinates of the engine's xi (..., 3)."""
    x = np.asarray(xi, dtype=np.float64)
    if etype == "pri":
        return x[..., [2, 0, 1]]
    if etype == "pyr":
        shift = 0.5 * (1.0 + x[..., 2:])
        return np.concatenate([x[..., :2] + shift, x[..., 2:]], axis=-1)
    return x.copy()


def _pyramid_basis(order: int, pts) -> np.ndarray:
    """(N, npts) PyFR's orthonormal pyramid basis of this order at PyFR points (pyr PolyBasis)."""
    p = np.asarray(pts, dtype=np.float64).reshape(-1, 3)
    x, y, z = p[:, 0], p[:, 1], p[:, 2]
    n = order + 1
    with np.errstate(divide="ignore", invalid="ignore"):
        a = np.where(z != 1, 2 * x / (1 - z), 0.0)
        b = np.where(z != 1, 2 * y / (1 - z), 0.0)
    scale = [2.0 ** (-k - 0.25) * (k + 0.5) ** 0.5 for k in range(n)]
    pa = [s * j for s, j in zip(scale, ex.jacobi_polynomials(n - 1, 0.0, 0.0, a))]
    pb = [s * j for s, j in zip(scale, ex.jacobi_polynomials(n - 1, 0.0, 0.0, b))]
    cols = []
    for i in range(n):
        for j in range(n):
            for k, pk in enumerate(ex.jacobi_polynomials(n - max(i, j) - 1, 2.0 * (i + j + 1), 0.0, z)):
                cols.append((2.0 * (k + j + i) + 3.0) ** 0.5 * (1 - z) ** (i + j) * pa[i] * pb[j] * pk)
    return np.stack(cols, axis=-1)


def space_basis(etype: str, order: int, pts) -> np.ndarray:
    """(N, npts) a basis of PyFR's space of this order at PyFR reference points (N, 3)."""
    if etype == "pyr":
        return _pyramid_basis(order, pts)
    return ex.basis_matrix(ETYPES[etype], modes(etype, order), to_engine(etype, pts))


def check_points(etype: str, order: int, pts, tol: float = 1e-8) -> np.ndarray:
    """The points (npts, 3) as float64 if they lie in the reference element and carry the space
    (a well-conditioned Vandermonde matrix); PointsError says why not."""
    p = np.asarray(pts, dtype=np.float64)
    if p.shape != (npts(etype, order), 3):
        raise PointsError(f"{p.shape[0] if p.ndim else 0} points of shape {p.shape} for a {NAMES[etype]} of "
                          f"order {order}, which needs ({npts(etype, order)}, 3)")
    if not np.all(np.isfinite(p)):
        raise PointsError("points are NaN or Inf")
    if not np.all(ex.inside(ETYPES[etype], to_engine(etype, p), tol)):
        raise PointsError(f"points lie outside PyFR's reference {NAMES[etype]}")
    cond = np.linalg.cond(space_basis(etype, order, p))
    if not cond < UNISOLVENT_CONDITION:
        raise PointsError(f"the points do not determine a polynomial of order {order} (Vandermonde "
                          f"condition number {cond:.3g})")
    return p


@lru_cache(maxsize=64)
def _conversion(etype: str, order: int, key: bytes) -> np.ndarray:
    pts = np.frombuffer(key, dtype=np.float64).reshape(-1, 3)
    m = modes(etype, order)
    fit = from_engine(etype, ex.fit_points(ETYPES[etype], m))
    interpolate = np.linalg.solve(space_basis(etype, order, pts).T, space_basis(etype, order, fit).T).T
    T = np.asarray(ex.fit_modal(ETYPES[etype], m, interpolate), dtype=np.float64)
    T.setflags(write=False)
    return T


def conversion(etype: str, order: int, pts) -> np.ndarray:
    """(K, npts): modal coefficients (modes(etype, order)) = matrix @ values at the points (checked
    with check_points first); one matrix per element type, order and point set."""
    p = np.ascontiguousarray(pts, dtype=np.float64)
    return _conversion(etype, int(order), p.tobytes())
