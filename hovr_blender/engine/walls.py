"""The domain's walls: the mesh's boundary faces as triangles, curved faces tessellated until the
triangles depart from the true (curved) surface by less than a tolerance. For showing the domain's
boundary as an ordinary mesh (the Blender importers' "Walls as Mesh" option).

Faces are numbered as shapes.FACE_PLANES numbers them (adjacency.face_neighbours' order). Each
face is parameterised onto the element's reference face, affinely (every reference face is a flat
parallelogram or triangle in xi, the prism's and pyramid's slanted faces and the pyramid's apex
included):
- a quadrilateral face by (u, v) in [-1, 1]^2, bilinear in its corners c0..c3 (the cycle of
  shapes.FACES): xi = c0 (1-u)(1-v)/4 + c1 (1+u)(1-v)/4 + c2 (1+u)(1+v)/4 + c3 (1-u)(1+v)/4;
- a triangular face by (u, v) on Nektar++'s reference triangle u, v >= -1, u + v <= 0:
  xi = c0 + (1+u)/2 (c1 - c0) + (1+v)/2 (c2 - c0), its corners c0..c2 in shapes.FACES' cycle;
and the world point is the element's geometry map x(xi) (expansions.basis_matrix with the
element's geom_coeffs, as mesh.py evaluates geometry).

tessellate(mesh, tolerance) puts a uniform k x k grid on every face (a quad: 2 k^2 triangles; a
triangle: k^2), starting at k = 1 and doubling k, face by face, until the deviation |x(u, v) -
linear interpolation of the triangle| at every sub-triangle's centroid and edge midpoints is at
most SAFETY * tolerance; k stops at max_k (64), and the result counts the faces that hit it
without meeting the tolerance. SAFETY = 3/4: where the deviation inside a small triangle is
quadratic (it vanishes at the corners), its maximum is at most 4/3 of the largest of its values at
the edge midpoints, so the checked points certify the tolerance over the whole triangle up to the
higher-order terms, which shrink faster under refinement.

Triangles wind counter-clockwise seen from outside the domain (outward normals) for elements of
positive orientation (the sign of the straight-sided twin's Jacobian decides). Vertices shared
by neighbouring faces are not welded: every face has its own grid (adjacent faces may differ in
k), so the mesh has seams of coincident vertices, and cracks of up to the tolerance where the two
grids differ (Blender's Merge by Distance closes the coincident ones).

Boundary faces: faces with no neighbour in face_neighbours, less the unmatched faces that
other unmatched faces cover from the other side (a quadrilateral met by two triangles, as
between a hexahedron and tetrahedra; outline.py's rule), which lie inside the domain. Instead of
all of them, tessellate takes a selection of faces (the walls of chosen Nektar++ composites or
boundary regions: io/nektar/composites.py gives them as (element, face)).
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from . import expansions as ex
from .adjacency import face_neighbours
from .mesh import with_geometry_expansion
from .outline import faces_covered_from_both_sides
from .shapes import FACE_PLANES, FACES, MAX_FACES, NAMES, VERTICES, plane_vertices

SAFETY = 0.75  # checked deviation <= SAFETY * tolerance (module docstring)
MAX_K = 64
_CHUNK = 1 << 20  # evaluated points per batch of faces
DEFAULT_RELATIVE_TOLERANCE = 1e-3  # of the bounding box's diagonal


@dataclass
class Walls:
    """tessellate's result: the triangles and, per boundary face, where they came from."""

    vertices: np.ndarray  # (n, 3) float64, world (the mesh's) coordinates
    triangles: np.ndarray  # (m, 3) int64, counter-clockwise seen from outside
    element: np.ndarray  # (F,) element of each boundary face
    face: np.ndarray  # (F,) its face, in shapes.FACE_PLANES' numbering
    k: np.ndarray  # (F,) grid subdivisions per side
    vertex_offset: np.ndarray  # (F,) first vertex of each face's grid
    triangle_offset: np.ndarray  # (F,) first triangle of each face
    deviation: np.ndarray  # (F,) largest deviation at the checked points
    tolerance: float
    capped: int  # faces that reached max_k with a deviation still above SAFETY * tolerance
    max_k: int = MAX_K

    @property
    def cap_hit(self) -> bool:
        return self.capped > 0

    def __iter__(self):  # vertices, triangles = tessellate(...)
        return iter((self.vertices, self.triangles))


def face_corners(shape: int, face: int) -> np.ndarray:
    """(3 or 4, 3): the reference corners of face `face` (FACE_PLANES' numbering) in the cyclic
    order of shapes.FACES."""
    want = set(int(i) for i in plane_vertices(shape)[face])
    for cycle in FACES[shape]:
        if set(cycle) == want:
            return VERTICES[shape][list(cycle)]
    raise ValueError(f"shape {shape} face {face}: no cycle in shapes.FACES")


def face_reference_points(corners: np.ndarray, uv) -> np.ndarray:
    """xi (..., 3) of the face parameters uv (..., 2) (the module docstring's parameterisations)."""
    uv = np.asarray(uv, dtype=np.float64)
    u, v = uv[..., 0:1], uv[..., 1:2]
    c = np.asarray(corners, dtype=np.float64)
    if len(c) == 4:
        return 0.25 * (c[0] * (1 - u) * (1 - v) + c[1] * (1 + u) * (1 - v) + c[2] * (1 + u) * (1 + v) + c[3] * (1 - u) * (1 + v))
    return c[0] + 0.5 * (1 + u) * (c[1] - c[0]) + 0.5 * (1 + v) * (c[2] - c[0])


def reference_orientation(shape: int, face: int) -> float:
    """+1 when the parameters' (u, v) counter-clockwise turn is outward in reference space, else -1."""
    c = face_corners(shape, face)
    tu, tv = c[1] - c[0], c[-1] - c[0]
    n = np.asarray(FACE_PLANES[shape][face][0], dtype=np.float64)
    return 1.0 if np.dot(np.cross(tu, tv), n) > 0 else -1.0


def grid(nsides: int, k: int):
    """The face grid of k subdivisions: (uv (p, 2), triangles (t, 3)) counter-clockwise in (u, v)."""
    t = np.linspace(-1.0, 1.0, k + 1)
    if nsides == 4:
        U, V = np.meshgrid(t, t, indexing="xy")  # vertex i + (k + 1) j at (t[i], t[j])
        uv = np.stack([U.ravel(), V.ravel()], axis=1)
        i, j = np.meshgrid(np.arange(k), np.arange(k), indexing="xy")
        a = (i + (k + 1) * j).ravel()
        b, c, d = a + 1, a + k + 2, a + k + 1
        tris = np.concatenate([np.stack([a, b, c], 1), np.stack([a, c, d], 1)])
        return uv, tris
    ij = [(i, j) for j in range(k + 1) for i in range(k + 1 - j)]
    index = {p: n for n, p in enumerate(ij)}
    uv = t[np.array(ij)]
    tris = [(index[i, j], index[i + 1, j], index[i, j + 1]) for (i, j) in ij if i + j <= k - 1]
    tris += [(index[i + 1, j], index[i + 1, j + 1], index[i, j + 1]) for (i, j) in ij if i + j <= k - 2]
    return uv, np.array(tris, dtype=np.int64).reshape(-1, 3)


# the checked points of a triangle, as barycentric weights of its corners: centroid, edge midpoints
_CHECK = np.array([[1 / 3, 1 / 3, 1 / 3], [0.5, 0.5, 0.0], [0.0, 0.5, 0.5], [0.5, 0.0, 0.5]])


def boundary_faces(mesh):
    """(element (F,), face (F,)): the faces on the domain's boundary (module docstring), faces in
    FACE_PLANES' numbering, sorted by element then face."""
    nb = face_neighbours(mesh).reshape(-1, MAX_FACES)
    nfaces = np.array([len(FACE_PLANES[int(s)]) for s in range(4)])[mesh.shape]
    open_ = (nb < 0) & (np.arange(MAX_FACES)[None, :] < nfaces[:, None])
    elem, face = np.nonzero(open_)
    if elem.size == 0:
        return elem.astype(np.int64), face.astype(np.int64)
    # unmatched faces covered from the other side by other unmatched faces lie inside
    verts = np.asarray(mesh.vertices, dtype=np.float64)
    pts = verts.reshape(-1, 3)
    size = float(np.ptp(pts, axis=0).max()) or 1.0
    q = np.round((pts - pts.min(axis=0)) / (1e-9 * size)).astype(np.int64)
    _, inverse = np.unique(q, axis=0, return_inverse=True)
    vid = inverse.reshape(verts.shape[:2])
    ids = np.full((elem.size, 4), -1, np.int64)
    for sh in np.unique(mesh.shape[elem]):
        for f, idx in enumerate(plane_vertices(int(sh))):
            sel = np.nonzero((mesh.shape[elem] == sh) & (face == f))[0]
            ids[sel, : len(idx)] = vid[elem[sel]][:, idx]
    quad = ids[:, 3] >= 0
    inner_q, inner_t = faces_covered_from_both_sides(ids[quad], ids[~quad, :3], int(vid.max()) + 1)
    inner = np.zeros(elem.size, bool)
    inner[np.nonzero(quad)[0][inner_q]] = True
    inner[np.nonzero(~quad)[0][inner_t]] = True
    return elem[~inner].astype(np.int64), face[~inner].astype(np.int64)


def default_tolerance(mesh, relative: float = DEFAULT_RELATIVE_TOLERANCE) -> float:
    """`relative` of the diagonal of the mesh's (corner vertices') bounding box."""
    pts = np.asarray(mesh.vertices, dtype=np.float64).reshape(-1, 3)
    return float(relative * np.linalg.norm(pts.max(axis=0) - pts.min(axis=0)))


def _orientation(mesh, elems) -> np.ndarray:
    """(m,) +1/-1: the sign of the Jacobian of each element's straight-sided twin."""
    out = np.ones(len(elems))
    for sh in np.unique(mesh.shape[elems]):
        V = VERTICES[int(sh)]
        axes = [int(np.nonzero((V == -1 + 2 * np.eye(3)[d]).all(axis=1))[0][0]) for d in range(3)]
        sel = np.nonzero(mesh.shape[elems] == sh)[0]
        X = mesh.vertices[elems[sel]]
        J = X[:, axes] - X[:, :1]
        out[sel] = np.where(np.linalg.det(J) < 0, -1.0, 1.0)
    return out


def checked_faces(mesh, faces):
    """(element, face) int64 arrays of a face selection, each element an index of `mesh` and each
    face one of its shape's faces (FACE_PLANES' numbering); ValueError naming the first bad pair."""
    try:
        elem, face = (np.asarray(a) for a in faces)
    except (TypeError, ValueError):
        raise ValueError("faces must be a pair of arrays (element, face)") from None
    if elem.ndim != 1 or face.shape != elem.shape or not all(np.issubdtype(a.dtype, np.integer) for a in (elem, face)):
        raise ValueError(f"faces must be two 1-D integer arrays of one length, got shapes {elem.shape} and {face.shape}")
    elem, face = elem.astype(np.int64), face.astype(np.int64)
    bad = np.flatnonzero((elem < 0) | (elem >= mesh.num_elements))
    if bad.size:
        raise ValueError(f"faces: element {elem[bad[0]]} is not in the mesh ({mesh.num_elements} elements)")
    nfaces = np.array([len(FACE_PLANES[s]) for s in range(4)])[mesh.shape[elem]]
    bad = np.flatnonzero((face < 0) | (face >= nfaces))
    if bad.size:
        e = int(elem[bad[0]])
        raise ValueError(f"faces: element {e} ({NAMES[int(mesh.shape[e])]}) has no face {face[bad[0]]}")
    return elem, face


def tessellate(mesh, tolerance: float | None = None, max_k: int = MAX_K, faces=None) -> Walls:
    """The boundary faces as triangles within `tolerance` of the true surface (module docstring);
    tolerance None: default_tolerance(mesh). faces: a selection (element, face) of any faces
    (checked_faces; a Nektar++ composite's: io/nektar/composites.py) instead of boundary_faces;
    each is tessellated and wound as its element's outward face, interior ones too."""
    if mesh.geom_coeffs is None:
        mesh = with_geometry_expansion(mesh)
    if tolerance is None:
        tolerance = default_tolerance(mesh)
    tolerance = float(tolerance)
    if not np.isfinite(tolerance) or tolerance <= 0:
        raise ValueError(f"tolerance must be positive, got {tolerance}")
    max_k = max(1, int(max_k))
    elem, face = boundary_faces(mesh) if faces is None else checked_faces(mesh, faces)
    F = elem.size
    k_of = np.ones(F, np.int64)
    dev_of = np.zeros(F)
    pts_of: list = [None] * F
    tris_of: list = [None] * F
    sign = _orientation(mesh, elem) if F else np.zeros(0)
    gm = mesh.geom_modes[elem]
    keys = np.concatenate([mesh.shape[elem, None], gm, face[:, None]], axis=1) if F else np.zeros((0, 5), np.int64)
    for key in np.unique(keys, axis=0):
        sh, gmodes, f = int(key[0]), tuple(int(v) for v in key[1:4]), int(key[4])
        idx = np.nonzero((keys == key).all(axis=1))[0]
        K = ex.num_coeffs(sh, gmodes)
        G = mesh.geom_coeffs[mesh.geom_offset[elem[idx]][:, None] + np.arange(K)[None, :]]  # (m, K, 3)
        corners = face_corners(sh, f)
        ref_sign = reference_orientation(sh, f)
        todo = np.arange(idx.size)
        k = 1
        while todo.size:
            uv, tris = grid(len(corners), k)
            xi = face_reference_points(corners, uv)
            xq = face_reference_points(corners, np.einsum("cw,twd->tcd", _CHECK, uv[tris]).reshape(-1, 2))
            B, Bq = ex.basis_matrix(sh, gmodes, xi), ex.basis_matrix(sh, gmodes, xq)
            left = []
            step = max(1, _CHUNK // (len(xi) + len(xq)))  # faces at a time: bounded memory
            for c0 in range(0, todo.size, step):
                part = todo[c0: c0 + step]
                X = np.einsum("pk,mkc->mpc", B, G[part])  # (m, p, 3)
                Xq = np.einsum("pk,mkc->mpc", Bq, G[part]).reshape(len(part), len(tris), 4, 3)
                lin = np.einsum("cw,mtwd->mtcd", _CHECK, X[:, tris])
                dev = np.linalg.norm(Xq - lin, axis=-1).max(axis=(1, 2))
                done = (dev <= SAFETY * tolerance) | (k >= max_k)
                for j in np.nonzero(done)[0]:
                    g = idx[part[j]]
                    k_of[g], dev_of[g], pts_of[g] = k, dev[j], X[j]
                    flip = ref_sign * sign[g] < 0
                    tris_of[g] = tris[:, ::-1] if flip else tris
                left.append(part[~done])
            todo = np.concatenate(left)
            k = min(2 * k, max_k)
    nv = np.array([len(p) for p in pts_of], np.int64)
    nt = np.array([len(t) for t in tris_of], np.int64)
    voff = np.concatenate([[0], np.cumsum(nv)[:-1]]).astype(np.int64) if F else np.zeros(0, np.int64)
    toff = np.concatenate([[0], np.cumsum(nt)[:-1]]).astype(np.int64) if F else np.zeros(0, np.int64)
    vertices = np.concatenate(pts_of) if F else np.zeros((0, 3))
    triangles = np.concatenate([t + o for t, o in zip(tris_of, voff)]) if F else np.zeros((0, 3), np.int64)
    capped = int(np.count_nonzero((k_of >= max_k) & (dev_of > SAFETY * tolerance)))
    return Walls(vertices, triangles.astype(np.int64), elem, face, k_of, voff, toff, dev_of, tolerance, capped, max_k)
