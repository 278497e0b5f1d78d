"""An element's local numbering from the mesh's faces: which mesh vertex is local vertex i,
which mesh edge is local edge j and in which direction (docs/spec/formats.md §2.11)."""
from __future__ import annotations

from dataclasses import dataclass

from ...engine.shapes import EDGES, FACES, HEX, NAMES, PRISM, PYR, TET
from .errors import NektarError
from .mesh_file import NektarMesh

# local vertex i = the mesh vertex common to these three faces (positions in the entry)
VERTEX_FACES = {
    HEX: ((0, 1, 4), (0, 1, 2), (0, 2, 3), (0, 3, 4), (1, 4, 5), (1, 2, 5), (2, 3, 5), (3, 4, 5)),
    PRISM: ((0, 1, 4), (0, 1, 2), (0, 2, 3), (0, 3, 4), (1, 2, 4), (2, 3, 4)),
    TET: ((0, 1, 3), (0, 1, 2), (0, 2, 3), (1, 2, 3)),
    PYR: ((0, 1, 4), (0, 1, 2), (0, 2, 3), (0, 3, 4), (1, 2, 4)),
}


@dataclass
class ElementTopology:
    vertices: list  # mesh vertex IDs in local order
    edges: list  # (mesh edge id, forward: mesh v0 is the local edge's first vertex)
    faces: list  # (mesh face id, face vertex IDs in the face's own order)


def face_vertices(mesh: NektarMesh, face_id):
    """The face's own vertex order: vertex j = end of edge j not shared with edge j+1."""
    _, edge_ids = mesh.faces[face_id]
    out = []
    n = len(edge_ids)
    for j in range(n):
        a, b = mesh.edges[edge_ids[j]]
        c, d = mesh.edges[edge_ids[(j + 1) % n]]
        if b in (c, d) and a not in (c, d):
            out.append(a)
        elif a in (c, d) and b not in (c, d):
            out.append(b)
        else:
            raise NektarError(f"{mesh.path}: face {face_id}: edges {edge_ids[j]} and {edge_ids[(j + 1) % n]} "
                              "do not meet in one vertex")
    if len(set(out)) != n:
        raise NektarError(f"{mesh.path}: face {face_id}: its edges do not form a closed loop")
    return out


def element_topology(mesh: NektarMesh, element_id, shape, face_ids, face_vertex_cache) -> ElementTopology:
    """face_vertex_cache: {face id: face_vertices}, shared by the elements of one mesh."""
    what = f"{mesh.path}: {NAMES[shape]} {element_id}"
    own_vertices = []
    for f in face_ids:
        if f not in face_vertex_cache:
            face_vertex_cache[f] = face_vertices(mesh, f)
        own_vertices.append(face_vertex_cache[f])
    vertex_sets = [set(v) for v in own_vertices]
    local = []
    for k, (a, b, c) in enumerate(VERTEX_FACES[shape]):
        common = vertex_sets[a] & vertex_sets[b] & vertex_sets[c]
        if len(common) != 1:
            raise NektarError(f"{what}: faces {face_ids[a]}, {face_ids[b]}, {face_ids[c]} share {len(common)} "
                              f"vertices, not exactly one (local vertex {k}); the face list does not describe "
                              f"a {NAMES[shape]}")
        local.append(common.pop())
    if len(set(local)) != len(local):
        raise NektarError(f"{what}: two local vertices coincide; the face list does not describe a {NAMES[shape]}")
    for k, local_face in enumerate(FACES[shape]):
        if vertex_sets[k] != {local[i] for i in local_face}:
            raise NektarError(f"{what}: face {face_ids[k]} does not have the vertices of local face {k}")
    edge_of = {}
    for f in face_ids:
        for e in mesh.faces[f][1]:
            edge_of[frozenset(mesh.edges[e])] = e
    edges = []
    for a, b in EDGES[shape]:
        e = edge_of.get(frozenset((local[a], local[b])))
        if e is None:
            raise NektarError(f"{what}: no edge joins local vertices {a} and {b}")
        edges.append((e, mesh.edges[e][0] == local[a]))
    return ElementTopology(local, edges, list(zip(face_ids, own_vertices)))
