"""Spectral/hp expansions of all four 3-D shapes, on the host (numpy, float64).

THE CONTRACT (implemented by this module, used by importers, the reference and the tests;
the Warp kernels implement the same polynomials independently and are tested against it).
Conventions are those of ../shared/spec/formats.md §2.8-2.12 (Nektar++):

Shapes: HEX = 0, PRISM = 1, TET = 2, PYR = 3; reference coordinates xi in [-1, 1]^3 with the
vertex numbering of §2.8 (SHAPE_VERTICES).

A "modal expansion" of shape s with modes (P0, P1, P2) is Nektar++'s MODIFIED family
(hex A,A,A; prism A,A,B; tet A,B,C; pyramid A,A,PyrC), coefficients in Nektar++'s storage
order (§2.10: hex direction 0 fastest; prism/tet/pyramid r fastest), with the collapsed-
vertex corrections of §2.10 applied. The same form holds the field (coeffs shape (K,)) and
the geometry map x(xi) (coeffs shape (K, 3)): one evaluator serves both.

Functions (all vectorised over leading point dimensions; xi (..., 3)):
    num_coeffs(shape, modes) -> int
    mode_triples(shape, modes) -> (K, 3) int      the (p, q, r) of each stored coefficient
    collapse(shape, xi) -> eta (..., 3)           denominators clamped at 1e-12 as Nektar++
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

HEX, PRISM, TET, PYR = 0, 1, 2, 3
SHAPE_NAMES = {HEX: "hexahedron", PRISM: "prism", TET: "tetrahedron", PYR: "pyramid"}

# More in the contract:
#   SHAPE_VERTICES[shape] -> (nv, 3) reference vertex coordinates (§2.8)
#   affine_fit(shape, gmodes, gcoeffs) -> (A (3,3), b (3,), ok): xi = A x + b when the map
#       x(xi) is affine (checked at fit points to 1e-12 relative), else ok = False
