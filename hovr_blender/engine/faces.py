"""The faces the traversal crosses, as triangles (docs/traversal.md): each chosen element face
tessellated through its element's geometry map within a certified distance bound
(walls.tessellate), with every triangle vertex's reference point on its element's face, so that a
ray's hit on a triangle gives Newton on the curved face its start (the barycentric point), and
every triangle its owner, the element and its local face (e * MAX_FACES + f).

element_faces: every element's faces, each shared face once per side, so that every crossing of
a face names the element on each side (and a non-conforming face, a hexahedron's face against two
tetrahedra, is crossed on both sides). The kernels take the triangles' boxes, grown by the bound,
in a wp.Bvh (a near miss of a triangle can still cross the curved face).
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from .shapes import FACE_PLANES, MAX_FACES
from .walls import SAFETY, default_tolerance, face_corners, face_reference_points, grid, tessellate

DEFAULT_RELATIVE_BOUND = 1e-3  # of the mesh's diagonal: docs/traversal.md (memory against grazing near misses)


@dataclass
class FaceMesh:
    """Triangles of element faces, each vertex with its world and reference point."""

    points: np.ndarray  # (P, 3) float64 world
    xi: np.ndarray  # (P, 3) float64: the same points in their element's reference coordinates (on the face)
    triangles: np.ndarray  # (T, 3) int32
    owner: np.ndarray  # (T,) int32: element * MAX_FACES + local face
    bound: float  # every triangle lies within this (world units) of its curved face

    @property
    def nbytes(self) -> int:
        return int(self.points.nbytes // 2 + self.xi.nbytes // 2 + self.triangles.nbytes + self.owner.nbytes)

    def boxes(self, pad: float):
        """(lowers, uppers) (T, 3) float64: each triangle's box grown by bound + pad."""
        tri = self.points[self.triangles]
        grow = self.bound + pad
        return tri.min(axis=1) - grow, tri.max(axis=1) + grow


def element_faces(mesh):
    """(element, face) int64: every real face of every element (a shared face once per side)."""
    nfaces = np.array([len(FACE_PLANES[s]) for s in range(4)])[mesh.shape]
    elem, face = np.nonzero(np.arange(MAX_FACES)[None, :] < nfaces[:, None])
    return elem.astype(np.int64), face.astype(np.int64)


def face_mesh(mesh, faces, relative: float = DEFAULT_RELATIVE_BOUND) -> FaceMesh:
    """The faces (element, face) tessellated within `relative` of the mesh's diagonal."""
    elem, face = (np.asarray(a, dtype=np.int64) for a in faces)
    bound = default_tolerance(mesh, relative)
    if elem.size == 0:
        return FaceMesh(np.zeros((0, 3)), np.zeros((0, 3)), np.zeros((0, 3), np.int32), np.zeros(0, np.int32), bound)
    walls = tessellate(mesh, bound, faces=(elem, face))
    xi = np.zeros_like(walls.vertices)
    shape = mesh.shape[walls.element]
    keys = np.stack([shape, walls.face, walls.k], axis=1)
    for key in np.unique(keys, axis=0):
        sh, f, k = (int(v) for v in key)
        idx = np.nonzero((keys == key).all(axis=1))[0]
        corners = face_corners(sh, f)
        ref = face_reference_points(corners, grid(len(corners), k)[0])  # (p, 3), the same for every face here
        rows = walls.vertex_offset[idx][:, None] + np.arange(len(ref))[None, :]
        xi[rows] = ref[None, :, :]
    counts = np.diff(np.append(walls.triangle_offset, len(walls.triangles)))
    owner = np.repeat(walls.element * MAX_FACES + walls.face, counts).astype(np.int32)
    # capped faces (max_k reached) are certified only to their own deviation
    bound = max(float(walls.tolerance), float(walls.deviation.max(initial=0.0)) / SAFETY)
    return FaceMesh(walls.vertices, xi, walls.triangles.astype(np.int32), owner, bound)
