"""Affine pyramids for the independent reference (reference.py), which VTK cannot hold: Nektar++'s
pyramid expansion is rational in xi (its collapsed coordinates divide by 1 - xi2), and no VTK
Lagrange cell spans that space, so vtk_volume.py refuses pyramids.

A pyramid whose map is affine (x = A xi + b, its base a parallelogram: the shared datasets'
Pyr_channel_m6) is decided here without any of the renderer's location or traversal:
- where the ray is inside: xi = A^-1 (x - b), exact in float64, and the reference pyramid's five
  half-spaces (xi >= -1, xi0 + xi2 <= 0, xi1 + xi2 <= 0) to INSIDE_TOL;
- the field: the element's own expansion (engine/expansions.py, numpy float64: the mesh's
  definition, the same evaluation vtk_volume.py uses at VTK's nodes) at that xi, point by point;
- the integral: the reference's own breakpoint cuts and adaptive Gauss-Kronrod quadrature, which
  only ever ask `at(k, x)`.
So a pyramid pixel shares with the renderer the basis' definition alone, not its float32 or Warp
code, its Newton, its segments or its quadrature. A curved pyramid has no exact inverse here:
rays that meet one stay unchecked (`curved_lo`, `curved_hi`).
"""
from __future__ import annotations

import numpy as np

from ..engine import expansions as ex
from ..engine import shapes

AFFINE_TOL = 1e-12  # of the element's size: its vertices and geometry off the affine map by more: curved
INSIDE_TOL = 1e-12  # in reference coordinates


class AffinePyramids:
    """The pyramids `elements` of `mesh`: the affine ones for `at` (lo, hi: their boxes), the
    others (`curved`) as padded boxes only (curved_lo, curved_hi): a ray that meets one is not
    decided. Holds arrays only (it travels to worker processes)."""

    def __init__(self, mesh, elements):
        elements = np.asarray(elements, dtype=np.int64)
        V0 = shapes.VERTICES[shapes.PYR]
        self.affine, self.A, self.Ainv, self.b, self.modes, self.coeffs = [], [], [], [], [], []
        lo, hi = [], []
        for e in elements:
            X = np.asarray(mesh.vertices[e, :5], dtype=np.float64)
            # xi axes from vertex 0 = (-1, -1, -1): vertices 1, 3 and 4 are one step of 2 along each
            A = np.stack([X[1] - X[0], X[3] - X[0], X[4] - X[0]], axis=1) / 2.0
            b = X[0] + A @ np.ones(3)
            size = float(np.ptp(X, axis=0).max()) or 1.0
            ok = np.abs(V0 @ A.T + b - X).max() <= AFFINE_TOL * size
            if ok and mesh.geom_coeffs is not None:
                xi = ex.fit_points(shapes.PYR, (4, 4, 4))
                gm = mesh.geom_modes[e]
                G = mesh.geom_coeffs[mesh.geom_offset[e]:mesh.geom_offset[e] + ex.num_coeffs(shapes.PYR, gm)]
                ok = np.abs(ex.eval_modal(shapes.PYR, gm, G, xi) - (xi @ A.T + b)).max() <= AFFINE_TOL * size
            if ok:
                self.affine.append(int(e))
                self.A.append(A)
                self.Ainv.append(np.linalg.inv(A))
                self.b.append(b)
                self.modes.append(tuple(int(m) for m in mesh.modes[e]))
                self.coeffs.append(np.asarray(mesh.element_coeffs(e), dtype=np.float64))
                lo.append(X.min(axis=0)), hi.append(X.max(axis=0))
        self.curved = np.setdiff1d(elements, np.asarray(self.affine, dtype=np.int64))
        self.lo, self.hi = np.array(lo).reshape(-1, 3), np.array(hi).reshape(-1, 3)
        V = np.asarray(mesh.vertices[self.curved, :5], dtype=np.float64).reshape(-1, 5, 3)
        size = np.ptp(V, axis=1).max(axis=1, keepdims=True) if len(V) else np.zeros((0, 1))
        # a curved pyramid may bulge past its vertices: a tenth of its size, as the reference pads VTK's cells
        self.curved_lo = V.min(axis=1) - 0.1 * size if len(V) else np.zeros((0, 3))
        self.curved_hi = V.max(axis=1) + 0.1 * size if len(V) else np.zeros((0, 3))

    def __len__(self):
        return len(self.affine)

    def at(self, k: int, x) -> tuple[bool, float]:
        """(inside affine pyramid k, its field there)."""
        xi = self.Ainv[k] @ (np.asarray(x, dtype=np.float64) - self.b[k])
        e = INSIDE_TOL
        inside = bool(np.all(xi >= -1 - e) and xi[0] + xi[2] <= e and xi[1] + xi[2] <= e)
        value = float(ex.eval_modal(shapes.PYR, self.modes[k], self.coeffs[k], xi[None])[0])
        return inside, value
