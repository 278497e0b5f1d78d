"""Curved-element geometry as tensor-product Legendre polynomials, for the device's Newton solves.

The importers give x(xi) as a modal expansion of the element's own shape (collapsed
coordinates for prisms, tets and pyramids). Newton inversion needs x and its Jacobian
at many points per ray; in collapsed coordinates the Jacobian needs the chain rule
through the collapse and is singular at it. Every such map is, however, a polynomial in
xi (pyramids: x w^2 with w = (1 - xi3) / 2 is), of degree <= D per direction, so it is
re-expressed once on the host as sum c_abc L_a(xi1) L_b(xi2) L_c(xi3) — the same
polynomial, not an approximation — whose value and gradient the device gets in one pass.

The fit interpolates the original expansion on a tensor grid where it is that polynomial and
never singular: a hexahedron's Chebyshev-Lobatto grid of the cube; a prism's and a pyramid's
Chebyshev-Gauss grid of the whole cube (their collapsed coordinates are defined off the element
too, but on the collapsed face's plane, which interior points never reach); a tetrahedron's
Chebyshev-Lobatto grid of a box inside it (its collapse is singular inside the cube), and by least
squares over its whole element where that box's extrapolation to the rest is off. The residual is
checked at other points of the whole element: MeshError if the re-expression is not the same
polynomial. (A pyramid interpolated on the box [-1, 0]^3 alone was 3e-5 of its map off at its base
corners: the Chebyshev polynomials grow fast outside the box.)
"""
from __future__ import annotations

import numpy as np

from . import expansions as ex
from . import shapes

# The box each shape's fit interpolates on (lower corner -1 in every direction, upper corner) and
# whether its grid is Chebyshev-Gauss (interior points) rather than Chebyshev-Lobatto
_FIT_BOX_UPPER = {shapes.HEX: (1.0, 1.0, 1.0), shapes.PRISM: (1.0, 1.0, 1.0),
                  shapes.TET: (-1.0 / 3.0, -1.0 / 3.0, -1.0 / 3.0), shapes.PYR: (1.0, 1.0, 1.0)}
_INTERIOR_GRID = {shapes.HEX: False, shapes.PRISM: True, shapes.TET: False, shapes.PYR: True}
CHECK_RTOL = 1e-8  # the re-expression's largest residual over the element, relative to the map's size
MAX_DEGREE = 16  # per direction, device vectors hold MAX_DEGREE + 1 Legendre values


def tensor_degree(shape: int, gmodes) -> int:
    """Per-direction degree D of x(xi) (times w^2 for pyramids) as a polynomial in xi."""
    gm = np.asarray(gmodes, dtype=int)
    if shape == shapes.HEX:
        return int(gm.max() - 1)
    if shape == shapes.PYR:
        return int(gm.sum() - 3 + 2)
    return int(gm.max() - 1)


def weight(shape: int, xi) -> np.ndarray:
    """w with x w^2 polynomial: (1 - xi3) / 2 for pyramids, 1 otherwise."""
    xi = np.asarray(xi, dtype=np.float64)
    if shape == shapes.PYR:
        return 0.5 * (1.0 - xi[..., 2])
    return np.ones(xi.shape[:-1])


def legendre(D: int, x) -> np.ndarray:
    """(len(x), D + 1): L_0..L_D at x."""
    x = np.asarray(x, dtype=np.float64)
    out = np.empty(x.shape + (D + 1,))
    out[..., 0] = 1.0
    if D >= 1:
        out[..., 1] = x
    for k in range(1, D):
        out[..., k + 1] = ((2 * k + 1) * x * out[..., k] - k * out[..., k - 1]) / (k + 1)
    return out


def _grid(shape: int, D: int, n: int | None = None) -> np.ndarray:
    up = np.asarray(_FIT_BOX_UPPER[shape])
    n = D + 1 if n is None else n
    if _INTERIOR_GRID[shape]:
        s = 0.5 * (1.0 - np.cos(np.pi * (np.arange(n) + 0.5) / n))
    else:
        s = 0.5 * (1.0 - np.cos(np.pi * np.arange(n) / max(n - 1, 1))) if n > 1 else np.array([0.5])
    axes = [-1.0 + s * (u + 1.0) for u in up]
    X = np.stack(np.meshgrid(*axes, indexing="ij"), axis=-1).reshape(-1, 3)
    return X


def _element_points(shape: int, n: int) -> np.ndarray:
    """Interior points of the whole reference element: its collapsed cube's Gauss-Legendre grid of
    n a direction, mapped into it."""
    g = np.polynomial.legendre.leggauss(n)[0]
    X = np.stack(np.meshgrid(g, g, g, indexing="ij"), axis=-1).reshape(-1, 3)
    return X if shape == shapes.HEX else ex.uncollapse(shape, X)


def _values(shape: int, gmodes, G: np.ndarray, X: np.ndarray) -> np.ndarray:
    """(m, P, 3): x w^2 of every element at the points."""
    return np.einsum("pk,mkc->mpc", ex.basis_matrix(shape, gmodes, X), G) * (weight(shape, X) ** 2)[None, :, None]


def _residual(shape: int, gmodes, G: np.ndarray, D: int, C: np.ndarray) -> np.ndarray:
    """(m,): each element's largest residual of the re-expression over its whole element, relative
    to the size of its coefficients."""
    Y = _element_points(shape, D + 3)
    got = np.einsum("pk,mkc->mpc", tensor_matrix(D, Y), C)
    return np.abs(got - _values(shape, gmodes, G, Y)).max(axis=(1, 2)) / (np.abs(G).max(axis=(1, 2)) + 1e-300)


def tensor_matrix(D: int, xi) -> np.ndarray:
    """(P, (D+1)^3) tensor Legendre basis at xi, index a + (D+1)(b + (D+1)c)."""
    xi = np.asarray(xi, dtype=np.float64)
    L = [legendre(D, xi[:, k]) for k in range(3)]
    return np.einsum("pa,pb,pc->pcba", L[0], L[1], L[2]).reshape(len(xi), -1)


def fit_tensor_geometry(shape: int, gmodes, G: np.ndarray, element_ids=None):
    """G (m, K, 3) modal geometry of m elements of one shape and geometry order ->
    (D, C) with C (m, (D+1)^3, 3) the tensor Legendre coefficients of x w^2."""
    from .mesh_base import MeshError

    D = tensor_degree(shape, gmodes)
    if D > MAX_DEGREE:
        raise MeshError(f"geometry of degree {D} per direction exceeds {MAX_DEGREE}")
    X = _grid(shape, D)
    m = G.shape[0]
    C = np.linalg.solve(tensor_matrix(D, X), _values(shape, gmodes, G, X).transpose(1, 0, 2).reshape(len(X), -1))
    C = C.reshape(-1, m, 3).transpose(1, 0, 2)
    err = _residual(shape, gmodes, G, D, C)
    off = err > CHECK_RTOL
    if np.any(off) and shape == shapes.TET:
        # a tetrahedron's box extrapolated too far: least squares over its whole element
        Y = _element_points(shape, 2 * D + 2)
        fit = np.linalg.lstsq(tensor_matrix(D, Y), _values(shape, gmodes, G[off], Y).transpose(1, 0, 2).reshape(len(Y), -1),
                              rcond=None)[0]
        C[off] = fit.reshape(-1, int(off.sum()), 3).transpose(1, 0, 2)
        err[off] = _residual(shape, gmodes, G[off], D, C[off])
    if np.any(err > CHECK_RTOL):
        bad = int(np.argmax(err))
        e = bad if element_ids is None else int(element_ids[bad])
        raise MeshError(f"element {e}: geometry is not a polynomial of degree {D} per direction "
                        f"(tensor re-expression off by {err[bad]:.2e} relative)")
    return D, C


def mesh_tensor_geometry(mesh):
    """(degree (N,), offset (N,), coefficients (K, 3), centre (N, 3)) for the mesh's non-affine
    elements (affine ones get degree 0 and no coefficients). Coefficients are of
    (x - centre) w^2, so float32 keeps precision for meshes far from the origin."""
    n = mesh.num_elements
    degree = np.zeros(n, np.int32)
    offset = np.zeros(n, np.int64)
    centre = np.zeros((n, 3))
    blocks = {}
    if mesh.geom_coeffs is None or mesh.affine is None or mesh.affine.all():
        return degree, offset, np.zeros((1, 3)), centre
    centre = mesh.vertices.mean(axis=1)
    curved = np.nonzero(~mesh.affine)[0]
    keys = np.concatenate([mesh.shape[curved, None], mesh.geom_modes[curved]], axis=1)
    for key in np.unique(keys, axis=0):
        sh, gm = int(key[0]), tuple(int(v) for v in key[1:])
        idx = curved[(keys == key).all(axis=1)]
        K = ex.num_coeffs(sh, gm)
        G = np.stack([mesh.geom_coeffs[mesh.geom_offset[e]: mesh.geom_offset[e] + K] for e in idx])
        D, C = fit_tensor_geometry(sh, gm, G, idx)
        # subtract the centre: x w^2 - c w^2, with w^2's own Legendre coefficients
        W = np.linalg.solve(tensor_matrix(D, _grid(sh, D)), weight(sh, _grid(sh, D)) ** 2)
        C = C - W[None, :, None] * centre[idx][:, None, :]
        degree[idx] = D
        for j, e in enumerate(idx):
            blocks[int(e)] = C[j]
    sizes = np.array([blocks[e].shape[0] if e in blocks else 0 for e in range(n)], np.int64)
    offset = np.concatenate([[0], np.cumsum(sizes)[:-1]]).astype(np.int64)
    coeffs = np.concatenate([blocks[e] for e in sorted(blocks)], axis=0)
    return degree, offset, coeffs, centre
