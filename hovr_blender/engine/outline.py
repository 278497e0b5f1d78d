"""The domain's outline: the edges of the mesh's boundary faces, for drawing the volume as a
wire object (straight element hulls; curved faces are drawn straight)."""
from __future__ import annotations

import numpy as np

from .mesh import VolumeMesh
from .shapes import FACES


def outline_edges(mesh: VolumeMesh):
    """The domain's outline for the viewport: (vertices (V, 3) float64, edges (E, 2) int) of the
    faces of the elements' straight vertex hulls that belong to one element only (the
    boundary; curved faces are drawn straight). Corners are merged when they coincide to
    1e-9 of the domain's size. A quadrilateral face met by two triangles (or two triangles
    met by the other diagonal's two, as between a hexahedron and tetrahedra) is interior too."""
    verts = np.asarray(mesh.vertices, dtype=np.float64)
    shapes = np.asarray(mesh.shape)
    size = float(np.ptp(verts.reshape(-1, 3), axis=0).max()) or 1.0
    q = np.round(verts.reshape(-1, 3) / (1e-9 * size)).astype(np.int64)
    uniq, inverse = np.unique(q, axis=0, return_inverse=True)
    vid = inverse.reshape(-1).reshape(verts.shape[:2])  # (N, 8) merged corner ids
    corners = np.zeros((len(uniq), 3))
    corners[vid.ravel()] = verts.reshape(-1, 3)
    faces = []  # (F, 4) corner ids, -1 pads triangles
    for sh, flist in FACES.items():
        el = np.nonzero(shapes == sh)[0]
        if el.size == 0:
            continue
        for f in flist:
            ids = vid[el][:, list(f)]
            if len(f) == 3:
                ids = np.concatenate([ids, np.full((len(el), 1), -1)], axis=1)
            faces.append(ids)
    faces = np.concatenate(faces)
    _, first, counts = np.unique(np.sort(faces, axis=1), axis=0, return_index=True, return_counts=True)
    single = faces[first[counts == 1]]
    quads, tris = single[single[:, 3] >= 0], single[single[:, 3] < 0, :3]
    inner_q, inner_t = faces_covered_from_both_sides(quads, tris, len(corners))
    edges = np.concatenate([
        np.stack([quads[~inner_q], np.roll(quads[~inner_q], -1, axis=1)], axis=-1).reshape(-1, 2),
        np.stack([tris[~inner_t], np.roll(tris[~inner_t], -1, axis=1)], axis=-1).reshape(-1, 2),
    ])
    edges = edges[edges[:, 0] != edges[:, 1]]
    edges = np.unique(np.sort(edges, axis=1), axis=0)
    used = np.unique(edges)
    remap = np.full(len(corners), -1, dtype=np.int64)
    remap[used] = np.arange(used.size)
    return corners[used], remap[edges]


def faces_covered_from_both_sides(quads, tris, nverts):
    """Which unmatched quads and triangles cover the same quadrilateral from two sides: a quad
    and a pair of triangles sharing a diagonal, or two pairs on different diagonals."""
    inner_q, inner_t = np.zeros(len(quads), bool), np.zeros(len(tris), bool)
    if len(tris) < 2:
        return inner_q, inner_t
    te = np.sort(np.stack([tris[:, [0, 1]], tris[:, [1, 2]], tris[:, [2, 0]]], axis=1).reshape(-1, 2), axis=1)
    tri_of = np.repeat(np.arange(len(tris)), 3)
    ue, inv, cnt = np.unique(te, axis=0, return_inverse=True, return_counts=True)
    inv = inv.reshape(-1)
    shared = np.nonzero(cnt[inv] == 2)[0]
    shared = shared[np.argsort(inv[shared], kind="stable")]
    t1, t2 = tri_of[shared[0::2]], tri_of[shared[1::2]]
    diag = ue[inv[shared[0::2]]]
    both = np.sort(np.concatenate([tris[t1], tris[t2]], axis=1), axis=1)  # the diagonal's ends twice
    keep = np.concatenate([np.ones((len(both), 1), bool), both[:, 1:] != both[:, :-1]], axis=1)
    ok = keep.sum(axis=1) == 4
    pair_keys = both[ok][keep[ok]].reshape(-1, 4)
    t1, t2, diag = t1[ok], t2[ok], diag[ok]
    keys = np.concatenate([np.sort(quads, axis=1), pair_keys])
    source = np.concatenate([np.full(len(quads), -1), diag[:, 0] * nverts + diag[:, 1]])
    _, group = np.unique(keys, axis=0, return_inverse=True)
    group = group.reshape(-1)
    distinct = np.unique(np.stack([group, source], axis=1), axis=0)
    inside = np.bincount(distinct[:, 0], minlength=group.max() + 1 if len(group) else 0) >= 2
    inner_q = inside[group[: len(quads)]]
    hit = inside[group[len(quads):]]
    inner_t[t1[hit]] = True
    inner_t[t2[hit]] = True
    return inner_q, inner_t
