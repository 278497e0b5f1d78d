"""Element geometry as a modal expansion (docs/spec/formats.md §2.12): vertex modes = vertex
coordinates; each curved edge's modes are fitted to Nektar++'s edge curve (interpolant of the
points with the end points moved onto the vertices); each face with F points adds its bubble
(the interior-mode part of the face interpolant); interior modes stay zero. For hexes this is
the Gordon-Hall blend the spec describes. Every element is certified valid (engine/validity.py)."""
from __future__ import annotations

from functools import lru_cache

import numpy as np

from ...engine import expansions as ex
from ...engine import limits
from ...engine import validity
from ...engine.expansions import gll_points
from ...engine.mesh import MeshError
from ...engine.shapes import EDGES, FACES, NAMES, VERTICES
from .errors import NektarError
from .mesh_file import NektarMesh
from .points import lagrange_matrix, points_1d, tri_evenly_spaced
from .topology import ElementTopology, element_topology

STRAIGHT_MODES = 2  # geometry modes of an element without curves: its vertices alone


class _GeometrySpace:
    """Mode classification and fit matrices of one geometry space: `num_modes` modes per
    direction of a shape."""

    def __init__(self, shape, num_modes):
        self.shape, self.num_modes = shape, num_modes
        self.modes = np.array([num_modes, num_modes, num_modes])
        self.num_coeffs = ex.num_coeffs(shape, self.modes)
        self.mode_triples = [tuple(t) for t in np.asarray(ex.mode_triples(shape, self.modes)).tolist()]
        ref = VERTICES[shape]
        at_vertices = self.mode_values(ref)
        on_vertex = np.abs(at_vertices).max(axis=0) > 1e-9
        self.vertex_modes = np.argmax(np.abs(at_vertices), axis=1)  # the mode of each vertex
        if on_vertex.sum() != len(ref) or len(set(self.vertex_modes.tolist())) != len(ref):
            raise RuntimeError(f"{NAMES[shape]}: vertex modes are not one per vertex")
        self.vertex_inverse = np.linalg.inv(at_vertices[:, self.vertex_modes])
        self.edge_samples = _edge_samples(num_modes)
        t = np.linspace(-0.9, 0.9, 7)
        on_edge = []
        for a, b in EDGES[shape]:
            on_edge.append(np.abs(self.mode_values(_segment(ref[a], ref[b], t))).max(axis=0) > 1e-9)
        on_edge = np.array(on_edge) & ~on_vertex
        self.edge_modes = [np.flatnonzero(row) for row in on_edge]
        self.edge_fit = []  # per edge: (pseudo-inverse on its own modes, vertex modes at its samples)
        for (a, b), own in zip(EDGES[shape], self.edge_modes):
            values = self.mode_values(_segment(ref[a], ref[b], self.edge_samples))
            self.edge_fit.append((np.linalg.pinv(values[:, own]) if len(own) else None, values[:, self.vertex_modes]))
        on_face = []
        for face in FACES[shape]:
            on_face.append(np.abs(self.mode_values(_face_points(ref[list(face)]))).max(axis=0) > 1e-9)
        self.traced_on_face = np.array(on_face)  # every mode with a trace on face k
        on_face = self.traced_on_face & ~on_vertex & ~on_edge.any(axis=0)
        self.face_modes = [np.flatnonzero(row) for row in on_face]
        if np.any(on_edge.sum(axis=0) > 1) or np.any(on_face.sum(axis=0) > 1):
            raise RuntimeError(f"{NAMES[shape]}: an edge or face mode lies on two edges or faces")
        self._face_fits = {}

    def mode_values(self, xi):
        """(len(xi), num_coeffs): every mode at reference points xi."""
        return ex.eval_modal(self.shape, self.modes, np.eye(self.num_coeffs), np.asarray(xi, float))

    def face_bubble_fit(self, k, xi_points, n):
        """Pseudo-inverse fitting F points at xi_points with the modes of degree < n traced on face k;
        the caller keeps the face-interior part. Cached by the point positions."""
        key = (k, n, np.round(xi_points, 12).tobytes())
        if key not in self._face_fits:
            small = {tuple(t) for t in np.asarray(ex.mode_triples(self.shape, (n, n, n))).tolist()}
            cols = np.array([i for i in np.flatnonzero(self.traced_on_face[k]) if self.mode_triples[i] in small])
            A = self.mode_values(xi_points)[:, cols]
            if np.linalg.matrix_rank(A) < len(cols):
                self._face_fits[key] = None
            else:
                keep = np.isin(cols, self.face_modes[k])
                self._face_fits[key] = (cols[keep], np.linalg.pinv(A)[keep])
        return self._face_fits[key]


def _segment(a, b, s):
    """Points at parameters s in [-1, 1] on the segment from a to b."""
    s = np.asarray(s)[:, None]
    return a * (1 - s) / 2 + b * (1 + s) / 2


def _face_points(corners):
    """Sample points inside the face with these corners (3 or 4), where a mode's trace shows."""
    g = np.linspace(0.1, 0.9, 5)
    if len(corners) == 4:
        u, v = np.meshgrid(g, g)
        u, v = u.ravel()[:, None], v.ravel()[:, None]
        return (corners[0] * (1 - u) * (1 - v) + corners[1] * u * (1 - v) + corners[2] * u * v
                + corners[3] * (1 - u) * v)
    u, v = np.meshgrid(g, g)
    keep = (u + v) < 0.95
    u, v = u[keep][:, None], v[keep][:, None]
    return corners[0] * (1 - u - v) + corners[1] * u + corners[2] * v


@lru_cache(maxsize=None)
def _geometry_space(shape, num_modes) -> _GeometrySpace:
    return _GeometrySpace(shape, num_modes)


def _edge_samples(num_modes):
    return gll_points(max(num_modes + 1, 3))  # one more than the modes: the edge fit is overdetermined


def _edge_curve(mesh: NektarMesh, edge_id, num_modes, forward):
    """Nektar++'s curved edge (docs/spec/formats.md §2.12 step 1) at the edge samples of the
    space of num_modes, read from the local edge's first vertex (forward: the mesh edge's v0) to
    its second."""
    points_type, points = mesh.curved_edges[edge_id]
    z = points_1d(points_type, len(points), mesh.path, f"curved edge {edge_id}")
    L, w0, w1 = _curve_matrix(points_type, len(points), num_modes, forward, z.tobytes())
    x0, x1 = (mesh.vertices[v] for v in mesh.edges[edge_id])
    return L @ points + w0 * x0 + w1 * x1


@lru_cache(maxsize=None)
def _curve_matrix(points_type, count, num_modes, forward, z_bytes):
    """(L, w0, w1): curve samples = L @ points + w0 x0 + w1 x1. Overwriting the vertex modes
    moves the interpolant's ends onto the vertices linearly."""
    z = np.frombuffer(z_bytes)
    s = _edge_samples(num_modes) * (1 if forward else -1)
    L = lagrange_matrix(z, np.concatenate([s, [-1.0, 1.0]]))
    w0, w1 = ((1 - s) / 2)[:, None], ((1 + s) / 2)[:, None]
    return L[:-2] - w0 * L[-2] - w1 * L[-1], w0, w1


def _points_per_side(tag, count):
    """n of a face's count points: n*n on a quadrilateral, n(n+1)/2 on a triangle (if whole)."""
    if tag == "Q":
        return int(round(np.sqrt(count)))
    return int(round((np.sqrt(8 * count + 1) - 1) / 2))


def face_frame_points(mesh: NektarMesh, face_id, warnings):
    """(points, n) of a curved face's F points in the face's own frame, or (None, n) when the
    interior positions are unknown (then only the edges shape the face)."""
    tag = mesh.faces[face_id][0]
    points_type, points = mesh.curved_faces[face_id]
    what = f"curved face {face_id}"
    n = _points_per_side(tag, len(points))
    if tag == "Q":
        if n * n != len(points):
            raise NektarError(f"{mesh.path}: {what}: {len(points)} points is not n*n for a quadrilateral")
        z = points_1d(points_type, n, mesh.path, what)
        a, b = np.meshgrid(z, z)  # first index (fastest) along face axis 0
        return np.stack([a.ravel(), b.ravel()], axis=1), n
    if points_type == "NodalTriEvenlySpaced" and n * (n + 1) // 2 == len(points) and n >= 2:
        return tri_evenly_spaced(n), n
    if n * (n + 1) // 2 == len(points) and n <= 3:  # vertices and edge points only: nothing interior
        return None, n
    warnings.append(f"{mesh.path}: curved triangle face {face_id} ({points_type}, {len(points)} points): interior "
                    "point positions of this type are not reproduced; the face follows its edge curves only")
    return None, n


def face_to_element(shape, topology: ElementTopology, face_vertex_ids, uv, tag):
    """Element reference coordinates of face-frame points uv on the face with these vertices."""
    ref = VERTICES[shape]
    position = {v: ref[i] for i, v in enumerate(topology.vertices)}
    corners = np.array([position[v] for v in face_vertex_ids])
    a, b = uv[:, :1], uv[:, 1:]
    if tag == "Q":
        u, v = (1 + a) / 2, (1 + b) / 2
        return (corners[0] * (1 - u) * (1 - v) + corners[1] * u * (1 - v) + corners[2] * u * v
                + corners[3] * (1 - u) * v)
    return corners[0] * (-(a + b) / 2) + corners[1] * (1 + a) / 2 + corners[2] * (1 + b) / 2


def _element_modes(mesh: NektarMesh, topology: ElementTopology):
    """Geometry modes per direction: enough for the element's most curve points."""
    num_modes = STRAIGHT_MODES
    for e, _ in topology.edges:
        if e in mesh.curved_edges:
            num_modes = max(num_modes, len(mesh.curved_edges[e][1]))
    for f, _ in topology.faces:
        if f in mesh.curved_faces:
            num_modes = max(num_modes, _points_per_side(mesh.faces[f][0], len(mesh.curved_faces[f][1])))
    return num_modes


def _curved_element(mesh: NektarMesh, shape, topology: ElementTopology, num_modes, warnings, edge_cache):
    """(K, 3) geometry coefficients of a curved element; edge_cache: curve samples by
    (edge, direction, num_modes), shared by the elements of one mesh."""
    space = _geometry_space(shape, num_modes)
    coeffs = np.zeros((space.num_coeffs, 3))
    corners = np.array([mesh.vertices[v] for v in topology.vertices])
    coeffs[space.vertex_modes] = space.vertex_inverse @ corners
    vertex_coeffs = coeffs[space.vertex_modes]
    for k, (e, forward) in enumerate(topology.edges):
        if e not in mesh.curved_edges or not len(space.edge_modes[k]):
            continue
        key = (e, forward, num_modes)
        if key not in edge_cache:
            edge_cache[key] = _edge_curve(mesh, e, num_modes, forward)
        pinv, vertex_part = space.edge_fit[k]
        coeffs[space.edge_modes[k]] = pinv @ (edge_cache[key] - vertex_part @ vertex_coeffs)
    for k, (f, face_vertex_ids) in enumerate(topology.faces):
        if f not in mesh.curved_faces:
            continue
        uv, n = face_frame_points(mesh, f, warnings)
        if uv is None:
            continue
        xi = face_to_element(shape, topology, face_vertex_ids, uv, mesh.faces[f][0])
        fit = space.face_bubble_fit(k, xi, n)
        if fit is None:
            raise NektarError(f"{mesh.path}: curved face {f}: its points do not determine a surface")
        cols, rows = fit
        coeffs[cols] = rows @ mesh.curved_faces[f][1]
    return coeffs


def _straight_elements(shape, corners):
    """(N, K, 3) geometry of straight elements with corners (N, vertices, 3): vertex modes only."""
    space = _geometry_space(shape, STRAIGHT_MODES)
    coeffs = np.zeros((corners.shape[0], space.num_coeffs, 3))
    coeffs[:, space.vertex_modes] = np.einsum("vw,nwj->nvj", space.vertex_inverse, corners)
    return coeffs


def _check_jacobians(path, shape, num_modes, ids, coeffs):
    """NektarError for the first element not certified valid (engine/validity.py)."""
    try:
        validity.check_elements(shape, (num_modes,) * 3, coeffs, ids)
    except MeshError as exc:
        raise NektarError(f"{path}: {exc}") from None


def mesh_geometry(mesh: NektarMesh, warnings):
    """(geometry modes (n, 3), [(K, 3) coefficients of each element]) of the mesh's elements,
    every Jacobian checked; notes about approximated faces are appended to warnings."""
    n = len(mesh.elements)
    face_vertex_cache, edge_cache = {}, {}
    modes = np.full((n, 3), STRAIGHT_MODES, dtype=np.int32)
    coeffs: list = [None] * n
    straight: dict = {}  # shape -> [(position, corners)]
    curved: dict = {}  # (shape, num_modes) -> [position]
    for k, (e, shape, face_ids) in enumerate(mesh.elements):
        limits.progress()
        topology = element_topology(mesh, e, shape, face_ids, face_vertex_cache)
        num_modes = _element_modes(mesh, topology)
        if num_modes == STRAIGHT_MODES:
            straight.setdefault(shape, []).append((k, [mesh.vertices[v] for v in topology.vertices]))
        else:
            modes[k] = num_modes
            coeffs[k] = _curved_element(mesh, shape, topology, num_modes, warnings, edge_cache)
            curved.setdefault((shape, num_modes), []).append(k)
    for shape, items in straight.items():
        positions = [k for k, _ in items]
        group = _straight_elements(shape, np.array([corners for _, corners in items]))
        _check_jacobians(mesh.path, shape, STRAIGHT_MODES, [mesh.elements[k][0] for k in positions], group)
        for k, c in zip(positions, group):
            coeffs[k] = c
    for (shape, num_modes), positions in curved.items():
        _check_jacobians(mesh.path, shape, num_modes, [mesh.elements[k][0] for k in positions],
                         np.stack([coeffs[k] for k in positions]))
    return modes, coeffs
