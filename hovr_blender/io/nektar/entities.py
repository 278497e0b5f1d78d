"""The entities of a mesh's <GEOMETRY>: vertices, edges, faces and elements, plain or B64Z
records (docs/spec/formats.md §2.2, §2.3), each checked to refer only to entities that exist.

Read from the top down (mesh.read_mesh): the elements, then at most the faces they can refer
to, the edges those faces can, the vertices those edges can; so a section padded with millions
of unused entries is refused before it is inflated or parsed, not after."""
from __future__ import annotations

import numpy as np

from ...engine.shapes import HEX, NAMES, PRISM, PYR, TET
from .errors import NektarError
from .xmlfile import check_count, endianness, entity_id, parse_floats, parse_ints, parse_number, records

ELEMENT_TAGS = {"H": HEX, "R": PRISM, "A": TET, "P": PYR}
# the tag of each face in an element's entry (docs/spec/formats.md §2.2)
FACE_KINDS = {HEX: "QQQQQQ", PRISM: "QTQTQ", TET: "TTTT", PYR: "QTTTT"}
# Jacobians are cubes of lengths: beyond this, double precision overflows while checking them.
MAX_COORDINATE = 1e100


def check_coordinates(x, path, what):
    """x, the (3,) or (n, 3) coordinates of `what`, unless one is beyond MAX_COORDINATE."""
    ok = np.all(np.abs(np.reshape(x, (-1, 3))) <= MAX_COORDINATE, axis=1)  # NaN, from an overflow, too
    if not ok.all():
        raise NektarError(f"{path}: {what}: coordinates {np.reshape(x, (-1, 3))[~ok][0].tolist()} are too large "
                          f"for double precision (|x| up to {MAX_COORDINATE:g} is supported)")
    return x


def read_vertices(section, path, budget, max_count=None):
    """({id: (3,) coordinates}, scale, move): the VERTEX section's XSCALE.. and XMOVE.. apply to
    the vertices here and to curve points in curves.py. At most max_count vertices (what the
    edges can use) are read."""
    scale = np.array([parse_number(section.attrib.get(k, "1"), path, f"VERTEX {k}")
                      for k in ("XSCALE", "YSCALE", "ZSCALE")])
    move = np.array([parse_number(section.attrib.get(k, "0"), path, f"VERTEX {k}")
                     for k in ("XMOVE", "YMOVE", "ZMOVE")])
    endian = endianness(section, path, "VERTEX")
    vertices = {}
    if endian:
        rec = records(section, path, "VERTEX", [("id", "i8", None), ("x", "f8", (3,))], endian, budget, max_count,
                      "edges")
        if not np.all(np.isfinite(rec["x"])):
            bad = int(rec["id"][np.argwhere(~np.isfinite(rec["x"]))[0][0]])
            raise NektarError(f"{path}: vertex {bad}: coordinates are not finite")
        xyz = rec["x"] * scale + move
        for i, x in zip(rec["id"].tolist(), xyz):
            if i in vertices:
                raise NektarError(f"{path}: vertex {i} is defined twice")
            vertices[i] = check_coordinates(x, path, f"vertex {i}")
    else:
        check_count(len(section), max_count, path, "VERTEX", "edges")
        for node in section:
            i = entity_id(node, path, "VERTEX")
            if node.tag != "V":
                raise NektarError(f"{path}: unexpected <{node.tag} ID={i}> in VERTEX")
            if i in vertices:
                raise NektarError(f"{path}: vertex {i} is defined twice")
            vertices[i] = check_coordinates(parse_floats(node.text, 3, path, f"vertex {i}") * scale + move,
                                            path, f"vertex {i}")
    if not vertices:
        raise NektarError(f"{path}: VERTEX section is empty")
    return vertices, scale, move


def edge_entries(section, path, budget, max_count=None) -> list:
    """[(id, (vertex id, vertex id))] of the EDGE section, at most max_count (what the faces can use)."""
    endian = endianness(section, path, "EDGE")
    if endian:
        rec = records(section, path, "EDGE", [("id", "i8", None), ("v", "i8", (2,))], endian, budget, max_count,
                      "faces")
        return list(zip(rec["id"].tolist(), rec["v"].tolist()))
    check_count(len(section), max_count, path, "EDGE", "faces")
    items = []
    for node in section:
        i = entity_id(node, path, "EDGE")
        if node.tag != "E":
            raise NektarError(f"{path}: unexpected <{node.tag} ID={i}> in EDGE")
        items.append((i, parse_ints(node.text, 2, path, f"edge {i}")))
    return items


def read_edges(items, path, vertices):
    """{id: (vertex id, vertex id)} of edge_entries, each vertex one that exists."""
    edges = {}
    for i, (a, b) in items:
        if i in edges:
            raise NektarError(f"{path}: edge {i} is defined twice")
        for v in (a, b):
            if v not in vertices:
                raise NektarError(f"{path}: edge {i} refers to missing vertex {v}")
        if a == b:
            raise NektarError(f"{path}: edge {i} joins vertex {a} to itself")
        edges[i] = (a, b)
    return edges


def face_entries(section, path, budget, max_count=None) -> list:
    """[(tag 'T' or 'Q', id, edge ids)] of the FACE section, at most max_count (what the elements can use)."""
    items = []
    plain = sum(1 for node in section if endianness(node, path, f"FACE {node.tag}") is None)
    check_count(plain, max_count, path, "FACE", "elements")
    for node in section:
        if node.tag not in ("T", "Q"):
            raise NektarError(f"{path}: unexpected <{node.tag}> in FACE")
        num_edges = 3 if node.tag == "T" else 4
        endian = endianness(node, path, f"FACE {node.tag}")
        if endian:
            left = None if max_count is None else max_count - len(items)
            rec = records(node, path, f"FACE {node.tag}", [("id", "i8", None), ("e", "i8", (num_edges,))], endian,
                          budget, left, "elements")
            items.extend((node.tag, i, tuple(e)) for i, e in zip(rec["id"].tolist(), rec["e"].tolist()))
        else:
            i = entity_id(node, path, "FACE")
            items.append((node.tag, i, tuple(parse_ints(node.text, num_edges, path, f"face {node.tag} {i}"))))
        check_count(len(items), max_count, path, "FACE", "elements")
    return items


def read_faces(items, path, edges):
    """{id: (tag 'T' or 'Q', edge ids)} of face_entries, each edge one that exists."""
    faces = {}
    for tag, i, edge_ids in items:
        if i in faces:
            raise NektarError(f"{path}: face {i} is defined twice")
        for e in edge_ids:
            if e not in edges:
                raise NektarError(f"{path}: face {i} refers to missing edge {e}")
        faces[i] = (tag, edge_ids)
    return faces


def element_entries(section, path, budget) -> list:
    """[(shape, id, face ids)] of the ELEMENT section (each within the file's inflation budget)."""
    items = []
    for node in section:
        if node.tag not in ELEMENT_TAGS:
            raise NektarError(f"{path}: <{node.tag}> in ELEMENT is not a 3-D element (A, P, R, H)")
        shape = ELEMENT_TAGS[node.tag]
        num_faces = len(FACE_KINDS[shape])
        endian = endianness(node, path, f"ELEMENT {node.tag}")
        if endian:
            rec = records(node, path, f"ELEMENT {node.tag}", [("id", "i8", None), ("f", "i8", (num_faces,))], endian,
                          budget)
            items.extend((shape, i, tuple(f)) for i, f in zip(rec["id"].tolist(), rec["f"].tolist()))
        else:
            i = entity_id(node, path, "ELEMENT")
            items.append((shape, i, tuple(parse_ints(node.text, num_faces, path, f"{NAMES[shape]} {i}"))))
    return items


def read_elements(items, path, faces):
    """{id: (shape, face ids)} of element_entries, each face of the kind its position in the entry needs."""
    elements = {}
    for shape, i, face_ids in items:
        if i in elements:
            raise NektarError(f"{path}: element {i} is defined twice")
        for k, f in enumerate(face_ids):
            if f not in faces:
                raise NektarError(f"{path}: {NAMES[shape]} {i} refers to missing face {f}")
            if faces[f][0] != FACE_KINDS[shape][k]:
                want = "quadrilateral" if FACE_KINDS[shape][k] == "Q" else "triangle"
                raise NektarError(f"{path}: {NAMES[shape]} {i}: face {f} (position {k}) must be a {want}")
        elements[i] = (shape, face_ids)
    return elements
