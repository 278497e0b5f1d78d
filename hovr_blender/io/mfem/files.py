"""MFEM's mesh (.mesh) and GridFunction (.gf) files, as MFEM 4.10 writes them and GLVis reads
them (docs/spec/formats.md §7): the mesh as written (no reordering, no orientation fixes:
GLVis's `Mesh(file, 1, 0, false)`), a GridFunction's values in the DOF numbering of its space
on that mesh (io/mfem/dofs.py).

Mesh: `MFEM mesh v1.0` (serial), `v1.2` (a parallel rank's piece or a mesh-part; the sections
after the vertices or nodes are skipped to `mfem_mesh_end`), `v1.3` (with attribute sets, which
are skipped) and `MFEM NC mesh v1.0` without refinement (the nonconforming frame a
variable-order space needs). `dimension 3`; `elements`: `attr geom v0 v1 ...` (geom 4 tet,
5 hex, 6 prism, 7 pyramid); `boundary` (read for the vertices it uses only); `vertices`: the
count, then either the space dimension and the coordinates, or `nodes` and a GridFunction of
the coordinates (a curved mesh). Vertices no element or boundary element uses are dropped, in
order, as MFEM's reader drops them.

GridFunction: `FiniteElementSpace`, `FiniteElementCollection: NAME`, `VDim: n`,
`Ordering: 0|1` (by nodes, by vector dimension), then the values.
"""
from __future__ import annotations

import re
from dataclasses import dataclass

import numpy as np

from ...engine import limits
from . import elements as el
from .text import MFEMError, Text, shown

# first lines of MFEM files this reader does not read, and what they are
OTHER_MESHES = {
    "MFEM NC mesh v1.1": "an anisotropically refined nonconforming mesh",
    "MFEM mesh v1.1": "a legacy nonconforming mesh",
    "MFEM NURBS mesh v1.0": "a NURBS mesh", "MFEM NURBS mesh v1.1": "a NURBS mesh",
    "MFEM NURBS NC-patch mesh v1.0": "a NURBS mesh", "MFEM INLINE mesh v1.0": "an inline mesh description",
}
MESHES = ("MFEM mesh v1.0", "MFEM mesh v1.2", "MFEM mesh v1.3", "MFEM NC mesh v1.0")
MAX_VDIM = 16
HEADER_BYTES = 4096  # a GridFunction's header lies in its first few lines
LEGACY = {"Linear": 1, "Quadratic": 2}  # fixed-order collections whose nodes are H1's (checked against MFEM)
_COLLECTION = re.compile(r"(?P<kind>H1|L2|L2Int|H1Pos|H1Ser)(?:@(?P<char>[A-Za-z]))?(?:_T(?P<btype>\d+))?"
                         r"_(?P<dim>\d)D_P(?P<order>\d+)(?:_Pyr(?P<pyr>\d))?")


@dataclass(frozen=True)
class Collection:
    """A finite element collection MFEM names: H1 or L2, its order, basis type and pyramid type."""

    name: str
    kind: str  # "H1" or "L2"
    order: int
    btype: int
    pyramid: int


def parse_collection(name: str) -> Collection:
    """The Collection of MFEM's name for it (FiniteElementCollection::Name); SpaceError for one
    this reader does not read."""
    if name in LEGACY:  # MFEM's fixed-order collections: H1 nodes at equispaced points
        return Collection(name, "H1", LEGACY[name], 4, el.FUENTES)
    m = _COLLECTION.fullmatch(name)
    if m is None:
        kind = name.split("_")[0]
        what = {"ND": "a Nedelec (H(curl)) space", "RT": "a Raviart-Thomas (H(div)) space", "NURBS": "a NURBS space"}
        raise el.SpaceError(f"collection {name!r}: {what.get(kind, 'not an H1 or L2 collection')}; "
                            "H1 and L2 fields are read")
    kind = m.group("kind")
    if kind in ("H1Pos", "H1Ser", "L2Int"):
        what = {"H1Pos": "a Bernstein (positive) basis", "H1Ser": "a serendipity basis",
                "L2Int": "integral (density) values"}[kind]
        raise el.SpaceError(f"collection {name!r}: {what} is not read; H1 and L2 nodal fields are")
    if m.group("dim") != "3":
        raise el.SpaceError(f"collection {name!r}: a {m.group('dim')}-D space; only 3-D fields have a volume")
    if kind == "H1":
        if m.group("btype") is not None:
            raise el.SpaceError(f"collection {name!r}: not a name MFEM gives an H1 collection")
        btype = el.BASIS_CHARS.get(m.group("char") or "G", -1)
        if btype not in el.CLOSED:
            raise el.SpaceError(f"collection {name!r}: basis {m.group('char')!r} is not a closed nodal basis read here")
    else:
        if m.group("char") is not None:
            raise el.SpaceError(f"collection {name!r}: not a name MFEM gives an L2 collection")
        btype = int(m.group("btype")) if m.group("btype") is not None else 0
        if btype not in el.NODAL:
            raise el.SpaceError(f"collection {name!r}: basis type {btype} "
                                f"({el.BASIS_TYPES.get(btype, 'unknown')}) is not a nodal basis read here")
    order = int(m.group("order")) if len(m.group("order")) <= 3 else 10 ** 3
    if (kind == "H1" and order < 1) or order > el.MAX_ORDER:
        raise el.SpaceError(f"collection {name!r}: order {order}; {1 if kind == 'H1' else 0}..{el.MAX_ORDER} "
                            "can be rendered")
    pyramid = int(m.group("pyr")) if m.group("pyr") is not None else el.FUENTES
    if pyramid not in (el.BERGOT, el.FUENTES):
        raise el.SpaceError(f"collection {name!r}: pyramid type {pyramid} is neither Bergot (0) nor Fuentes (1)")
    return Collection(name, kind, order, btype, pyramid)


@dataclass
class GridFunction:
    collection: Collection
    vdim: int
    ordering: int  # 0: by nodes (x of every node, then y, ...), 1: by vector dimension
    values: np.ndarray  # (ndofs * vdim,)
    line: int  # the line of its header, for messages


@dataclass
class MFEMMesh:
    path: str
    version: str
    geoms: np.ndarray  # (NE,) MFEM geometry of each element
    offsets: np.ndarray  # (NE + 1,) into connectivity
    connectivity: np.ndarray  # the elements' vertices, renumbered after unused ones were dropped
    num_vertices: int
    coordinates: np.ndarray | None  # (num_vertices, 3); None for a curved mesh
    nodes: GridFunction | None

    @property
    def num_elements(self) -> int:
        return int(self.geoms.size)

    def groups(self):
        """{geom: (element indices, (n, vertices) array)}, each geometry's elements in order."""
        out = {}
        for geom in np.unique(self.geoms):
            idx = np.flatnonzero(self.geoms == geom)
            nv = el.NUM_VERTICES[int(geom)]
            cols = self.offsets[idx][:, None] + np.arange(nv)[None, :]
            out[int(geom)] = (idx, self.connectivity[cols])
        return out


# ----------------------------------------------------------------------------- GridFunctions

def read_gridfunction(path, header_only: bool = False) -> GridFunction:
    """A .gf file: one GridFunction (its values to the end of the file); header_only: its first
    HEADER_BYTES only, the values left empty (the import dialog's field list)."""
    text = Text(path, "MFEM GridFunction", HEADER_BYTES if header_only else None)
    gf = _gridfunction(text, header_only)
    if header_only:
        return gf
    if not text.at_end():
        raise text.error(f"GridFunction values: {shown(text.word())} is not a number")
    return gf


def _gridfunction(text: Text, header_only: bool = False, what: str = "GridFunction values") -> GridFunction:
    text.skip_comments()
    start = text.pos
    first = text.line().decode("ascii", "replace").strip()
    if first == "MFEM FiniteElementSpace v1.0":
        raise text.error("a FiniteElementSpace v1.0 header (NURBS or variable-order spaces MFEM itself cannot "
                         "read back); save the field raised to one order (GridFunction::ProlongateToMaxOrder)", start)
    if first != "FiniteElementSpace":
        raise text.error(f"not an MFEM GridFunction: expected 'FiniteElementSpace', found {shown(first)}", start)
    text.keyword("FiniteElementCollection:")
    line = text.pos
    name = text.line().decode("ascii", "replace").strip()
    try:
        collection = parse_collection(name)
    except el.SpaceError as exc:
        raise text.error(str(exc), line) from None
    text.keyword("VDim:")
    vdim = text.integer("VDim", 1, MAX_VDIM)
    text.keyword("Ordering:")
    ordering = text.integer("Ordering", 0, 1)
    text.skip_comments()
    values = np.zeros(0) if header_only else text.numbers(np.float64, what)
    return GridFunction(collection, vdim, ordering, values, text.line_number(start))


# ----------------------------------------------------------------------------- meshes

def read_mesh(path) -> MFEMMesh:
    text = Text(path, "MFEM mesh")
    text.skip_space()
    first = text.line().decode("ascii", "replace").strip()
    if first in OTHER_MESHES:
        raise text.error(f"{first!r} is {OTHER_MESHES[first]}, which is not read (readable: "
                         f"{', '.join(MESHES)} without refinement)", 0)
    if first not in MESHES:
        raise text.error(f"not an MFEM mesh (its first line is {shown(first)}; readable: {', '.join(MESHES)})", 0)
    if first.startswith("MFEM NC"):
        return _nc_mesh(text, first)
    text.keyword("dimension")
    _dimension(text)
    text.keyword("elements")
    geoms, offsets, conn = _elements(text, "elements", (4, 5, 6, 7), nc=False)
    if first == "MFEM mesh v1.3":
        text.keyword("attribute_sets")
        _attribute_sets(text)
    text.keyword("boundary")
    _, _, bconn = _elements(text, "boundary", (2, 3), nc=False)
    if first == "MFEM mesh v1.3":
        text.keyword("bdr_attribute_sets")
        _attribute_sets(text)
    text.keyword("vertices")
    count = text.integer("vertex count", 1, max(1, len(text.data)))
    used = np.zeros(count, dtype=bool)
    for what, c in (("the element", conn), ("the boundary", bconn)):
        if c.size and (c.min() < 0 or c.max() >= count):
            raise text.error(f"{what} list names vertex {int(c.max() if c.max() >= count else c.min()):,}, "
                             f"outside the {count:,} vertices")
        used[c] = True
    text.skip_comments()
    start = text.pos
    token = text.word()
    coordinates, nodes = None, None
    if token == b"nodes":
        nodes = _gridfunction(text, what="nodes")
    else:
        text.pos = start
        sdim = text.integer("space dimension", 1, 3)
        if sdim != 3:
            raise text.error(f"space dimension {sdim}: a 3-D mesh needs 3 coordinates a vertex", start)
        xyz = text.numbers(np.float64, "vertex coordinates")
        if xyz.size != 3 * count:
            raise text.error(f"{xyz.size:,} coordinates for {count:,} vertices (3 each)", start)
        coordinates = xyz.reshape(count, 3)
    _mesh_end(text, first)
    # MFEM's reader drops vertices that no element or boundary element names (keeping the order)
    renumber = np.cumsum(used) - 1
    if coordinates is not None:
        coordinates = coordinates[used]
    return MFEMMesh(text.path, first, geoms, offsets, renumber[conn], int(used.sum()), coordinates, nodes)


def _dimension(text: Text):
    start = text.pos
    dim = text.integer("dimension", 1, 3)
    if dim != 3:
        raise text.error(f"a {dim}-D mesh; only 3-D meshes have a volume to render", start)


def _elements(text: Text, what: str, allowed, nc: bool):
    """(geoms, offsets, connectivity) of an element list: `attr geom v...` each (NC meshes:
    `rank attr geom ref_type v...`); an element naming a vertex twice is refused."""
    start = text.pos
    one = "element" if what == "elements" else "boundary element"
    count = text.integer(f"{one} count", 0 if what == "boundary" else 1, max(1, len(text.data) // 8))
    flat = text.numbers(np.int64, what)
    head = 4 if nc else 2  # the numbers before the vertices
    geoms, offsets = np.empty(count, np.int64), np.empty(count + 1, np.int64)
    keep = np.zeros(flat.size, dtype=bool)
    gcol = 2 if nc else 1  # the column of the geometry
    # the common case, all one geometry, at once; else element by element
    if count and flat.size >= head and int(flat[gcol]) in allowed:
        g0 = int(flat[gcol])
        stride = head + el.NUM_VERTICES[g0]
        if flat.size == count * stride:
            table = flat.reshape(count, stride)
            if np.all(table[:, gcol] == g0) and (not nc or not np.any(table[:, 3])):
                geoms[:] = g0
                offsets[:] = np.arange(count + 1) * (stride - head)
                return _distinct(text, start, one, geoms, offsets, table[:, head:].ravel())
    pos = 0
    off = 0
    for e in range(count):
        limits.progress()
        if pos + head > flat.size:
            raise text.error(f"{what}: {count:,} declared, the list ends after {e:,}", start)
        geom = int(flat[pos + gcol])
        if nc and geom < 0:
            raise text.error(f"{one} {e}: an unused element slot (a derefined mesh); not read", start)
        if geom not in allowed:
            raise text.error(f"{one} {e}: geometry {geom} ({el.NAMES.get(geom, 'unknown')}) is not one of "
                             f"{', '.join(f'{g} {el.NAMES[g]}' for g in allowed)}", start)
        if nc and flat[pos + 3] != 0:
            raise _refined(text, start, e)
        nv = el.NUM_VERTICES[geom]
        geoms[e], offsets[e] = geom, off
        if pos + head + nv > flat.size:
            raise text.error(f"{one} {e}: the list ends inside it ({count:,} declared)", start)
        keep[pos + head:pos + head + nv] = True
        pos += head + nv
        off += nv
    if pos != flat.size:
        raise text.error(f"{what}: {flat.size - pos:,} numbers after the {count:,} declared", start)
    offsets[count] = off
    return _distinct(text, start, one, geoms, offsets, flat[keep])


def _distinct(text: Text, start: int, one: str, geoms, offsets, conn):
    for geom in np.unique(geoms):
        idx = np.flatnonzero(geoms == geom)
        rows = np.sort(conn[offsets[idx][:, None] + np.arange(el.NUM_VERTICES[int(geom)])[None, :]], axis=1)
        twice = np.any(rows[:, 1:] == rows[:, :-1], axis=1)
        if twice.any():
            raise text.error(f"{one} {int(idx[np.argmax(twice)])} names a vertex twice", start)
    return geoms, offsets, conn


def _refined(text: Text, start: int, element: int) -> MFEMError:
    return text.error(f"element {element} is refined: nonconforming meshes with refinement (hanging nodes) are not "
                      "read; unrefined ones (EnsureNCMesh, a variable-order space's mesh) are", start)


def _attribute_sets(text: Text):
    """Skips an ArraysByName section: a count, then per set a (quoted) name, a size, its entries."""
    count = text.integer("attribute set count", 0, len(text.data))
    for _ in range(count):
        text.skip_space()
        if text.data[text.pos:text.pos + 1] == b'"':
            m = re.compile(rb'"(?:[^"\\]|\\.)*"').match(text.data, text.pos)
            if m is None:
                raise text.error("an attribute set's name: an unterminated quoted string")
            text.pos = m.end()
        else:
            text.word()
        size = text.integer("attribute set size", 0, len(text.data))
        for _ in range(size):
            text.integer("attribute", -2 ** 31, 2 ** 31)


def _mesh_end(text: Text, version: str):
    """What follows the vertices or nodes: v1.0 nothing it reads; v1.2 and v1.3 lines up to
    `mfem_mesh_end` (a parallel piece's sections among them); NC meshes `mfem_mesh_end`."""
    if version == "MFEM mesh v1.0":
        return
    if version == "MFEM NC mesh v1.0":
        text.keyword("mfem_mesh_end")
        return
    m = re.compile(rb"^[ \t]*mfem_mesh_end[ \t\r]*$", re.M).search(text.data, text.pos)
    if m is None:
        raise text.error(f"{version}: no 'mfem_mesh_end' line after the vertices")


def _nc_mesh(text: Text, version: str) -> MFEMMesh:
    text.keyword("dimension")
    _dimension(text)
    word = text.keyword("rank", "sfc_version", "elements")
    if word == "rank":
        text.integer("rank", 0, 2 ** 31)
        word = text.keyword("sfc_version", "elements")
    if word == "sfc_version":
        text.integer("sfc_version", 0, 0)
        text.keyword("elements")
    geoms, offsets, conn = _elements(text, "elements", (4, 5, 6, 7), nc=True)
    word = text.keyword("boundary", "vertex_parents", "root_state", "coordinates", "nodes")
    if word == "boundary":
        _elements(text, "boundary", (1, 2, 3), nc=False)
        word = text.keyword("vertex_parents", "root_state", "coordinates", "nodes")
    if word == "vertex_parents":
        raise text.error("vertex_parents: a refined nonconforming mesh (hanging nodes); not read")
    if word == "root_state":
        count = text.integer("root_state count", 0, len(geoms))
        for _ in range(count):
            text.integer("root state", 0, 2 ** 31)
        word = text.keyword("coordinates", "nodes")
    if conn.size and conn.min() < 0:
        raise text.error(f"an element names node {int(conn.min())}")
    # the Mesh's vertices: the elements' nodes in the order of their ids (NCMesh::UpdateVertices)
    ids, renumbered = np.unique(conn, return_inverse=True)
    coordinates, nodes = None, None
    if word == "coordinates":
        start = text.pos
        count = text.integer("coordinate count", 0, max(1, len(text.data)))
        if ids.size and ids[-1] >= count:
            raise text.error(f"node {int(ids[-1]):,} has no coordinates (the section holds {count:,})", start)
        sdim = text.integer("space dimension", 3, 3)
        xyz = text.numbers(np.float64, "coordinates")
        if xyz.size != sdim * count:
            raise text.error(f"{xyz.size:,} coordinates for {count:,} nodes (3 each)", start)
        coordinates = xyz.reshape(count, 3)[ids]
    else:
        nodes = _gridfunction(text, what="nodes")
    _mesh_end(text, version)
    return MFEMMesh(text.path, version, geoms, offsets, renumbered.reshape(-1), int(ids.size), coordinates, nodes)
