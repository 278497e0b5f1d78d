"""VTK's 3-D cells: the types read, their degrees, and their node orders as integer lattice
indices (parameters = index / degree).

Node orders are derived from VTK's documented rules (corners, edges, faces, interior; recursive
"onion" order for tetrahedra; the wedge's triangle faces are row-by-row) and checked against
vtk's own cells in tests/io/test_vtu.py. Hexahedra in files older than version 2.1 use the
VTK 8 order (last two vertical edges swapped), as vtkXMLUnstructuredDataReader converts them
(it renumbers only when the file version is < 2.1; 2.1 and 2.2 are both the VTK 9 order).
"""
from __future__ import annotations

import numpy as np

from ...engine.shapes import HEX, PRISM, TET

# VTK type -> (name, our shape, basis family)
CELL_TYPES = {
    10: ("VTK_TETRA", TET, "linear"),
    12: ("VTK_HEXAHEDRON", HEX, "linear"),
    13: ("VTK_WEDGE", PRISM, "linear"),
    71: ("VTK_LAGRANGE_TETRAHEDRON", TET, "lagrange"),
    72: ("VTK_LAGRANGE_HEXAHEDRON", HEX, "lagrange"),
    73: ("VTK_LAGRANGE_WEDGE", PRISM, "lagrange"),
    78: ("VTK_BEZIER_TETRAHEDRON", TET, "bezier"),
    79: ("VTK_BEZIER_HEXAHEDRON", HEX, "bezier"),
    80: ("VTK_BEZIER_WEDGE", PRISM, "bezier"),
}
# refused: VTK's higher-order pyramid space is not Nektar++'s
PYRAMIDS = {14: "VTK_PYRAMID", 74: "VTK_LAGRANGE_PYRAMID", 81: "VTK_BEZIER_PYRAMID"}

_TET_EDGES = ((0, 1), (1, 2), (2, 0), (0, 3), (1, 3), (2, 3))
# each face's interior is a triangle whose corners lie next to these vertices, in this order
_TET_FACES = ((0, 1, 3), (2, 3, 1), (0, 3, 2), (0, 2, 1))


def _tri_onion(n):
    """Barycentric indices (b0, b1, b2), sum n, in VTK's recursive triangle order."""
    if n < 0:
        return []
    if n == 0:
        return [(0, 0, 0)]
    points = [(n, 0, 0), (0, n, 0), (0, 0, n)]
    points += [(n - i, i, 0) for i in range(1, n)]
    points += [(0, n - i, i) for i in range(1, n)]
    points += [(i, 0, n - i) for i in range(1, n)]
    return points + [(a + 1, b + 1, c + 1) for a, b, c in _tri_onion(n - 3)]


def tet_order(n):
    """(N, 4) barycentric lattice indices (weights of VTK vertices 0..3), in VTK point order."""
    if n < 0:
        return []
    if n == 0:
        return [(0, 0, 0, 0)]
    points = [tuple(n if k == vertex else 0 for k in range(4)) for vertex in range(4)]
    for u, v in _TET_EDGES:
        for i in range(1, n):
            weights = [0] * 4
            weights[u], weights[v] = n - i, i
            points.append(tuple(weights))
    for face in _TET_FACES:
        for on_face in _tri_onion(n - 3):
            weights = [0] * 4
            for vertex, weight in zip(face, on_face):
                weights[vertex] = weight + 1
            points.append(tuple(weights))
    return points + [tuple(x + 1 for x in weights) for weights in tet_order(n - 4)]


def hex_order(p, q, r, vtk8=False):
    """(N, 3) lattice indices (i, j, k) in VTK point order; vtk8: pre-2.1 files' edge order."""
    points = [(0, 0, 0), (p, 0, 0), (p, q, 0), (0, q, 0), (0, 0, r), (p, 0, r), (p, q, r), (0, q, r)]
    for k in (0, r):
        points += [(i, 0, k) for i in range(1, p)] + [(p, j, k) for j in range(1, q)]
        points += [(i, q, k) for i in range(1, p)] + [(0, j, k) for j in range(1, q)]
    verticals = ((0, 0), (p, 0), (0, q), (p, q)) if vtk8 else ((0, 0), (p, 0), (p, q), (0, q))
    for i, j in verticals:
        points += [(i, j, k) for k in range(1, r)]
    for i in (0, p):
        points += [(i, j, k) for k in range(1, r) for j in range(1, q)]
    for j in (0, q):
        points += [(i, j, k) for k in range(1, r) for i in range(1, p)]
    for k in (0, r):
        points += [(i, j, k) for j in range(1, q) for i in range(1, p)]
    return points + [(i, j, k) for k in range(1, r) for j in range(1, q) for i in range(1, p)]


def wedge_order(p, q):
    """(N, 3) lattice indices (i, j, k): triangle (i, j) of degree p, line k of degree q."""
    corners = [(0, 0), (p, 0), (0, p)]
    sides = ([(i, 0) for i in range(1, p)], [(p - j, j) for j in range(1, p)], [(0, p - j) for j in range(1, p)])
    edges = sides[0] + sides[1] + sides[2]
    # the wedge's triangle-face and body points run row by row, not in the triangle's onion order
    inner = [(i, j) for j in range(1, p - 1) for i in range(1, p - j)]
    points = [(i, j, 0) for i, j in corners] + [(i, j, q) for i, j in corners]
    points += [(i, j, 0) for i, j in edges] + [(i, j, q) for i, j in edges]
    for i, j in corners:
        points += [(i, j, k) for k in range(1, q)]
    points += [(i, j, 0) for i, j in inner] + [(i, j, q) for i, j in inner]
    for side in sides:
        points += [(i, j, k) for k in range(1, q) for i, j in side]
    return points + [(i, j, k) for k in range(1, q) for i, j in inner]


def vtk_node_params(shape, degrees, vtk8=False):
    """(N, 3) VTK parametric coordinates ([0, 1]-based) of a cell's nodes, in VTK point order."""
    if shape == HEX:
        return np.array(hex_order(*degrees, vtk8=vtk8), dtype=np.float64) / np.asarray(degrees, dtype=np.float64)
    if shape == TET:
        return np.array(tet_order(degrees[0]), dtype=np.float64)[:, 1:] / degrees[0]
    p, q = degrees[0], degrees[2]
    return np.array(wedge_order(p, q), dtype=np.float64) / np.array([p, p, q], dtype=np.float64)


def infer_degrees(shape, num_nodes):
    """(p, p, p) of the complete cell with num_nodes nodes, or None if there is none."""
    if shape == HEX:
        p = round(num_nodes ** (1.0 / 3.0)) - 1
        return (p, p, p) if p >= 1 and (p + 1) ** 3 == num_nodes else None
    for p in range(1, 64):
        count = (p + 1) * (p + 2) * (p + 3) // 6 if shape == TET else (p + 1) ** 2 * (p + 2) // 2
        if count == num_nodes:
            return (p, p, p)
        if count > num_nodes:
            return None
    return None


def node_count(shape, degrees):
    p, q, r = degrees
    if shape == HEX:
        return (p + 1) * (q + 1) * (r + 1)
    if shape == TET:
        return (p + 1) * (p + 2) * (p + 3) // 6
    return (p + 1) * (p + 2) // 2 * (r + 1)
