"""MFEM's 3-D element geometries and its H1 and L2 spaces as the engine holds them: reference
frames, node positions, and the exact change of basis from nodal values to modal coefficients.

Facts from MFEM 4.10 (fem/geom.cpp, fem/fe/fe_h1.cpp, fe_l2.cpp, fe_base.cpp, fem/fe_coll.cpp;
docs/spec/formats.md §7), checked against PyMFEM 4.10's own nodes and values in tests/io/test_mfem.py:
- Geometries 4 TETRAHEDRON, 5 CUBE, 6 PRISM, 7 PYRAMID; reference elements in [0, 1]^3: the unit
  cube, the tet x, y, z >= 0, x + y + z <= 1, the prism (triangle x, y >= 0, x + y <= 1) x z, the
  pyramid on the square z = 0 with its apex at (0, 0, 1). Local edges and faces: EDGES, FACES.
- Spaces of order p: H1 and L2 hex Q_p, tet P_p, prism P_p(triangle) x P_p(line): the engine's
  expansions of p + 1 modes. MFEM's pyramids are rational (Bergot, `_Pyr0`, and Fuentes, the
  default): the engine's pyramid of p + 1 modes holds H1 pyramids of order 1 and Bergot pyramids
  of orders up to 2 (L2 Bergot 0..2, L2 Fuentes only order 0); no engine pyramid holds the others.
- Nodal bases: the values are those of the function at nodes built from a 1-D point set (the
  collection's basis type; H1's default Gauss-Lobatto, L2's Gauss-Legendre). An H1 element's
  nodes: its vertices; p - 1 per edge at cp[1..p-1] from the edge's first vertex; per face the
  lattice (i, j) of the face's frame (its vertices in FACES order) at barycentric weights
  (cp[p-i-j], cp[i], cp[j]) / w on a triangle, (cp[i], cp[j]) on a square, j outer; the
  interior nodes in MFEM's order. An L2 element: all its nodes in MFEM's order.

The engine's frames: hex, tet and pyramid xi = 2X - 1 (the same vertex numbering); the prism's
triangle is the engine's (xi0, xi2), so xi = (2y - 1, 2z - 1, 2x - 1), a cyclic and so
orientation-keeping map.
"""
from __future__ import annotations

from functools import lru_cache

import numpy as np
from numpy.polynomial import legendre

from ...engine import expansions as ex
from ...engine.shapes import HEX, MAX_MODES, PRISM, PYR, TET

TRIANGLE, SQUARE = 2, 3
SHAPES = {4: TET, 5: HEX, 6: PRISM, 7: PYR}  # MFEM Geometry::Type -> engine shape
NAMES = {4: "tetrahedron", 5: "hexahedron", 6: "prism", 7: "pyramid", 0: "point", 1: "segment",
         2: "triangle", 3: "square"}
PLURALS = {4: "tetrahedra", 5: "hexahedra", 6: "prisms", 7: "pyramids"}
NUM_VERTICES = {0: 1, 1: 2, 2: 3, 3: 4, 4: 4, 5: 8, 6: 6, 7: 5}
EDGES = {
    4: ((0, 1), (0, 2), (0, 3), (1, 2), (1, 3), (2, 3)),
    5: ((0, 1), (1, 2), (3, 2), (0, 3), (4, 5), (5, 6), (7, 6), (4, 7), (0, 4), (1, 5), (2, 6), (3, 7)),
    6: ((0, 1), (1, 2), (2, 0), (3, 4), (4, 5), (5, 3), (0, 3), (1, 4), (2, 5)),
    7: ((0, 1), (1, 2), (3, 2), (0, 3), (0, 4), (1, 4), (2, 4), (3, 4)),
}
FACES = {
    4: ((1, 2, 3), (0, 3, 2), (0, 1, 3), (0, 2, 1)),
    5: ((3, 2, 1, 0), (0, 1, 5, 4), (1, 2, 6, 5), (2, 3, 7, 6), (3, 0, 4, 7), (4, 5, 6, 7)),
    6: ((0, 2, 1), (3, 4, 5), (0, 1, 4, 3), (1, 2, 5, 4), (2, 0, 3, 5)),
    7: ((3, 2, 1, 0), (0, 1, 4), (1, 2, 4), (2, 3, 4), (3, 0, 4)),
}
VERTICES = {
    4: np.array([[0, 0, 0], [1, 0, 0], [0, 1, 0], [0, 0, 1]], dtype=np.float64),
    5: np.array([[0, 0, 0], [1, 0, 0], [1, 1, 0], [0, 1, 0], [0, 0, 1], [1, 0, 1], [1, 1, 1], [0, 1, 1]],
                dtype=np.float64),
    6: np.array([[0, 0, 0], [1, 0, 0], [0, 1, 0], [0, 0, 1], [1, 0, 1], [0, 1, 1]], dtype=np.float64),
    7: np.array([[0, 0, 0], [1, 0, 0], [1, 1, 0], [0, 1, 0], [0, 0, 1]], dtype=np.float64),
}
for _v in VERTICES.values():
    _v.setflags(write=False)

MAX_ORDER = MAX_MODES - 1

# BasisType (fem/fe/fe_base.hpp): id -> (name, 1-D point set); None: not a nodal basis read here
BASIS_TYPES = {0: "GaussLegendre", 1: "GaussLobatto", 2: "Positive (Bernstein)", 3: "OpenUniform",
               4: "ClosedUniform", 5: "OpenHalfUniform", 6: "Serendipity", 7: "ClosedGL",
               8: "IntegratedGLL"}
NODAL = (0, 1, 3, 4, 5, 7)
CLOSED = (1, 4, 7)
BASIS_CHARS = {"g": 0, "G": 1, "s": 1, "P": 2, "u": 3, "U": 4, "o": 5, "S": 6, "c": 7, "i": 8}
BERGOT, FUENTES = 0, 1  # MFEM's pyramid types; 4.10's default is Fuentes


class SpaceError(ValueError):
    """A collection or element this reader cannot hold exactly (the caller names the file)."""


def points_1d(btype: int, p: int) -> np.ndarray:
    """MFEM's p + 1 points of basis type btype on [0, 1] (Quadrature1D)."""
    n = p + 1
    if btype == 0:
        return 0.5 * (legendre.leggauss(n)[0] + 1.0)
    if btype == 1:
        return 0.5 * (ex.gll_points(n) + 1.0) if n > 1 else np.array([0.5])
    if btype == 3:
        return np.arange(1, n + 1) / (n + 1.0)
    if btype == 4:
        return np.arange(n) / float(n - 1) if n > 1 else np.array([0.5])
    if btype == 5:
        return (np.arange(n) + 0.5) / n
    if btype == 7:
        if n < 2:
            return np.array([1.0])  # MFEM sets the first point to 0, then the last (the same) to 1
        out = np.zeros(n)
        out[-1] = 1.0
        if n > 2:
            g = 0.5 * (legendre.leggauss(n - 1)[0] + 1.0)
            out[1:-1] = 0.5 * (g[:-1] + g[1:])
        return out
    raise SpaceError(f"basis type {btype} ({BASIS_TYPES.get(btype, 'unknown')}) is not a nodal basis read here")


# ----------------------------------------------------------------------------- the nodes

def tri_lattice(p: int):
    """[(i, j)] of a triangle's interior lattice points (i, j >= 1, i + j < p), j outer."""
    return [(i, j) for j in range(1, p) for i in range(1, p - j)]


def _tri_xy(cp, p, i, j):
    w = cp[i] + cp[j] + cp[p - i - j]
    return cp[i] / w, cp[j] / w


def h1_interior(geom: int, p: int, cp) -> np.ndarray:
    """(n, 3) an H1 element's interior nodes (reference X), in MFEM's order."""
    out = []
    if geom == 5:
        out = [(cp[i], cp[j], cp[k]) for k in range(1, p) for j in range(1, p) for i in range(1, p)]
    elif geom == 4:
        for k in range(1, p):
            for j in range(1, p - k):
                for i in range(1, p - j - k):
                    w = cp[i] + cp[j] + cp[k] + cp[p - i - j - k]
                    out.append((cp[i] / w, cp[j] / w, cp[k] / w))
    elif geom == 6:
        out = [(*_tri_xy(cp, p, i, j), cp[k]) for k in range(1, p) for i, j in tri_lattice(p)]
    elif p > 2:  # pyramids: only orders without interior nodes are read (pyramid_order)
        raise SpaceError("H1 pyramid interior nodes")
    return np.array(out, dtype=np.float64).reshape(-1, 3)


def l2_nodes(geom: int, p: int, op) -> np.ndarray:
    """(n, 3) an L2 element's nodes (reference X), in MFEM's order."""
    if geom == 5:
        out = [(op[i], op[j], op[k]) for k in range(p + 1) for j in range(p + 1) for i in range(p + 1)]
    elif geom == 4:
        out = []
        for k in range(p + 1):
            for j in range(p + 1 - k):
                for i in range(p + 1 - j - k):
                    w = op[i] + op[j] + op[k] + op[p - i - j - k]
                    out.append((op[i] / w, op[j] / w, op[k] / w))
    elif geom == 6:
        tri = [_tri_xy(op, p, i, j) for j in range(p + 1) for i in range(p + 1 - j)]
        out = [(x, y, op[k]) for k in range(p + 1) for x, y in tri]
    else:  # Bergot's pyramid (fe_l2.cpp L2_BergotPyramidElement)
        out = []
        for k in range(p + 1):
            for j in range(p + 1 - k):
                wjk = op[j] + op[k] + op[p - j - k]
                for i in range(p + 1 - k):
                    wik = op[i] + op[k] + op[p - i - k]
                    w = wik * wjk * op[p - k]
                    out.append((0.0, 0.0, 1.0) if abs(w) < 1e-14 else
                               (op[i] * (op[j] + op[p - j - k]) / w, op[j] * (op[i] + op[p - i - k]) / w,
                                op[k] * op[p - k] / w))
    return np.array(out, dtype=np.float64).reshape(-1, 3)


def face_weights(nv: int, p: int, cp) -> np.ndarray:
    """(n, nv) the weights on a face's vertices of its interior nodes, in its frame's lattice
    order (a triangle's barycentric, a square's bilinear)."""
    if nv == 3:
        w = np.array([(cp[p - i - j], cp[i], cp[j]) for i, j in tri_lattice(p)], dtype=np.float64).reshape(-1, 3)
        return w / np.maximum(w.sum(axis=1, keepdims=True), 1e-300)
    st = np.array([(cp[i], cp[j]) for j in range(1, p) for i in range(1, p)], dtype=np.float64).reshape(-1, 2)
    s, t = st[:, 0], st[:, 1]
    return np.stack([(1 - s) * (1 - t), s * (1 - t), s * t, (1 - s) * t], axis=1)


def face_dofs(nv: int, p: int) -> int:
    return (p - 1) * (p - 2) // 2 if nv == 3 else (p - 1) ** 2


@lru_cache(maxsize=None)
def face_permutation(nv: int, p: int, corners: tuple) -> np.ndarray:
    """perm (n,): an element's face node k (in its own frame) is the face's node perm[k] (in the
    face's frame), where corners[m] is the element frame's corner holding the face frame's corner m."""
    lattice = tri_lattice(p) if nv == 3 else [(i, j) for j in range(1, p) for i in range(1, p)]
    where = {node: n for n, node in enumerate(lattice)}
    out = np.empty(len(lattice), dtype=np.int64)
    if nv == 3:
        for k, (i, j) in enumerate(lattice):
            mine = (p - i - j, i, j)  # lattice weights on the element frame's corners
            theirs = tuple(mine[corners[m]] for m in range(3))
            out[k] = where[(theirs[1], theirs[2])]
    else:
        grid = np.array([(0, 0), (p, 0), (p, p), (0, p)])  # the element frame's corners
        c0, c1, c3 = grid[corners[0]], grid[corners[1]], grid[corners[3]]
        A = np.stack([c1 - c0, c3 - c0], axis=1) / p  # face frame (I, J) -> element frame (i, j)
        Ainv = np.linalg.inv(A)
        for k, (i, j) in enumerate(lattice):
            I, J = np.rint(Ainv @ (np.array([i, j]) - c0)).astype(int)
            out[k] = where[(int(I), int(J))]
    out.setflags(write=False)
    return out


@lru_cache(maxsize=None)
def h1_layout(geom: int, p: int, btype: int):
    """An H1 element's nodes in the order the reader gathers its values: vertices, edges (local
    order, from the edge's first vertex), faces (local order, each in its own frame), interior.
    Returns the nodes (n, 3), reference X."""
    cp = points_1d(btype, p)
    V = VERTICES[geom]
    parts = [V]
    inner = cp[1:p]
    for a, b in EDGES[geom]:
        parts.append(V[a] + inner[:, None] * (V[b] - V[a]))
    for face in FACES[geom]:
        parts.append(face_weights(len(face), p, cp) @ V[list(face)])
    parts.append(h1_interior(geom, p, cp))
    nodes = np.concatenate(parts, axis=0)
    nodes.setflags(write=False)
    return nodes


def h1_element_dofs(geom: int, p: int) -> int:
    """Interior DOFs of an H1 element (fem/fe_coll.cpp H1_dof)."""
    return {5: (p - 1) ** 3, 4: (p - 1) * (p - 2) * (p - 3) // 6, 6: (p - 1) ** 2 * (p - 2) // 2, 7: 0}[geom]


def l2_count(geom: int, p: int) -> int:
    n = p + 1
    return {5: n ** 3, 4: n * (n + 1) * (n + 2) // 6, 6: n * n * (n + 1) // 2, 7: n * (n + 1) * (2 * n + 1) // 6}[geom]


def check_order(kind: str, geom: int, p: int, pyramid_type: int):
    """SpaceError unless the engine holds MFEM's element of this kind, geometry and order exactly."""
    if p > MAX_ORDER:
        raise SpaceError(f"order {p}: orders up to {MAX_ORDER} can be rendered")
    if geom != 7:
        return
    if kind == "H1":
        ok = p == 1 or (p == 2 and pyramid_type == BERGOT)
    else:
        ok = p == 0 or (p <= 2 and pyramid_type == BERGOT)
    if not ok:
        name = "Bergot" if pyramid_type == BERGOT else "Fuentes"
        raise SpaceError(f"{kind} pyramids of order {p} ({name}'s basis) are rational functions no engine pyramid "
                         f"holds; readable pyramids: H1 order 1, H1 and L2 Bergot (_Pyr0) orders up to 2, L2 order 0")


# ----------------------------------------------------------------------------- to the engine

def modes(geom: int, p: int) -> tuple[int, int, int]:
    """The engine's modes holding MFEM's space of order p (order 0, the constants, in the linear
    expansion: the engine's one-mode expansion is a vertex mode, not a constant)."""
    return (max(p, 1) + 1,) * 3


def to_engine(geom: int, X) -> np.ndarray:
    """The engine's reference coordinates xi of MFEM reference points X (..., 3)."""
    X = np.asarray(X, dtype=np.float64)
    xi = 2.0 * X - 1.0
    return xi[..., [1, 2, 0]] if geom == 6 else xi


@lru_cache(maxsize=128)
def _conversion(geom: int, p: int, key: bytes) -> np.ndarray:
    X = np.frombuffer(key, dtype=np.float64).reshape(-1, 3)
    shape, m = SHAPES[geom], modes(geom, p)
    if p == 0:  # one value, the constant: its coefficients in the linear expansion
        T = ex.fit_modal(shape, m, np.ones(len(ex.fit_points(shape, m))))[:, None] * np.ones((1, len(X)))
    else:
        B = ex.basis_matrix(shape, m, to_engine(geom, X))  # (n, K), square: the spaces agree
        if B.shape[0] != B.shape[1]:
            raise SpaceError(f"{B.shape[0]} nodes for the {B.shape[1]} modes of a {NAMES[geom]} of order {p}")
        T = np.linalg.inv(B)
    T = np.ascontiguousarray(T, dtype=np.float64)
    T.setflags(write=False)
    return T


def conversion(geom: int, p: int, X) -> np.ndarray:
    """(K, n): modal coefficients = matrix @ values at the nodes X (n, 3), for an element of
    order p (the engine's modes(geom, p)); one matrix per node set."""
    return _conversion(int(geom), int(p), np.ascontiguousarray(X, dtype=np.float64).tobytes())


def truncated_order(geom: int, p: int, coeffs: np.ndarray, tol: float) -> np.ndarray:
    """(n,) the smallest order q <= p per element whose modes hold its coefficients (n, K) to tol:
    every coefficient of a mode outside the order-q expansion at most tol (the modified basis is
    hierarchical: an order-q polynomial has exactly those modes)."""
    shape = SHAPES[geom]
    triples = ex.mode_triples(shape, modes(geom, p))
    a, b, c = triples[:, 0], triples[:, 1], triples[:, 2]
    # the order of each mode: the smallest q whose q + 1 modes hold it (engine/expansions.py's triples)
    degree = {HEX: np.maximum(np.maximum(a, b), c), TET: a + b + c, PRISM: np.maximum(a + c, b),
              PYR: np.maximum(a, b) + c}[shape]
    big = np.abs(coeffs) > tol
    top = np.where(big, degree[None, :], 0).max(axis=1) if coeffs.size else np.zeros(0, int)
    return np.maximum(np.asarray(top, dtype=np.int64), 1)  # a constant lies in the linear modes


def keep_modes(geom: int, p: int, q: int) -> np.ndarray:
    """Indices, in the order-p expansion, of the order-q expansion's modes (its storage order)."""
    shape = SHAPES[geom]
    big = {tuple(t): n for n, t in enumerate(ex.mode_triples(shape, modes(geom, p)).tolist())}
    return np.array([big[tuple(t)] for t in ex.mode_triples(shape, modes(geom, q)).tolist()], dtype=np.int64)
