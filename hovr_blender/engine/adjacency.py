"""Host-side inputs of the traversal: which element lies across each face, how a point of a shared
face in one element's reference coordinates reads in the other's, and a straight-sided guess of
every element's world -> reference map.

Faces are numbered as the kernels' element.face_plane numbers them (shapes.FACE_PLANES;
tests/engine/test_adjacency.py checks the two agree). Two faces are the same when
their corner vertices coincide (to 1e-9 of the mesh's size: corner_ids); a face met by more or fewer than
two elements has no neighbour, and the traversal searches the BVH there instead of walking.
Matching corners only is enough: a wrong match (two curved faces with the same corners but
different shapes) costs the kernel one failed inside test, never a wrong segment.
"""
from __future__ import annotations

import numpy as np

from .shapes import FACE_PLANES, MAX_FACES, VERTICES, plane_vertices

def corner_ids(mesh) -> np.ndarray:
    """(N, V) int64: each element's corner vertices numbered so that coincident ones share a
    number (-1 past a shape's corners). Coincident: equal when rounded to 1e-9 of the mesh's size
    on one of the 8 grids shifted by half a cell per axis (two points closer than half a cell in
    every axis share a cell on one of them; one grid alone splits the pairs that straddle its
    cells' walls: two of the NGSolve post's elements lost their shared face so), joined
    transitively."""
    V = np.asarray(mesh.vertices, dtype=np.float64)
    ncorner = np.array([len(VERTICES[s]) for s in range(4)])[mesh.shape]
    real = np.arange(V.shape[1])[None, :] < ncorner[:, None]
    pts = V[real]
    lo = pts.min(axis=0)
    scaled = (pts - lo) / (max(float(np.ptp(pts, axis=0).max()), 1e-300) * 1e-9)
    labels = np.arange(len(pts))
    shifts = [np.array([(k >> a) & 1 for a in range(3)]) * 0.5 for k in range(8)]
    while True:
        before = labels.copy()
        for shift in shifts:
            cell = np.floor(scaled + shift).astype(np.int64)
            order = np.lexsort(cell.T[::-1])
            new_cell = np.ones(len(order), bool)
            new_cell[1:] = np.any(cell[order[1:]] != cell[order[:-1]], axis=1)
            inv = np.empty(len(order), np.int64)
            inv[order] = np.cumsum(new_cell) - 1
            low = np.full(inv.max() + 1, len(pts))
            np.minimum.at(low, inv, labels)
            labels = low[inv]
        while not np.array_equal(labels[labels], labels):
            labels = labels[labels]
        if np.array_equal(labels, before):
            break
    out = np.full(V.shape[:2], -1, np.int64)
    out[real] = labels
    return out


def face_neighbours(mesh) -> np.ndarray:
    """(N * MAX_FACES,) int32: the element across face f of element e at e * MAX_FACES + f, -1 if none."""
    n = mesh.num_elements
    out = np.full(n * MAX_FACES, -1, np.int32)
    ids = corner_ids(mesh)
    keys, slots = [], []
    for shape in np.unique(mesh.shape):
        elems = np.nonzero(mesh.shape == shape)[0]
        for f, idx in enumerate(plane_vertices(int(shape))):
            # a face's key: its corners' numbers sorted, padded to four
            corners = np.sort(ids[elems][:, idx], axis=1)
            if corners.shape[1] == 3:
                corners = np.concatenate([np.full((len(elems), 1), -1, np.int64), corners], axis=1)
            keys.append(corners)
            slots.append(elems * MAX_FACES + f)
    keys = np.concatenate(keys)
    slots = np.concatenate(slots)
    order = np.lexsort(keys.T[::-1])
    keys, slots = keys[order], slots[order]
    same = np.all(keys[1:] == keys[:-1], axis=1)
    # runs of exactly two equal keys are shared faces
    start = np.concatenate([[True], ~same])
    run_id = np.cumsum(start) - 1
    run_len = np.bincount(run_id)
    pair = np.nonzero(same & (run_len[run_id[1:]] == 2))[0]
    a, b = slots[pair], slots[pair + 1]
    out[a] = b // MAX_FACES
    out[b] = a // MAX_FACES
    return out


def face_maps(mesh, neighbours: np.ndarray) -> np.ndarray:
    """(N * MAX_FACES, 3, 4) float64: for face f of element e with a neighbour n, the affine map
    xi_n = M[:, :3] xi_e + M[:, 3] of a point of the face in e's reference coordinates to the same
    point in n's, from the face's corners matched by their world positions (a reference face is
    flat, and a conforming face's geometry is one polynomial of its corners' coordinates from either
    side; points off the face go along the normals, inward in e to outward in n); zero elsewhere.
    The walk takes the neighbour's solution where it leaves e from this (kernels/walk.py)."""
    n_el = mesh.num_elements
    out = np.zeros((n_el * MAX_FACES, 3, 4))
    nb = np.asarray(neighbours).reshape(n_el, MAX_FACES)
    elem, face = np.nonzero(nb >= 0)
    if elem.size == 0:
        return out
    other = nb[elem, face]
    back = np.argmax(nb[other] == elem[:, None], axis=1)  # n's face that leads back to e
    keys = np.stack([mesh.shape[elem], face, mesh.shape[other], back], axis=1)
    for key in np.unique(keys, axis=0):
        se, f, sn, g = (int(v) for v in key)
        sel = np.nonzero((keys == key).all(axis=1))[0]
        ie, ig = plane_vertices(se)[f], plane_vertices(sn)[g]
        if len(ie) != len(ig):
            continue
        xe = mesh.vertices[elem[sel]][:, ie]  # (m, k, 3) world corners, e's order
        xn = mesh.vertices[other[sel]][:, ig]
        match = np.argmin(np.linalg.norm(xe[:, :, None] - xn[:, None], axis=-1), axis=2)  # (m, k)
        ne = np.asarray(FACE_PLANES[se][f][0], float)
        nn = np.asarray(FACE_PLANES[sn][g][0], float)
        P = VERTICES[se][ie[:3]]  # three corners and a point off the face, in e's coordinates
        P = np.vstack([P, P[0] - ne / np.linalg.norm(ne)])
        Q = VERTICES[sn][np.asarray(ig)[match[:, :3]]]  # (m, 3, 3)
        Q = np.concatenate([Q, (Q[:, 0] + nn / np.linalg.norm(nn))[:, None]], axis=1)
        H = np.linalg.inv(np.hstack([P, np.ones((4, 1))]).T)  # Q^T = M [P^T; 1]
        out[elem[sel] * MAX_FACES + f] = np.einsum("mpj,pk->mjk", Q, H)
    return out


def vertex_affine_guess(mesh) -> np.ndarray:
    """(N, 3, 4): xi ~ M[:, :3] x + M[:, 3], exact for affine elements and, for curved ones,
    the map of their straight-sided twin through vertex 0 and its three axis neighbours: the
    start of Newton's inversion (kernels/geometry.start_guess)."""
    M = mesh.ref_from_world.copy()
    if mesh.affine is None or mesh.affine.all():
        return M
    for shape in np.unique(mesh.shape[~mesh.affine]):
        V = VERTICES[int(shape)]
        axes = [int(np.nonzero((V == -1 + 2 * np.eye(3)[d]).all(axis=1))[0][0]) for d in range(3)]
        elems = np.nonzero((mesh.shape == shape) & ~mesh.affine)[0]
        X = mesh.vertices[elems]
        J = 0.5 * np.transpose(X[:, axes] - X[:, :1], (0, 2, 1))  # columns dx/dxi_d
        det = np.linalg.det(J)
        good = np.isfinite(det) & (np.abs(det) > 0)
        A = np.zeros_like(J)
        A[good] = np.linalg.inv(J[good])
        M[elems, :, :3] = A
        # xi = A (x - x_0) - 1; degenerate twins: xi = 0 (Newton starts from the centre)
        M[elems, :, 3] = np.where(good[:, None], -np.einsum("mij,mj->mi", A, X[:, 0]) - 1.0, 0.0)
    return M
