"""A Nektar++ mesh file as read: its entities, the DOMAIN's elements and the curves."""
from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path

from .curves import read_curves
from .domain import domain_elements
from .entities import edge_entries, element_entries, face_entries, read_edges, read_elements, read_faces, read_vertices
from .errors import NektarError
from .xmlfile import file_budget, parse_xml


@dataclass
class NektarMesh:
    path: Path
    vertices: dict  # id -> (3,) coordinates
    edges: dict  # id -> (vertex id, vertex id)
    faces: dict  # id -> (tag 'T'/'Q', edge ids)
    elements: list  # (id, shape, face ids) of the DOMAIN's elements, in ID order
    curved_edges: dict = field(default_factory=dict)  # edge id -> (points type, (n, 3) points)
    curved_faces: dict = field(default_factory=dict)  # face id -> (points type, (N, 3) points)


def read_mesh(path: Path) -> NektarMesh:
    root = parse_xml(path, "mesh file")
    geometry = _geometry_section(root, path)
    sections = {}
    for name in ("VERTEX", "EDGE", "FACE", "ELEMENT"):
        sections[name] = geometry.find(name)
        if sections[name] is None:
            raise NektarError(f"{path}: GEOMETRY has no <{name}> section")
    budget = file_budget(path)
    # top down: each section holds at most what the one above it can refer to (entities.py)
    element_items = element_entries(sections["ELEMENT"], path, budget)
    face_items = face_entries(sections["FACE"], path, budget, sum(len(f) for _, _, f in element_items))
    edge_items = edge_entries(sections["EDGE"], path, budget, sum(len(e) for _, _, e in face_items))
    vertices, scale, move = read_vertices(sections["VERTEX"], path, budget, 2 * len(edge_items))
    edges = read_edges(edge_items, path, vertices)
    faces = read_faces(face_items, path, edges)
    elements = read_elements(element_items, path, faces)
    if not elements:
        raise NektarError(f"{path}: the mesh has no elements")
    ids = domain_elements(geometry, path, elements)
    curved_edges, curved_faces = read_curves(geometry, path, edges, faces, scale, move, budget)
    return NektarMesh(path, vertices, edges, faces, [(i, *elements[i]) for i in ids], curved_edges, curved_faces)


def _geometry_section(root, path):
    geometry = root.find("GEOMETRY")
    if geometry is None:
        raise NektarError(f"{path}: no <GEOMETRY> section (a mesh file is needed)")
    if geometry.attrib.get("DIM", "3").strip() != "3" or geometry.attrib.get("SPACE", "3").strip() != "3":
        raise NektarError(f"{path}: GEOMETRY DIM={geometry.attrib.get('DIM')} SPACE={geometry.attrib.get('SPACE')}; "
                          "only 3-D meshes")
    if geometry.find("VERTEX") is None and (geometry.attrib.get("HDF5FILE") or any(c.tag == "HDF5" for c in geometry)):
        raise NektarError(f"{path}: the geometry is in an HDF5 .nekg file, which is not supported; "
                          "convert with NekMesh in.nekg out.xml")
    return geometry
