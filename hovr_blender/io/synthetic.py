"""Generated meshes for tests and benchmarks: any field sampled onto a brick of hexes, a cube of all
four shapes (straight or bent)."""
from __future__ import annotations

from itertools import permutations

import numpy as np

from ..engine import expansions as ex
from ..engine import shapes
from ..engine.mesh import MeshError, VolumeMesh
from .paper_scale import curved_copy


def brick(lower, upper, cells, modes, func, field_name="f", chunk=20000) -> VolumeMesh:
    """cells = (nx, ny, nz) axis-aligned hexes over [lower, upper], element i + nx (j + ny k);
    func(x, y, z) interpolated at the tensor GLL points with `modes` per direction (exact for
    polynomials of degree < modes). Vectorised over elements, `chunk` at a time (a million
    elements in seconds); the same mesh, bit for bit, as fitting every element on its own
    (expansions.fit_tensor_coefficients, VolumeMesh.from_affine_hexes)."""
    lower, upper, modes = np.asarray(lower, float), np.asarray(upper, float), int(modes)
    nx, ny, nz = (int(c) for c in cells)
    if not (np.all(np.isfinite(lower)) and np.all(np.isfinite(upper)) and np.all(upper > lower)):
        raise MeshError(f"brick: upper {upper.tolist()} must exceed lower {lower.tolist()} in every direction")
    edges = [np.linspace(lower[d], upper[d], n + 1) for d, n in enumerate((nx, ny, nz))]
    k, j, i = (a.ravel() for a in np.meshgrid(np.arange(nz), np.arange(ny), np.arange(nx), indexing="ij"))
    lo = np.stack([edges[0][i], edges[1][j], edges[2][k]], axis=1)
    hi = np.stack([edges[0][i + 1], edges[1][j + 1], edges[2][k + 1]], axis=1)
    mid, half = 0.5 * (lo + hi), 0.5 * (hi - lo)
    verts = lo[:, None, :] + (shapes.VERTICES[shapes.HEX] + 1.0)[None] * 0.5 * (hi - lo)[:, None, :]  # box_vertices
    n, size = len(lo), modes ** 3
    g = ex.gll_points(modes)
    Vi = np.linalg.inv(ex.modified_a(modes, g))  # nodal -> modal, one direction
    A, B, C = np.meshgrid(g, g, g, indexing="ij")
    coeffs = np.empty((n, size))
    for a in range(0, n, chunk):
        m, h = mid[a:a + chunk, :, None, None, None], half[a:a + chunk, :, None, None, None]
        vals = np.broadcast_to(np.asarray(func(m[:, 0] + h[:, 0] * A, m[:, 1] + h[:, 1] * B, m[:, 2] + h[:, 2] * C),
                                          dtype=np.float64), (len(m),) + A.shape)
        c = np.einsum("ai,eijk->eajk", Vi, vals)  # one direction at a time, as fit_tensor_coefficients
        c = np.einsum("bj,eajk->eabk", Vi, c)
        c = np.einsum("ck,eabk->eabc", Vi, c)
        coeffs[a:a + chunk] = c.transpose(0, 3, 2, 1).reshape(len(m), size)  # direction 0 fastest
    x0 = verts.mean(axis=1)  # the world->reference map of mesh.affine_from_hex_vertices: diagonal here
    inv = 1.0 / (0.5 * (verts[:, [1, 3, 4], [0, 1, 2]] - verts[:, 0, :]))
    M = np.zeros((n, 3, 4))
    M[:, [0, 1, 2], [0, 1, 2]] = inv
    M[:, :, 3] = -(inv * x0)
    return VolumeMesh(shape=np.full(n, shapes.HEX, np.int32), vertices=verts, ref_from_world=M,
                      modes=np.full((n, 3), modes, np.int32), basis=np.full(n, ex.MODIFIED_A, np.int32),
                      coeff_offset=np.arange(n, dtype=np.int64) * size, coeffs=coeffs.ravel(), field_name=field_name,
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


def cube_field(x, y, z):
    """curved_cube's field: smooth, not a polynomial (so every order approximates it)."""
    return np.sin(2.5 * x + 0.5) * np.cos(2.0 * y) + z * z


def curved_cube(cells: int, modes: int = 5, func=cube_field) -> VolumeMesh:
    """mixed_cube(cells, modes, func) over the unit cube bent by a quadratic displacement (3
    geometry modes, paper_scale.curved_copy): curved elements of all four shapes, pyramid apexes
    and many elements meeting at a vertex. The benchmark's curved mixed-shape dataset
    (bench/suite.py) and the scene of the float32-against-float64 regression tests."""

    def bend(x, y, z):
        return 0.08 * (1 - (2 * x - 1) ** 2), 0.05 * x * y, -0.06 * (y - 0.5) ** 2 + 0.02 * x

    return curved_copy(mixed_cube(cells, modes, func), bend, geom_modes=3)


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
