"""The four element shapes: ids, names, reference vertices, faces, edges and face planes, and the
limit on modes per direction. One home for these facts; everything else imports them (the Warp
kernels' face_plane is the device's own copy of FACE_PLANES, checked against it in the tests).

Reference elements (spec: docs/spec/formats.md, Nektar++'s conventions): xi in [-1, 1]^3,
hexahedron the cube; prism collapsed in xi0 + xi2 <= 0; tetrahedron xi0 + xi1 + xi2 <= -1;
pyramid collapsed towards the apex (-1, -1, 1).
"""
from __future__ import annotations

import numpy as np

HEX, PRISM, TET, PYR = 0, 1, 2, 3
NAMES = {HEX: "hexahedron", PRISM: "prism", TET: "tetrahedron", PYR: "pyramid"}

MAX_MODES = 15  # modes per direction (degree 14): the renderer's limit, and the readers'

VERTICES = {
    HEX: np.array([[-1, -1, -1], [1, -1, -1], [1, 1, -1], [-1, 1, -1],
                   [-1, -1, 1], [1, -1, 1], [1, 1, 1], [-1, 1, 1]], dtype=np.float64),
    PRISM: np.array([[-1, -1, -1], [1, -1, -1], [1, 1, -1], [-1, 1, -1], [-1, -1, 1], [-1, 1, 1]], dtype=np.float64),
    TET: np.array([[-1, -1, -1], [1, -1, -1], [-1, 1, -1], [-1, -1, 1]], dtype=np.float64),
    PYR: np.array([[-1, -1, -1], [1, -1, -1], [1, 1, -1], [-1, 1, -1], [-1, -1, 1]], dtype=np.float64),
}
for _v in VERTICES.values():
    _v.setflags(write=False)

# volume centroids of the reference shapes (pyramid: a quarter of the height above the base)
CENTROIDS = {HEX: np.zeros(3), PRISM: np.array([-1 / 3, 0.0, -1 / 3]), TET: np.full(3, -0.5),
             PYR: np.array([-0.25, -0.25, -0.5])}

# Faces in Nektar++'s local numbering, each a cycle of local vertices.
FACES = {
    HEX: ((0, 1, 2, 3), (0, 1, 5, 4), (1, 2, 6, 5), (3, 2, 6, 7), (0, 3, 7, 4), (4, 5, 6, 7)),
    PRISM: ((0, 1, 2, 3), (0, 1, 4), (1, 2, 5, 4), (3, 2, 5), (0, 3, 5, 4)),
    TET: ((0, 1, 2), (0, 1, 3), (1, 2, 3), (0, 2, 3)),
    PYR: ((0, 1, 2, 3), (0, 1, 4), (1, 2, 4), (3, 2, 4), (0, 3, 4)),
}
# Edges in Nektar++'s local numbering (first vertex, second vertex).
EDGES = {
    HEX: ((0, 1), (1, 2), (2, 3), (3, 0), (0, 4), (1, 5), (2, 6), (3, 7), (4, 5), (5, 6), (6, 7), (7, 4)),
    PRISM: ((0, 1), (1, 2), (3, 2), (0, 3), (0, 4), (1, 4), (2, 5), (3, 5), (4, 5)),
    TET: ((0, 1), (1, 2), (0, 2), (0, 3), (1, 3), (2, 3)),
    PYR: ((0, 1), (1, 2), (3, 2), (0, 3), (0, 4), (1, 4), (2, 4), (3, 4)),
}

# The faces as planes, in the kernels' order (the traversal's exit faces and neighbours):
# (normal, c), inside where normal . xi <= c. Faces 0..2 are xi_k = -1.
MAX_FACES = 6
FACE_PLANES = {
    HEX: [((-1, 0, 0), 1), ((0, -1, 0), 1), ((0, 0, -1), 1), ((1, 0, 0), 1), ((0, 1, 0), 1), ((0, 0, 1), 1)],
    PRISM: [((-1, 0, 0), 1), ((0, -1, 0), 1), ((0, 0, -1), 1), ((0, 1, 0), 1), ((1, 0, 1), 0)],
    TET: [((-1, 0, 0), 1), ((0, -1, 0), 1), ((0, 0, -1), 1), ((1, 1, 1), -1)],
    PYR: [((-1, 0, 0), 1), ((0, -1, 0), 1), ((0, 0, -1), 1), ((1, 0, 1), 0), ((0, 1, 1), 0)],
}


def plane_vertices(shape: int) -> list[np.ndarray]:
    """Per face of FACE_PLANES, the local vertex indices lying on it."""
    V = VERTICES[shape]
    return [np.nonzero(np.abs(V @ np.asarray(n, float) - c) < 1e-12)[0] for n, c in FACE_PLANES[shape]]


# PLANE_OF_FACE[shape][k]: the FACE_PLANES index of the face FACES[shape][k] (Nektar++'s local
# face k), the two numberings' one bridge (the walls of a Nektar++ composite: io/nektar/composites.py).
PLANE_OF_FACE = {s: tuple(next(p for p, on in enumerate(plane_vertices(s)) if set(on.tolist()) == set(face))
                          for face in FACES[s]) for s in FACES}
