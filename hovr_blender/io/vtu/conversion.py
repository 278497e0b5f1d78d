"""A VTK cell -> the same polynomial as modal expansions (docs/spec/formats.md §4).

A cell of degree p is a polynomial in the same space as the MODIFIED expansion with p+1 modes
per direction (hex Q_p, tet P_p, wedge P_p(triangle) x P_q(line)), so field and geometry are
converted exactly: the cell's own interpolant (Lagrange on equispaced nodes, or Bernstein) is
evaluated at expansions.fit_points and fitted with expansions.fit_modal. One (modes x nodes)
matrix per cell kind and degree serves all its cells.

Reference-cell correspondence. Hex and tet: xi = 2r - 1. Wedge: VTK's triangle (r, s) is our
(xi3, xi1) triangle and VTK's t is our xi2 -- a cyclic permutation, so orientation is kept;
VTK corners 0..5 land on our prism vertices 0, 4, 1, 3, 5, 2. Writers differ in handedness
(NGSolve's hexahedra are all left-handed in VTK's frame), so a cell whose signed volume is
negative is read through the mirrored correspondence (`mirror`): every element comes out
right-handed, and then the engine certifies it (engine/validity.py).
"""
from __future__ import annotations

import math
from functools import lru_cache

import numpy as np

from ...engine import expansions as ex
from ...engine.shapes import HEX, PRISM, TET
from .cells import hex_order, tet_order, wedge_order


def xi_to_vtk(shape, xi, mirror=False):
    """VTK parametric coordinates of our reference points xi (..., 3)."""
    r = 0.5 * (np.asarray(xi, dtype=np.float64) + 1.0)
    if shape == PRISM:
        return r[..., [0, 2, 1]] if mirror else r[..., [2, 0, 1]]
    if mirror and shape == TET:
        return r[..., [1, 0, 2]]
    if mirror:
        return np.concatenate([r[..., :2], 1.0 - r[..., 2:]], axis=-1)
    return r


def _lagrange_1d(n, x):
    """(M, n+1) equispaced Lagrange basis on [0, 1] at x (M,)."""
    z = n * x
    out = np.ones(x.shape + (n + 1,))
    for a in range(n + 1):
        for b in range(n + 1):
            if b != a:
                out[:, a] *= (z - b) / (a - b)
    return out


def _bernstein_1d(n, x):
    return np.stack([math.comb(n, a) * x**a * (1.0 - x) ** (n - a) for a in range(n + 1)], axis=-1)


def _simplex_factor(family, n, barycentric):
    """(M, n+1) per-barycentric factor: Lagrange (Silvester) prod_{s<a} (n lam - s)/(s+1) or
    Bernstein lam^a / a! (the n! is applied by the caller)."""
    out = np.ones(barycentric.shape + (n + 1,))
    for a in range(1, n + 1):
        if family == "bezier":
            out[:, a] = barycentric**a / math.factorial(a)
        else:
            out[:, a] = out[:, a - 1] * (n * barycentric - (a - 1)) / a
    return out


def cell_basis(shape, family, degrees, params, vtk8=False):
    """(M, N) values of the cell's N nodal (Lagrange) or control-point (Bernstein) basis
    functions, VTK point order, at VTK parametric points (M, 3)."""
    params = np.asarray(params, dtype=np.float64)
    one_d = _bernstein_1d if family == "bezier" else _lagrange_1d
    if shape == HEX:
        lattice = np.array(hex_order(*degrees, vtk8=vtk8))
        factors = [one_d(degrees[d], params[:, d]) for d in range(3)]
        return factors[0][:, lattice[:, 0]] * factors[1][:, lattice[:, 1]] * factors[2][:, lattice[:, 2]]
    if shape == TET:
        n = degrees[0]
        lattice = np.array(tet_order(n))
        r, s, t = params.T
        barycentric = (1.0 - r - s - t, r, s, t)
        out = np.ones((params.shape[0], lattice.shape[0]))
        for k in range(4):
            out *= _simplex_factor(family, n, barycentric[k])[:, lattice[:, k]]
        return out * (math.factorial(n) if family == "bezier" else 1.0)
    p, q = degrees[0], degrees[2]
    lattice = np.array(wedge_order(p, q))
    r, s, t = params.T
    barycentric = (1.0 - r - s, r, s)
    triangle_lattice = (p - lattice[:, 0] - lattice[:, 1], lattice[:, 0], lattice[:, 1])
    out = np.ones((params.shape[0], lattice.shape[0]))
    for k in range(3):
        out *= _simplex_factor(family, p, barycentric[k])[:, triangle_lattice[k]]
    if family == "bezier":
        out *= math.factorial(p)
    return out * one_d(q, t)[:, lattice[:, 2]]


def modes_for(shape, degrees):
    """Modes per direction of the expansion holding a cell of these degrees."""
    if shape == HEX:
        return tuple(d + 1 for d in degrees)
    if shape == TET:
        return (degrees[0] + 1,) * 3
    return (degrees[0] + 1, degrees[2] + 1, degrees[0] + 1)  # our prism triangle is (xi1, xi3)


@lru_cache(maxsize=64)
def conversion_matrix(shape, family, degrees, vtk8=False, mirror=False):
    """(K, N): modal coefficients = matrix @ nodal values (VTK point order); read-only."""
    modes = modes_for(shape, degrees)
    xi = np.asarray(ex.fit_points(shape, modes), dtype=np.float64)
    E = cell_basis(shape, family, degrees, xi_to_vtk(shape, xi, mirror), vtk8)
    T = np.asarray(ex.fit_modal(shape, modes, E), dtype=np.float64)
    T.setflags(write=False)
    return T
