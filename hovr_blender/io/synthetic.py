"""Generated affine meshes for tests and benchmarks: any field sampled onto a brick of hexes."""
from __future__ import annotations

import numpy as np

from ..engine.basis import fit_tensor_coefficients
from ..engine.mesh import VolumeMesh
from .builtin import box_vertices


def brick(lower, upper, cells, modes, func, field_name="f") -> VolumeMesh:
    """cells = (nx, ny, nz) axis-aligned hexes over [lower, upper]; func(x, y, z) interpolated
    with `modes` per direction (exact for polynomials of degree < modes)."""
    lower, upper = np.asarray(lower, float), np.asarray(upper, float)
    nx, ny, nz = cells
    edges = [np.linspace(lower[k], upper[k], n + 1) for k, n in enumerate((nx, ny, nz))]
    verts, coeffs = [], []
    for k in range(nz):
        for j in range(ny):
            for i in range(nx):
                lo = np.array([edges[0][i], edges[1][j], edges[2][k]])
                hi = np.array([edges[0][i + 1], edges[1][j + 1], edges[2][k + 1]])
                mid, half = 0.5 * (lo + hi), 0.5 * (hi - lo)
                verts.append(box_vertices(lo, hi))
                coeffs.append(fit_tensor_coefficients(
                    lambda a, b, c, mid=mid, half=half: func(mid[0] + half[0] * a, mid[1] + half[1] * b, mid[2] + half[2] * c),
                    (modes,) * 3))
    return VolumeMesh.from_affine_hexes(np.array(verts), (modes,) * 3, coeffs, field_name=field_name,
                                        source=f"synthetic:brick{nx}x{ny}x{nz}")
