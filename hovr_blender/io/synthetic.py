"""Generated affine meshes for tests and benchmarks: any field sampled onto a brick of hexes."""
from __future__ import annotations

from itertools import permutations

import numpy as np

from ..core import expansions as ex
from ..core import shapes
from ..core.expansions import fit_tensor_coefficients
from ..core.mesh import VolumeMesh
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


def straight_geometry(shape: int, vertices) -> np.ndarray:
    """2-mode geometry coefficients (K, 3) of the straight element through `vertices`
    (the shape's vertex order, docs/spec/formats.md §2.8): with two modes every mode is a vertex mode."""

    vertices = np.asarray(vertices, dtype=np.float64)
    k = ex.num_coeffs(shape, (2, 2, 2))
    ref = shapes.VERTICES[shape]
    # B[i, j] = mode j at vertex i; vertex modes make it a permutation matrix
    B = np.stack([ex.eval_modal(shape, (2, 2, 2), np.eye(k)[j], ref) for j in range(k)], axis=1)
    return np.linalg.solve(B, vertices)


def _oriented_tet(v):
    v = np.asarray(v, float)
    if np.linalg.det(np.stack([v[1] - v[0], v[2] - v[0], v[3] - v[0]])) < 0:
        v = v[[0, 2, 1, 3]]
    return v


def mixed_cube(n: int, modes: int, func, field_name="f", lower=(0.0, 0.0, 0.0), size=1.0) -> VolumeMesh:
    """A cube of n^3 cells, each cell cut into one shape in turn: a hexahedron, two prisms,
    six tetrahedra (Kuhn) or six pyramids (apex at the cell centre). Straight elements of all
    four shapes sharing faces across shapes; the field `func` is fitted with `modes`."""

    lower = np.asarray(lower, float)
    h = size / n
    kinds, geoms, coeffs = [], [], []

    def add(shape, verts):
        g = straight_geometry(shape, verts)
        pts = ex.eval_modal(shape, (2, 2, 2), g, ex.fit_points(shape, (modes,) * 3))
        kinds.append(shape)
        geoms.append(g)
        coeffs.append(ex.fit_modal(shape, (modes,) * 3, func(pts[:, 0], pts[:, 1], pts[:, 2])))

    cube_ref = shapes.VERTICES[shapes.HEX]
    for k in range(n):
        for j in range(n):
            for i in range(n):
                origin = lower + h * np.array([i, j, k], float)
                corner = lambda a, b, c: origin + h * np.array([a, b, c], float)  # noqa: E731
                kind = (i + j + k) % 4
                if kind == 0:
                    add(shapes.HEX, origin + h * (cube_ref + 1.0) / 2.0)
                elif kind == 1:  # x + z <= 1 and its point reflection through the cell's y axis
                    lo = [corner(0, 0, 0), corner(1, 0, 0), corner(1, 1, 0), corner(0, 1, 0), corner(0, 0, 1), corner(0, 1, 1)]
                    hi = [corner(1, 0, 1), corner(0, 0, 1), corner(0, 1, 1), corner(1, 1, 1), corner(1, 0, 0), corner(1, 1, 0)]
                    add(shapes.PRISM, lo)
                    add(shapes.PRISM, hi)
                elif kind == 2:
                    for perm in permutations(range(3)):
                        p0 = np.zeros(3)
                        p1 = p0.copy(); p1[perm[0]] = 1  # noqa: E702
                        p2 = p1.copy(); p2[perm[1]] = 1  # noqa: E702
                        add(shapes.TET, _oriented_tet([origin + h * p for p in (p0, p1, p2, np.ones(3))]))
                else:
                    centre = origin + 0.5 * h
                    faces = [  # each cell face as a quad (counter-clockwise seen from outside)
                        [(0, 0, 0), (0, 1, 0), (1, 1, 0), (1, 0, 0)], [(0, 0, 1), (1, 0, 1), (1, 1, 1), (0, 1, 1)],
                        [(0, 0, 0), (1, 0, 0), (1, 0, 1), (0, 0, 1)], [(0, 1, 0), (0, 1, 1), (1, 1, 1), (1, 1, 0)],
                        [(0, 0, 0), (0, 0, 1), (0, 1, 1), (0, 1, 0)], [(1, 0, 0), (1, 1, 0), (1, 1, 1), (1, 0, 1)],
                    ]
                    for face in faces:
                        base = [corner(*c) for c in face][::-1]  # base seen from the apex: counter-clockwise
                        add(shapes.PYR, base + [centre])
    n_modes = (modes,) * 3
    return VolumeMesh.from_elements(kinds, n_modes, coeffs, (2, 2, 2), geoms, field_name=field_name,
                                    source=f"synthetic:mixed_cube{n}")


def with_field(mesh: VolumeMesh, func, modes: int, field_name="f") -> VolumeMesh:
    """The same geometry carrying func(x, y, z) fitted with `modes` per direction in every
    element (exact for polynomials the element's space holds); for meshes that come without
    a field, such as scaleHO."""

    n = mesh.num_elements
    coeffs = [None] * n
    keys = np.concatenate([mesh.shape[:, None], mesh.geom_modes], axis=1)
    for key in np.unique(keys, axis=0):
        shape, geometry_modes = int(key[0]), tuple(int(v) for v in key[1:])
        idx = np.nonzero((keys == key).all(axis=1))[0]
        field_modes = (modes,) * 3
        pts = ex.fit_points(shape, field_modes)
        geometry_basis = ex.basis_matrix(shape, geometry_modes, pts)
        num_geometry_coeffs = ex.num_coeffs(shape, geometry_modes)
        G = mesh.geom_coeffs[mesh.geom_offset[idx][:, None] + np.arange(num_geometry_coeffs)[None, :]]  # (k, K, 3)
        X = np.einsum("pk,ekc->epc", geometry_basis, G)
        vals = func(X[..., 0], X[..., 1], X[..., 2])  # (k, P)
        C = ex.fit_modal(shape, field_modes, vals.T)  # (K, k)
        for j, e in enumerate(idx):
            coeffs[e] = C[:, j]
    geometry = []
    for e in range(n):
        start = mesh.geom_offset[e]
        geometry.append(mesh.geom_coeffs[start:start + ex.num_coeffs(int(mesh.shape[e]), mesh.geom_modes[e])])
    return VolumeMesh.from_elements(mesh.shape, (modes,) * 3, coeffs, mesh.geom_modes, geometry, field_name=field_name,
                                    source=mesh.source)
