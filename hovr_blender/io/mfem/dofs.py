"""MFEM's DOF numbering, reproduced: which value of a GridFunction belongs to which node of which
element (MFEM 4.10 mesh/mesh.cpp, fem/fespace.cpp; docs/spec/formats.md §7).

The mesh's topology as MFEM builds it on reading (Mesh::FinalizeTopology): edges numbered in
the order they first appear, element by element, each element's edges in its local order
(DSTable::Push); faces likewise, a face known by its three smallest vertices (STable3D), and
held in the frame of the element that first has it (Mesh::GenerateFaces: its vertices in that
element's local face order). H1 DOFs: one per vertex (the vertex numbers), then p - 1 per edge
(running from its lower-numbered vertex to the higher), then each face's interior nodes in the
face's frame, faces in order, then each element's interior nodes, elements in order. L2: each
element's nodes, elements in order. A vector GridFunction holds VDim values per DOF, by nodes
(Ordering 0: every DOF's x, then every y, ...) or by vector dimension (Ordering 1).

Each element's values are gathered at its nodes in the reader's own order (elements.h1_layout),
matching a node to a DOF by where it lies, not by MFEM's tables of DOF orders: an edge's node
at cp[k] from the edge's lower vertex, a face's node by its lattice point in the face's frame.
"""
from __future__ import annotations

from dataclasses import dataclass
from functools import cached_property

import numpy as np

from ...engine import limits
from . import elements as el
from .files import GridFunction, MFEMMesh
from .text import MFEMError


class Topology:
    """Edges and faces of an MFEM mesh, numbered as MFEM numbers them."""

    def __init__(self, mesh: MFEMMesh):
        self.mesh = mesh
        self.groups = mesh.groups()

    def _occurrences(self, table):
        """Per local entity j of each geometry: (element index, j, global vertices (padded -1)),
        all of them in MFEM's visiting order (elements in order, local entities in order)."""
        elems, local, verts = [], [], []
        for geom, (idx, conn) in self.groups.items():
            for j, ent in enumerate(table[geom]):
                limits.progress()
                elems.append(idx)
                local.append(np.full(idx.size, j))
                v = np.full((idx.size, 4), -1, dtype=np.int64)
                v[:, :len(ent)] = conn[:, list(ent)]
                verts.append(v)
        elems, local, verts = np.concatenate(elems), np.concatenate(local), np.concatenate(verts)
        limits.progress()
        order = np.lexsort((local, elems))
        return elems[order], local[order], verts[order]

    @staticmethod
    def _first_appearance(keys):
        """(id of each occurrence, first occurrence of each id, count): ids in order of first appearance."""
        _, first, inverse, counts = np.unique(keys, axis=0, return_index=True, return_inverse=True,
                                              return_counts=True)
        limits.progress()
        inverse = inverse.reshape(-1)
        rank = np.empty(first.size, dtype=np.int64)
        rank[np.argsort(first, kind="stable")] = np.arange(first.size)
        by_rank = np.empty_like(first)
        by_rank[rank] = first
        return rank[inverse], by_rank, counts[np.argsort(rank)]

    @cached_property
    def edges(self):
        """{geom: (edge ids (n, m), forward (n, m): the local edge runs from the lower vertex)}, count."""
        elems, local, verts = self._occurrences(el.EDGES)
        limits.progress()
        a, b = verts[:, 0], verts[:, 1]
        ids, _, _ = self._first_appearance(np.stack([np.minimum(a, b), np.maximum(a, b)], axis=1))
        out = {}
        for geom, (idx, _) in self.groups.items():
            limits.progress()
            where = np.isin(elems, idx)  # this geometry's occurrences, in element order, local order
            m = len(el.EDGES[geom])
            out[geom] = (ids[where].reshape(idx.size, m), (a < b)[where].reshape(idx.size, m))
        return out, int(ids.max()) + 1 if ids.size else 0

    @cached_property
    def faces(self):
        """{geom: (face ids (n, f), corners (n, f, 4): which of the element's face corners holds the
        face frame's corner m)}, the faces' vertex counts."""
        elems, local, verts = self._occurrences(el.FACES)
        nv = (verts >= 0).sum(axis=1)
        ordered = np.sort(np.where(verts >= 0, verts, np.iinfo(np.int64).max), axis=1)
        limits.progress()
        ids, first, counts = self._first_appearance(ordered[:, :3])
        limits.progress()
        path = self.mesh.path
        if counts.size and counts.max() > 2:
            f = int(np.argmax(counts > 2))
            raise MFEMError(f"{path}: face {f} is shared by {int(counts[f])} elements (at most two can share one)")
        frame = verts[first[ids]]
        differ = np.any(np.sort(frame, axis=1) != np.sort(verts, axis=1), axis=1)
        if differ.any():
            o = int(np.flatnonzero(differ)[0])
            raise MFEMError(f"{path}: element {int(elems[o])}'s face {int(local[o])} shares three vertices with another "
                            "face but not all of them")
        limits.progress()
        match = verts[:, :, None] == frame[:, None, :]  # [o, k, m]: the element's corner k is the frame's corner m
        match &= (frame >= 0)[:, None, :]
        corners = np.where(frame >= 0, np.argmax(match, axis=1), -1)
        limits.progress()
        quad = nv == 4
        step = (corners[:, 1] - corners[:, 0]) % 4
        twisted = quad & ~(((step == 1) | (step == 3)) & np.all((np.roll(corners, -1, axis=1) - corners) % 4 == step[:, None],
                                                                axis=1))
        if twisted.any():
            o = int(np.flatnonzero(twisted)[0])
            raise MFEMError(f"{path}: element {int(elems[o])}'s face {int(local[o])} meets its neighbour's twisted")
        out = {}
        for geom, (idx, _) in self.groups.items():
            limits.progress()
            where = np.isin(elems, idx)
            f = len(el.FACES[geom])
            out[geom] = (ids[where].reshape(idx.size, f), corners[where].reshape(idx.size, f, 4))
        face_nv = np.empty(first.size, dtype=np.int64)
        face_nv[ids] = nv
        return out, face_nv


@dataclass
class Gathered:
    """One geometry's elements of a space: their values at the nodes and the nodes."""

    geom: int
    elements: np.ndarray  # (n,) element indices
    values: np.ndarray  # (n, nodes, vdim)
    nodes: np.ndarray  # (nodes, 3) MFEM reference coordinates
    order: int


def gather(topology: Topology, gf: GridFunction, path: str) -> list[Gathered]:
    """Each geometry's elements' values at their nodes, in the element's node order (`path`: the
    file holding the GridFunction); MFEMError when its values do not fit its space on this mesh."""
    mesh, col = topology.mesh, gf.collection
    p = col.order
    for geom in topology.groups:
        try:
            el.check_order(col.kind, geom, p, col.pyramid)
        except el.SpaceError as exc:
            raise MFEMError(f"{path}: {col.name}: {exc}") from None
    dof_sets, ndofs = (_h1_dofs if col.kind == "H1" else _l2_dofs)(topology, p)
    if gf.values.size != ndofs * gf.vdim:
        hint = ""
        if gf.values.size > ndofs * gf.vdim:
            hint = (" (a variable-order space saved as it is? MFEM writes no element orders: save the field "
                    "raised to its largest order, GridFunction::ProlongateToMaxOrder())")
        raise MFEMError(f"{path}: line {gf.line}: {gf.values.size:,} values; {col.name} with VDim {gf.vdim} on this "
                        f"mesh ({mesh.num_elements:,} elements) has {ndofs * gf.vdim:,}{hint}")
    limits.check_bytes(sum(d.size for _, d in dof_sets) * gf.vdim * 8 * 3, f"{path}: the elements' values")
    if gf.ordering == 1:
        table = gf.values.reshape(ndofs, gf.vdim)
    else:
        table = gf.values.reshape(gf.vdim, ndofs).T
    out = []
    for geom, dofs in dof_sets:
        limits.progress()
        out.append(Gathered(geom, topology.groups[geom][0], table[dofs], nodes_of(col, geom), p))
    return out


def nodes_of(col, geom: int) -> np.ndarray:
    """(n, 3) the nodes of an element of this collection, in the order gather() gives its values."""
    if col.kind == "H1":
        return el.h1_layout(geom, col.order, col.btype)
    return el.l2_nodes(geom, col.order, el.points_1d(col.btype, col.order))


def _l2_dofs(topology: Topology, p: int):
    mesh = topology.mesh
    counts = np.array([el.l2_count(g, p) if g in el.SHAPES else 0 for g in range(8)], dtype=np.int64)
    start = np.concatenate([[0], np.cumsum(counts[mesh.geoms])])
    out = [(geom, start[idx][:, None] + np.arange(counts[geom])[None, :])
           for geom, (idx, _) in topology.groups.items()]
    return out, int(start[-1])


def _h1_dofs(topology: Topology, p: int):
    mesh = topology.mesh
    nv_dofs = mesh.num_vertices
    (edges, num_edges) = topology.edges if p >= 2 else ({}, 0)
    ne_dofs = num_edges * (p - 1)
    faces, face_nv = topology.faces if p >= 2 else ({}, np.zeros(0, np.int64))
    fcount = np.array([el.face_dofs(int(n), p) for n in face_nv], dtype=np.int64) if p >= 2 else np.zeros(0, np.int64)
    fbase = nv_dofs + ne_dofs + np.concatenate([[0], np.cumsum(fcount)])[:-1]
    limits.progress()
    nf_dofs = int(fcount.sum())
    interior = np.array([el.h1_element_dofs(int(g), p) if g in el.SHAPES else 0 for g in range(8)], dtype=np.int64)
    per = interior[mesh.geoms]
    ibase = nv_dofs + ne_dofs + nf_dofs + np.concatenate([[0], np.cumsum(per)])
    out = []
    for geom, (idx, conn) in topology.groups.items():
        parts = [conn]
        if p >= 2:
            eid, forward = edges[geom]
            k = np.arange(p - 1)
            along = np.where(forward[..., None], k, p - 2 - k)
            parts.append((nv_dofs + eid[..., None] * (p - 1) + along).reshape(idx.size, -1))
            fid, corners = faces[geom]
            for j, face in enumerate(el.FACES[geom]):
                limits.progress()
                n = el.face_dofs(len(face), p)
                if n == 0:
                    continue
                c = corners[:, j, :len(face)]
                keys, which = np.unique(c, axis=0, return_inverse=True)
                perms = np.stack([el.face_permutation(len(face), p, tuple(int(v) for v in key)) for key in keys])
                parts.append(fbase[fid[:, j]][:, None] + perms[which.reshape(-1)])
        count = interior[geom]
        parts.append(ibase[idx][:, None] + np.arange(count)[None, :])
        out.append((geom, np.concatenate(parts, axis=1)))
    return out, int(ibase[-1])
