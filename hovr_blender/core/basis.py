"""Host-side (numpy, float64) one-dimensional bases, for fitting and for the reference.

The kernels evaluate the same polynomials with their own recurrence (kernels/element.py);
tests compare the two. Basis ids are shared with the kernels.
"""
from __future__ import annotations

import numpy as np
from numpy.polynomial import legendre

MODIFIED_A = 0  # Nektar++ Modified_A (§2.9 of spec/formats.md)

BASIS_NAMES = {MODIFIED_A: "Modified_A"}
MAX_MODES = 15  # degree 14 per direction


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


def basis_values(basis: int, n: int, x) -> np.ndarray:
    if basis == MODIFIED_A:
        return modified_a(n, x)
    raise ValueError(f"unknown basis id {basis}")


def gll_points(n: int) -> np.ndarray:
    """n Gauss-Lobatto-Legendre points on [-1, 1] (n >= 2)."""
    if n < 2:
        return np.zeros(1)
    interior = legendre.Legendre.basis(n - 1).deriv().roots()
    return np.concatenate([[-1.0], np.sort(interior.real), [1.0]])


def fit_tensor_coefficients(func, modes, basis: int = MODIFIED_A) -> np.ndarray:
    """Coefficients c[i + n0 (j + n1 k)] of the tensor expansion interpolating func(xi1, xi2, xi3)
    at GLL points; exact when func is in the space (e.g. a polynomial of degree < n per direction)."""
    n0, n1, n2 = (int(m) for m in modes)
    pts = [gll_points(n) for n in (n0, n1, n2)]
    X = np.meshgrid(*pts, indexing="ij")
    vals = np.asarray(func(*X), dtype=np.float64)  # (n0, n1, n2)
    V = [basis_values(basis, n, p) for n, p in zip((n0, n1, n2), pts)]
    c = np.einsum("ai,ijk->ajk", np.linalg.inv(V[0]), vals)
    c = np.einsum("bj,ajk->abk", np.linalg.inv(V[1]), c)
    c = np.einsum("ck,abk->abc", np.linalg.inv(V[2]), c)
    return np.ascontiguousarray(c.transpose(2, 1, 0)).ravel()  # direction 0 fastest


def eval_tensor(coeffs: np.ndarray, modes, xi, basis: int = MODIFIED_A) -> np.ndarray:
    """Evaluate one hexahedral tensor expansion at reference points xi (..., 3)."""
    n0, n1, n2 = (int(m) for m in modes)
    xi = np.asarray(xi, dtype=np.float64)
    c = np.asarray(coeffs, dtype=np.float64).reshape(n2, n1, n0)
    a = basis_values(basis, n0, xi[..., 0])
    b = basis_values(basis, n1, xi[..., 1])
    g = basis_values(basis, n2, xi[..., 2])
    return np.einsum("...i,...j,...k,kji->...", a, b, g, c)
