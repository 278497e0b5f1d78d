"""Nektar++ importer: mesh XML (plain or B64Z-compressed, curved edges and faces, all four 3-D
shapes) and field files (.fld/.chk/.rst in XML or HDF5, multi-part .fld/ directories).

Everything follows ../shared/spec/formats.md §2 (cited as §2.x). The result is a VolumeMesh
whose field and geometry are both modal expansions of Nektar++'s MODIFIED family in Nektar++'s
storage order (core/expansions.py):
- field: Modified bases are copied as stored (local coefficients, §2.6); GLL_Lagrange hexes are
  converted to the same polynomial in Modified_A; any other basis is refused by name;
- geometry (§2.12): vertex modes = vertex coordinates; each curved edge's modes are fitted to
  Nektar++'s edge curve (interpolant of the points with the end points moved onto the
  vertices); each face with F points adds its bubble (the interior-mode part of the face
  interpolant); interior modes stay zero. For hexes this is the Gordon-Hall blend of §2.12.

Untrusted input (core/limits.py is the policy): only regular files are opened; the mesh is
read first and every size a field file declares is checked against it before anything is
inflated or allocated; zlib output is bounded; HDF5 objects are followed through hard links
only and their data must lie in the file itself. Every failure is a NektarError naming the file
and the record or element.
"""
from __future__ import annotations

import base64
import binascii
import re
import xml.etree.ElementTree as ET
from dataclasses import dataclass, field as dc_field
from functools import lru_cache
from pathlib import Path

import numpy as np

from ..core import limits
from ..core.expansions import gll_points
from ..core.shapes import EDGES, FACES, HEX, MAX_MODES, NAMES, PRISM, PYR, TET, VERTICES
from ..core.mesh import MeshError, VolumeMesh


class NektarError(ValueError):
    """A Nektar++ file this reader cannot use; the message names the file and the record."""


ELEMENT_TAGS = {"H": HEX, "R": PRISM, "A": TET, "P": PYR}
FLD_SHAPES = {"Hexahedron": HEX, "Prism": PRISM, "Tetrahedron": TET, "Pyramid": PYR}
# (tag of each face in the element entry) §2.2
FACE_KINDS = {HEX: "QQQQQQ", PRISM: "QTQTQ", TET: "TTTT", PYR: "QTTTT"}
# local vertex i = the mesh vertex common to these three faces (positions in the entry) §2.11
VERTEX_FACES = {
    HEX: ((0, 1, 4), (0, 1, 2), (0, 2, 3), (0, 3, 4), (1, 4, 5), (1, 2, 5), (2, 3, 5), (3, 4, 5)),
    PRISM: ((0, 1, 4), (0, 1, 2), (0, 2, 3), (0, 3, 4), (1, 2, 4), (2, 3, 4)),
    TET: ((0, 1, 3), (0, 1, 2), (0, 2, 3), (1, 2, 3)),
    PYR: ((0, 1, 4), (0, 1, 2), (0, 2, 3), (0, 3, 4), (1, 2, 4)),
}
# The Modified basis each shape must carry in a field file (§2.5); GLL_Lagrange only for hexes.
MODIFIED_BASES = {
    HEX: ("Modified_A",) * 3,
    PRISM: ("Modified_A", "Modified_A", "Modified_B"),
    TET: ("Modified_A", "Modified_B", "Modified_C"),
    PYR: ("Modified_A", "Modified_A", "ModifiedPyr_C"),
}
# BasisType enum order (§2.6), used by HDF5 files
BASIS_ENUM = ("NoBasisType", "Ortho_A", "Ortho_B", "Ortho_C", "Modified_A", "Modified_B", "Modified_C",
              "OrthoPyr_C", "ModifiedPyr_C", "Fourier", "GLL_Lagrange", "Gauss_Lagrange", "Legendre",
              "Chebyshev", "Monomial", "FourierSingleMode", "FourierHalfModeRe", "FourierHalfModeIm")
# PointsType enum order (§2.3)
POINTS_ENUM = ("NoPointsType", "GaussGaussLegendre", "GaussRadauMLegendre", "GaussRadauPLegendre",
               "GaussLobattoLegendre", "GaussGaussChebyshev", "GaussRadauMChebyshev", "GaussRadauPChebyshev",
               "GaussLobattoChebyshev", "GaussRadauMAlpha0Beta1", "GaussRadauMAlpha0Beta2",
               "GaussRadauMAlpha1Beta0", "GaussRadauMAlpha2Beta0", "GaussKronrodLegendre",
               "GaussRadauKronrodMLegendre", "GaussRadauKronrodMAlpha1Beta0", "GaussLobattoKronrodLegendre",
               "PolyEvenlySpaced", "FourierEvenlySpaced", "FourierSingleModeSpaced", "BoundaryLayerPoints",
               "BoundaryLayerPointsRev", "NodalTriElec", "NodalTriFekete", "NodalTriEvenlySpaced",
               "NodalTetEvenlySpaced", "NodalTetElec", "NodalPrismEvenlySpaced", "NodalPrismElec", "NodalTriSPI",
               "NodalTetSPI", "NodalPrismSPI", "NodalQuadElec", "NodalHexElec", "GaussLegendreWithMP",
               "GaussLegendreWithM")
NO_FIELD = "(none)"

_FORBIDDEN = (b"<!doctype", b"<!entity")
# The renderer's limit on modes per direction also bounds curve points (one mode per point).
MAX_CURVE_POINTS = MAX_MODES
# Mesh sections have no declared size; real ones deflate by < 20x, a zlib bomb by ~1000x.
MESH_INFLATE_RATIO = 200
# Entries of one attribute of an HDF5 field definition (FIELDS, BASIS, ...): real ones hold a few.
MAX_ATTRIBUTE_VALUES = 4096
# Jacobians are cubes of lengths: beyond this, double precision overflows while checking them.
MAX_COORDINATE = 1e100
_HDF5_MAGIC = b"\x89HDF\r\n\x1a\n"


# ----------------------------------------------------------------------------- low level

def _parse_xml(path: Path, what: str) -> ET.Element:
    try:
        raw = limits.read_regular(path, what)
    except OSError as exc:
        raise NektarError(f"{path}: cannot read ({exc.strerror or exc})") from exc
    low = raw.lower()
    # DTDs can define entities (exponential expansion, external files): no Nektar++ file has one.
    for pat in _FORBIDDEN:
        for enc in ("ascii", "utf-16-le", "utf-16-be"):
            if pat.decode().encode(enc) in low:
                raise NektarError(f"{path}: DOCTYPE/ENTITY declarations are refused")
    try:
        root = ET.fromstring(raw)
    except ET.ParseError as exc:
        raise NektarError(f"{path}: not well-formed XML ({exc})") from exc
    if root.tag != "NEKTAR":
        raise NektarError(f"{path}: root element is <{root.tag}>, expected <NEKTAR>")
    return root


def _int(text, path, what):
    try:
        return int(str(text).strip())
    except (TypeError, ValueError):
        raise NektarError(f"{path}: {what}: {text!r} is not an integer") from None


def _ints(text, n, path, what):
    try:
        vals = [int(v) for v in (text or "").split()]
    except ValueError:
        raise NektarError(f"{path}: {what}: expected {n} integers, got {text!r}") from None
    if len(vals) != n:
        raise NektarError(f"{path}: {what}: expected {n} integers, got {len(vals)}")
    return vals


def _floats(text, n, path, what):
    toks = (text or "").split()
    if len(toks) != n:
        raise NektarError(f"{path}: {what}: expected {n} numbers, got {len(toks)}")
    try:
        v = np.array(toks, dtype=np.float64)
    except ValueError:
        raise NektarError(f"{path}: {what}: not all numbers (expressions are not supported)") from None
    if not np.all(np.isfinite(v)):
        raise NektarError(f"{path}: {what}: coordinates are not finite")
    return v


def _entity_id(node, path, what):
    try:
        return int(node.attrib["ID"])
    except (KeyError, ValueError):
        raise NektarError(f"{path}: {what} <{node.tag}> without a valid integer ID") from None


def _number(text, path, what):
    try:
        v = float(text)
    except (TypeError, ValueError):
        raise NektarError(f"{path}: {what}: {text!r} is not a number (expressions are not supported)") from None
    if not np.isfinite(v):
        raise NektarError(f"{path}: {what}: {text!r} is not finite")
    return v


def _endianness(node, path, what, default=None):
    comp = node.attrib.get("COMPRESSED", default)
    if comp is None:
        return None
    if comp not in ("B64Z-LittleEndian", "B64Z-BigEndian"):
        raise NektarError(f"{path}: {what}: COMPRESSED={comp!r}; only B64Z-LittleEndian/BigEndian are known")
    bits = node.attrib.get("BITSIZE", "64").strip()
    if bits != "64":
        raise NektarError(f"{path}: {what}: BITSIZE={bits!r}; only 64-bit data is known")
    return "<" if comp.endswith("LittleEndian") else ">"


def _inflate(text, path, what, max_bytes):
    """Bytes of a B64Z block (§2.3): base64 without '=' padding, zlib, NUL padding after the stream."""
    s = re.sub(r"\s+", "", text or "")
    if not s:
        raise NektarError(f"{path}: {what}: empty data")
    try:
        packed = base64.b64decode(s + "=" * (-len(s) % 4), validate=True)
    except (binascii.Error, ValueError) as exc:
        raise NektarError(f"{path}: {what}: data is not valid base64 ({exc})") from exc
    try:
        raw, rest = limits.inflate(packed, max_bytes, f"{path}: {what}")
    except ValueError as exc:
        raise NektarError(str(exc)) from exc
    if rest.strip(b"\0"):  # NUL padding to a multiple of 3 is normal, anything else is not
        raise NektarError(f"{path}: {what}: {len(rest)} unexpected bytes after the zlib stream")
    return raw


def _records(node, path, what, fields, endian):
    """Structured array of the fixed-size records of a compressed mesh block (§2.3 table)."""
    text = node.text or ""
    # the ratio bounds a bomb; the memory limit caps the bound so that a low limit refuses only
    # sections that really inflate beyond it
    bound = min(MESH_INFLATE_RATIO * len(text) + 4096, limits.current().max_memory)
    raw = _inflate(text, path, what, bound)
    dt = np.dtype([(name, endian + kind, shape) if shape else (name, endian + kind) for name, kind, shape in fields])
    if len(raw) % dt.itemsize:
        raise NektarError(f"{path}: {what}: {len(raw)} bytes is not a whole number of {dt.itemsize}-byte records")
    return np.frombuffer(raw, dtype=dt)


# ----------------------------------------------------------------------------- 1-D / 2-D point sets

def _points_1d(ptype: str, n: int, path, what) -> np.ndarray:
    """Positions on [-1, 1] of n points of a Nektar++ 1-D points type (§2.3)."""
    if n < 2 and ptype != "GaussGaussLegendre":
        raise NektarError(f"{path}: {what}: {n} {ptype} points; at least 2 are needed")
    z = _points_1d_cached(ptype, n)
    if z is None:
        raise NektarError(f"{path}: {what}: points type {ptype!r} is not supported")
    return z


@lru_cache(maxsize=None)
def _points_1d_cached(ptype: str, n: int):
    from numpy.polynomial import legendre as L

    if ptype == "GaussLobattoLegendre":
        return gll_points(n)
    if ptype == "PolyEvenlySpaced":
        return np.linspace(-1.0, 1.0, n)
    if ptype == "GaussGaussLegendre":
        return np.sort(L.leggauss(n)[0])
    if ptype == "GaussLobattoChebyshev":
        return -np.cos(np.pi * np.arange(n) / (n - 1))
    if ptype == "GaussGaussChebyshev":
        return -np.cos(np.pi * (2 * np.arange(n) + 1) / (2 * n))
    if ptype in ("GaussRadauMLegendre", "GaussRadauPLegendre"):
        # -1 and the roots of (P_{n-1} + P_n) / (1 + x); the P variant is its mirror image
        c = np.zeros(n + 1)
        c[n - 1] = c[n] = 1.0
        r = np.sort(np.real(L.legroots(c)))
        r[0] = -1.0
        return r if ptype.endswith("MLegendre") else np.sort(-r)
    return None


def _tri_evenly(n: int) -> np.ndarray:
    """NodalTriEvenlySpaced points in Nektar++'s order: vertices, edge 0, 1, 2, interior (§2.11)."""
    pts = {}
    for i in range(n):  # rows in y
        for j in range(n - i):
            pts[(i, j)] = (-1.0 + 2.0 * j / (n - 1), -1.0 + 2.0 * i / (n - 1))
    verts = [(0, 0), (0, n - 1), (n - 1, 0)]
    e0 = [(0, j) for j in range(1, n - 1)]
    e1 = [(i, n - 1 - i) for i in range(1, n - 1)]
    e2 = [(i, 0) for i in range(n - 2, 0, -1)]
    interior = [(i, j) for i in range(1, n) for j in range(1, n - i) if i + j != n - 1]
    return np.array([pts[k] for k in verts + e0 + e1 + e2 + interior])


def _lagrange_matrix(nodes, x):
    """(len(x), len(nodes)) values of the Lagrange interpolants through nodes at x."""
    nodes = np.asarray(nodes, float)
    x = np.asarray(x, float)
    n = len(nodes)
    out = np.ones((len(x), n))
    for k in range(n):
        for m in range(n):
            if m != k:
                out[:, k] *= (x - nodes[m]) / (nodes[k] - nodes[m])
    return out


# ----------------------------------------------------------------------------- mesh

@dataclass
class _Mesh:
    path: Path
    verts: dict  # id -> (3,) coordinates
    edges: dict  # id -> (v0, v1)
    faces: dict  # id -> (tag 'T'/'Q', edge ids)
    elements: list  # (id, shape, face ids) in ID order
    curved_edges: dict = dc_field(default_factory=dict)  # edge id -> (ptype, (n, 3) points)
    curved_faces: dict = dc_field(default_factory=dict)  # face id -> (ptype, (N, 3) points)


def _geometry(root, path):
    geom = root.find("GEOMETRY")
    if geom is None:
        raise NektarError(f"{path}: no <GEOMETRY> section (a mesh file is needed)")
    if geom.attrib.get("DIM", "3").strip() != "3" or geom.attrib.get("SPACE", "3").strip() != "3":
        raise NektarError(f"{path}: GEOMETRY DIM={geom.attrib.get('DIM')} SPACE={geom.attrib.get('SPACE')}; only 3-D meshes")
    if geom.find("VERTEX") is None and (geom.attrib.get("HDF5FILE") or any(c.tag == "HDF5" for c in geom)):
        raise NektarError(f"{path}: the geometry is in an HDF5 .nekg file, which is not supported; "
                          "convert with NekMesh in.nekg out.xml")
    return geom


def _read_vertices(sec, path):
    scale = np.array([_number(sec.attrib.get(k, "1"), path, f"VERTEX {k}") for k in ("XSCALE", "YSCALE", "ZSCALE")])
    move = np.array([_number(sec.attrib.get(k, "0"), path, f"VERTEX {k}") for k in ("XMOVE", "YMOVE", "ZMOVE")])
    endian = _endianness(sec, path, "VERTEX")
    verts = {}
    if endian:
        rec = _records(sec, path, "VERTEX", [("id", "i8", None), ("x", "f8", (3,))], endian)
        if not np.all(np.isfinite(rec["x"])):
            bad = int(rec["id"][np.argwhere(~np.isfinite(rec["x"]))[0][0]])
            raise NektarError(f"{path}: vertex {bad}: coordinates are not finite")
        xyz = rec["x"] * scale + move
        for i, x in zip(rec["id"].tolist(), xyz):
            if i in verts:
                raise NektarError(f"{path}: vertex {i} is defined twice")
            verts[i] = _coordinates(x, path, f"vertex {i}")
    else:
        for v in sec:
            i = _entity_id(v, path, "VERTEX")
            if v.tag != "V":
                raise NektarError(f"{path}: unexpected <{v.tag} ID={i}> in VERTEX")
            if i in verts:
                raise NektarError(f"{path}: vertex {i} is defined twice")
            verts[i] = _coordinates(_floats(v.text, 3, path, f"vertex {i}") * scale + move, path, f"vertex {i}")
    if not verts:
        raise NektarError(f"{path}: VERTEX section is empty")
    return verts, scale, move


def _coordinates(x, path, what):
    """x, the (3,) or (n, 3) coordinates of `what`, unless one is beyond MAX_COORDINATE."""
    ok = np.all(np.abs(np.reshape(x, (-1, 3))) <= MAX_COORDINATE, axis=1)  # NaN, from an overflow, too
    if not ok.all():
        raise NektarError(f"{path}: {what}: coordinates {np.reshape(x, (-1, 3))[~ok][0].tolist()} are too large "
                          f"for double precision (|x| up to {MAX_COORDINATE:g} is supported)")
    return x


def _read_edges(sec, path, verts):
    endian = _endianness(sec, path, "EDGE")
    edges = {}
    if endian:
        rec = _records(sec, path, "EDGE", [("id", "i8", None), ("v", "i8", (2,))], endian)
        items = zip(rec["id"].tolist(), rec["v"].tolist())
    else:
        items = []
        for e in sec:
            i = _entity_id(e, path, "EDGE")
            if e.tag != "E":
                raise NektarError(f"{path}: unexpected <{e.tag} ID={i}> in EDGE")
            items.append((i, _ints(e.text, 2, path, f"edge {i}")))
    for i, (a, b) in items:
        if i in edges:
            raise NektarError(f"{path}: edge {i} is defined twice")
        for v in (a, b):
            if v not in verts:
                raise NektarError(f"{path}: edge {i} refers to missing vertex {v}")
        if a == b:
            raise NektarError(f"{path}: edge {i} joins vertex {a} to itself")
        edges[i] = (a, b)
    return edges


def _read_faces(sec, path, edges):
    faces = {}
    for node in sec:
        if node.tag not in ("T", "Q"):
            raise NektarError(f"{path}: unexpected <{node.tag}> in FACE")
        n = 3 if node.tag == "T" else 4
        endian = _endianness(node, path, f"FACE {node.tag}")
        if endian:
            rec = _records(node, path, f"FACE {node.tag}", [("id", "i8", None), ("e", "i8", (n,))], endian)
            items = zip(rec["id"].tolist(), rec["e"].tolist())
        else:
            i = _entity_id(node, path, "FACE")
            items = [(i, _ints(node.text, n, path, f"face {node.tag} {i}"))]
        for i, eids in items:
            if i in faces:
                raise NektarError(f"{path}: face {i} is defined twice")
            for e in eids:
                if e not in edges:
                    raise NektarError(f"{path}: face {i} refers to missing edge {e}")
            faces[i] = (node.tag, tuple(eids))
    return faces


def _read_elements(sec, path, faces):
    elements = {}
    for node in sec:
        if node.tag not in ELEMENT_TAGS:
            raise NektarError(f"{path}: <{node.tag}> in ELEMENT is not a 3-D element (A, P, R, H)")
        shape = ELEMENT_TAGS[node.tag]
        nf = len(FACE_KINDS[shape])
        endian = _endianness(node, path, f"ELEMENT {node.tag}")
        if endian:
            rec = _records(node, path, f"ELEMENT {node.tag}", [("id", "i8", None), ("f", "i8", (nf,))], endian)
            items = zip(rec["id"].tolist(), rec["f"].tolist())
        else:
            i = _entity_id(node, path, "ELEMENT")
            items = [(i, _ints(node.text, nf, path, f"{NAMES[shape]} {i}"))]
        for i, fids in items:
            if i in elements:
                raise NektarError(f"{path}: element {i} is defined twice")
            for k, f in enumerate(fids):
                if f not in faces:
                    raise NektarError(f"{path}: {NAMES[shape]} {i} refers to missing face {f}")
                if faces[f][0] != FACE_KINDS[shape][k]:
                    want = "quadrilateral" if FACE_KINDS[shape][k] == "Q" else "triangle"
                    raise NektarError(f"{path}: {NAMES[shape]} {i}: face {f} (position {k}) must be a {want}")
            elements[i] = (shape, tuple(fids))
    return elements


def _read_curved(geom, path, mesh: _Mesh, scale, move):
    curved = geom.find("CURVED")
    if curved is None or not len(curved):
        return
    endian = _endianness(curved, path, "CURVED")
    entries = []  # (kind 'E'/'F', curve id, entity id, npoints, ptype name, points or None)
    if endian:
        # point pool: DATAPOINTS/INDEX and /POINTS (§2.3)
        dps = curved.findall("DATAPOINTS")
        if len(dps) > 1:
            raise NektarError(f"{path}: CURVED has {len(dps)} DATAPOINTS blocks; one is expected")
        index = pts = None
        if dps:
            ix, pn = dps[0].find("INDEX"), dps[0].find("POINTS")
            if ix is None or pn is None:
                raise NektarError(f"{path}: CURVED/DATAPOINTS lacks INDEX or POINTS")
            index = _records(ix, path, "CURVED INDEX", [("i", "i8", None)], endian)["i"]
            pts = _records(pn, path, "CURVED POINTS", [("id", "i8", None), ("x", "f8", (3,))], endian)["x"]
            if not np.all(np.isfinite(pts)):
                raise NektarError(f"{path}: CURVED POINTS: coordinates are not finite")
            pts = pts * scale + move  # the compressed reader scales every curve point (§2.2)
        for node in curved:
            if node.tag not in ("E", "F"):
                continue
            rec = _records(node, path, f"CURVED {node.tag}",
                           [(k, "i8", None) for k in ("id", "entity", "npoints", "ptid", "offset", "ptype")], endian)
            for r in rec:
                cid, ent, npts, off, pt = (int(r[k]) for k in ("id", "entity", "npoints", "offset", "ptype"))
                what = f"curved {'edge' if node.tag == 'E' else 'face'} record {cid} ({'EDGEID' if node.tag == 'E' else 'FACEID'} {ent})"
                if not 0 <= pt < len(POINTS_ENUM):
                    raise NektarError(f"{path}: {what}: unknown points type {pt}")
                _check_npoints(npts, node.tag, path, what)
                if index is None:
                    raise NektarError(f"{path}: {what}: CURVED has no DATAPOINTS")
                if off < 0 or off + npts > len(index):
                    raise NektarError(f"{path}: {what}: points {off}..{off + npts - 1} lie outside INDEX ({len(index)} entries)")
                ix_ = index[off : off + npts]
                if np.any(ix_ < 0) or np.any(ix_ >= len(pts)):
                    raise NektarError(f"{path}: {what}: INDEX refers to a point outside POINTS ({len(pts)} points)")
                entries.append((node.tag, cid, ent, npts, POINTS_ENUM[pt], pts[ix_]))
    else:
        for node in curved:
            if node.tag not in ("E", "F"):
                continue
            cid = _entity_id(node, path, "CURVED")
            key = "EDGEID" if node.tag == "E" else "FACEID"
            what = f"curved {'edge' if node.tag == 'E' else 'face'} {cid} ({key} {node.attrib.get(key)})"
            ent = _int(node.attrib.get(key), path, f"{what}: {key}")
            npts = _int(node.attrib.get("NUMPOINTS"), path, f"{what}: NUMPOINTS")
            _check_npoints(npts, node.tag, path, what)
            ptype = node.attrib.get("TYPE", "").strip()
            if ptype not in POINTS_ENUM:
                raise NektarError(f"{path}: {what}: unknown points TYPE {ptype!r}")
            xyz = _floats(node.text, 3 * npts, path, what).reshape(npts, 3)
            if node.tag == "E":  # the uncompressed reader scales edge points only (§2.2)
                xyz = xyz * scale + move
            entries.append((node.tag, cid, ent, npts, ptype, xyz))
    for tag, cid, ent, npts, ptype, xyz in entries:
        what = f"curved {'edge' if tag == 'E' else 'face'} {cid}"
        _coordinates(xyz, path, what)
        if tag == "E":
            if ent not in mesh.edges:
                raise NektarError(f"{path}: {what} refers to missing edge {ent}")
            if ent in mesh.curved_edges:
                raise NektarError(f"{path}: edge {ent} is curved twice")
            mesh.curved_edges[ent] = (ptype, xyz)
        else:
            if ent not in mesh.faces:
                raise NektarError(f"{path}: {what} refers to missing face {ent}")
            if ent in mesh.curved_faces:
                raise NektarError(f"{path}: face {ent} is curved twice")
            mesh.curved_faces[ent] = (ptype, xyz)


def _check_npoints(npts, tag, path, what):
    cap = MAX_CURVE_POINTS if tag == "E" else MAX_CURVE_POINTS**2
    if not 1 <= npts <= cap:
        raise NektarError(f"{path}: {what}: NUMPOINTS={npts}; 1..{cap} are supported")


def _parse_ranges(text, path, what):
    """List of (a, b) inclusive ranges of a Nektar++ ID list '0-7,12' (no expansion: sizes untrusted)."""
    out = []
    for tok in (text or "").replace(" ", "").replace("\t", "").replace("\n", "").split(","):
        m = re.fullmatch(r"(\d+)(?:-(\d+))?", tok)
        if not m:
            raise NektarError(f"{path}: {what}: bad ID list {text!r}")
        a = int(m.group(1))
        b = int(m.group(2)) if m.group(2) else a
        if b < a:
            raise NektarError(f"{path}: {what}: bad ID range {tok!r}")
        if b >= 1 << 62:
            raise NektarError(f"{path}: {what}: ID {b} is out of range")
        out.append((a, b))
    return out


def _range_count(ranges):
    return sum(b - a + 1 for a, b in ranges)


def _expand_ranges(ranges):
    return np.concatenate([np.arange(a, b + 1, dtype=np.int64) for a, b in ranges]) if ranges else np.zeros(0, np.int64)


def _select(ids, ranges):
    """(positions in the sorted array `ids` of the IDs any range holds, (lo, hi) position bounds
    of each range, and whether each range's IDs all exist). Work is bounded by the number of
    ranges plus len(ids), never by the ranges' declared sizes."""
    r = np.array(ranges, dtype=np.int64).reshape(-1, 2)
    lo = np.searchsorted(ids, r[:, 0], "left")
    hi = np.searchsorted(ids, r[:, 1], "right")
    complete = hi - lo - 1 == r[:, 1] - r[:, 0]
    depth = np.zeros(len(ids) + 1, np.int64)  # how many ranges cover each position
    np.add.at(depth, lo, 1)
    np.add.at(depth, hi, -1)
    return np.flatnonzero(np.cumsum(depth[:-1]) > 0), lo, hi, complete


def _first_missing(ids, a, lo, hi):
    """The first ID from a on that `ids` (sorted) lacks, given ids[lo:hi] are those in the range."""
    run = ids[lo:hi] - a - np.arange(hi - lo)
    gap = np.flatnonzero(run)
    return int(a + (gap[0] if len(gap) else hi - lo))


def _domain_elements(geom, path, elements):
    """Element IDs of the DOMAIN (all elements when there is no DOMAIN) (§2.2). Each composite is
    read once, however often it is named."""
    dom = geom.find("DOMAIN")
    if dom is None:
        return sorted(elements)
    texts = [dom.text or ""] + [d.text or "" for d in dom if d.tag == "D"]
    ranges = []
    for t in texts:
        for m in re.finditer(r"C\s*\[([^\]]*)\]", t):
            ranges.extend(_parse_ranges(m.group(1), path, "DOMAIN"))
    if not ranges:
        raise NektarError(f"{path}: DOMAIN names no composite")
    comps = {}
    sec = geom.find("COMPOSITE")
    for c in (sec if sec is not None else []):
        comps[_entity_id(c, path, "COMPOSITE")] = c.text or ""
    comp_ids = np.array(sorted(comps), dtype=np.int64)
    pos, lo, hi, complete = _select(comp_ids, ranges)
    if not complete.all():
        i = int(np.argmin(complete))
        raise NektarError(f"{path}: DOMAIN refers to missing composite C[{_first_missing(comp_ids, ranges[i][0], lo[i], hi[i])}]")
    elem_ids = np.array(sorted(elements), dtype=np.int64)
    elem_shapes = np.array([elements[e][0] for e in elem_ids.tolist()], dtype=np.int64)
    # count[s][k]: elements of shape s among the first k, to check a range's shapes without expanding it
    count = np.concatenate([np.zeros((4, 1), np.int64), np.cumsum(elem_shapes == np.arange(4)[:, None], axis=1)], axis=1)
    ranges, owners = [], []  # element ranges, and (composite, letter) of each
    for cid in comp_ids[pos].tolist():
        for m in re.finditer(r"([A-Z])\s*\[([^\]]*)\]", comps[cid]):
            letter = m.group(1)
            if letter not in ELEMENT_TAGS:
                raise NektarError(f"{path}: composite C[{cid}] in the DOMAIN holds {letter}[...], not 3-D elements")
            rs = _parse_ranges(m.group(2), path, f"composite C[{cid}]")
            ranges.extend(rs)
            owners.extend([(cid, letter)] * len(rs))
    if not ranges:
        raise NektarError(f"{path}: the DOMAIN holds no elements")
    pos, lo, hi, complete = _select(elem_ids, ranges)
    shapes = np.array([ELEMENT_TAGS[letter] for _, letter in owners])
    same_shape = count[shapes, hi] - count[shapes, lo] == hi - lo
    bad = np.flatnonzero(~(complete & same_shape))
    if len(bad):
        i = int(bad[0])
        cid, letter = owners[i]
        if not complete[i]:
            e = _first_missing(elem_ids, ranges[i][0], lo[i], hi[i])
            raise NektarError(f"{path}: composite C[{cid}] refers to missing element {e}")
        k = lo[i] + int(np.argmax(elem_shapes[lo[i] : hi[i]] != shapes[i]))
        raise NektarError(f"{path}: composite C[{cid}] lists {letter}[{elem_ids[k]}] but element {elem_ids[k]} is a "
                          f"{NAMES[int(elem_shapes[k])]}")
    return elem_ids[pos].tolist()


def _read_mesh(path: Path) -> _Mesh:
    root = _parse_xml(path, "mesh file")
    geom = _geometry(root, path)
    secs = {}
    for name in ("VERTEX", "EDGE", "FACE", "ELEMENT"):
        secs[name] = geom.find(name)
        if secs[name] is None:
            raise NektarError(f"{path}: GEOMETRY has no <{name}> section")
    verts, scale, move = _read_vertices(secs["VERTEX"], path)
    edges = _read_edges(secs["EDGE"], path, verts)
    faces = _read_faces(secs["FACE"], path, edges)
    elements = _read_elements(secs["ELEMENT"], path, faces)
    if not elements:
        raise NektarError(f"{path}: the mesh has no elements")
    ids = _domain_elements(geom, path, elements)
    mesh = _Mesh(path, verts, edges, faces, [(i, *elements[i]) for i in ids])
    _read_curved(geom, path, mesh, scale, move)
    return mesh


# ----------------------------------------------------------------------------- element topology

def _face_vertices(mesh: _Mesh, fid):
    """The face's own vertex order (§2.11): vertex j = end of edge j not shared with edge j+1."""
    _, eids = mesh.faces[fid]
    out = []
    n = len(eids)
    for j in range(n):
        a, b = mesh.edges[eids[j]]
        c, d = mesh.edges[eids[(j + 1) % n]]
        if b in (c, d) and a not in (c, d):
            out.append(a)
        elif a in (c, d) and b not in (c, d):
            out.append(b)
        else:
            raise NektarError(f"{mesh.path}: face {fid}: edges {eids[j]} and {eids[(j + 1) % n]} do not meet in one vertex")
    if len(set(out)) != n:
        raise NektarError(f"{mesh.path}: face {fid}: its edges do not form a closed loop")
    return out


@dataclass
class _Topo:
    verts: list  # mesh vertex IDs in local order
    edges: list  # (mesh edge id, forward: mesh v0 is the local edge's first vertex)
    faces: list  # (mesh face id, face vertex IDs in the face's own order)


def _topology(mesh: _Mesh, eid, shape, fids, fverts_cache) -> _Topo:
    what = f"{mesh.path}: {NAMES[shape]} {eid}"
    fv = []
    for f in fids:
        if f not in fverts_cache:
            fverts_cache[f] = _face_vertices(mesh, f)
        fv.append(fverts_cache[f])
    fsets = [set(v) for v in fv]
    local = []
    for k, (a, b, c) in enumerate(VERTEX_FACES[shape]):
        common = fsets[a] & fsets[b] & fsets[c]
        if len(common) != 1:
            raise NektarError(f"{what}: faces {fids[a]}, {fids[b]}, {fids[c]} share {len(common)} vertices, "
                              f"not exactly one (local vertex {k}); the face list does not describe a {NAMES[shape]}")
        local.append(common.pop())
    if len(set(local)) != len(local):
        raise NektarError(f"{what}: two local vertices coincide; the face list does not describe a {NAMES[shape]}")
    for k, lv in enumerate(FACES[shape]):
        if fsets[k] != {local[i] for i in lv}:
            raise NektarError(f"{what}: face {fids[k]} does not have the vertices of local face {k}")
    edge_of = {}
    for f in fids:
        for e in mesh.faces[f][1]:
            edge_of[frozenset(mesh.edges[e])] = e
    edges = []
    for a, b in EDGES[shape]:
        e = edge_of.get(frozenset((local[a], local[b])))
        if e is None:
            raise NektarError(f"{what}: no edge joins local vertices {a} and {b}")
        edges.append((e, mesh.edges[e][0] == local[a]))
    return _Topo(local, edges, list(zip(fids, fv)))


# ----------------------------------------------------------------------------- geometry

class _Space:
    """Mode classification and fit matrices of one (shape, P) geometry space."""

    def __init__(self, shape, P):
        from ..core import expansions as ex

        self.ex, self.shape, self.P = ex, shape, P
        self.modes = np.array([P, P, P])
        self.K = ex.num_coeffs(shape, self.modes)
        self.triples = [tuple(t) for t in np.asarray(ex.mode_triples(shape, self.modes)).tolist()]
        ref = VERTICES[shape]
        phi_v = self.phi(ref)
        on_vertex = np.abs(phi_v).max(axis=0) > 1e-9
        self.vidx = np.argmax(np.abs(phi_v), axis=1)  # the mode of each vertex
        if on_vertex.sum() != len(ref) or len(set(self.vidx.tolist())) != len(ref):
            raise RuntimeError(f"{NAMES[shape]}: vertex modes are not one per vertex")
        self.phi_vv_inv = np.linalg.inv(phi_v[:, self.vidx])
        # edges: P + 1 GLL samples (one more than the modes, so the fit is overdetermined)
        self.s = _space_samples(P)
        t = np.linspace(-0.9, 0.9, 7)
        on_edge = []
        for a, b in EDGES[shape]:
            on_edge.append(np.abs(self.phi(self._seg(ref[a], ref[b], t))).max(axis=0) > 1e-9)
        on_edge = np.array(on_edge) & ~on_vertex
        self.eidx = [np.flatnonzero(r) for r in on_edge]
        self.edge_fit = []
        for (a, b), idx in zip(EDGES[shape], self.eidx):
            ph = self.phi(self._seg(ref[a], ref[b], self.s))
            self.edge_fit.append((np.linalg.pinv(ph[:, idx]) if len(idx) else None, ph[:, self.vidx]))
        on_face = []
        for fv in FACES[shape]:
            on_face.append(np.abs(self.phi(self._face_points(ref[list(fv)]))).max(axis=0) > 1e-9)
        self.on_face_any = np.array(on_face)  # every mode with a trace on face k
        on_face = self.on_face_any & ~on_vertex & ~on_edge.any(axis=0)
        self.fidx = [np.flatnonzero(r) for r in on_face]
        if np.any(on_edge.sum(axis=0) > 1) or np.any(on_face.sum(axis=0) > 1):
            raise RuntimeError(f"{NAMES[shape]}: an edge or face mode lies on two edges or faces")
        self._face_fit = {}

    def phi(self, xi):
        return self.ex.eval_modal(self.shape, self.modes, np.eye(self.K), np.asarray(xi, float))

    @staticmethod
    def _seg(a, b, s):
        s = np.asarray(s)[:, None]
        return a * (1 - s) / 2 + b * (1 + s) / 2

    @staticmethod
    def _face_points(corners):
        g = np.linspace(0.1, 0.9, 5)
        if len(corners) == 4:
            u, v = np.meshgrid(g, g)
            u, v = u.ravel()[:, None], v.ravel()[:, None]
            return (corners[0] * (1 - u) * (1 - v) + corners[1] * u * (1 - v) + corners[2] * u * v + corners[3] * (1 - u) * v)
        u, v = np.meshgrid(g, g)
        keep = (u + v) < 0.95
        u, v = u[keep][:, None], v[keep][:, None]
        return corners[0] * (1 - u - v) + corners[1] * u + corners[2] * v

    def face_bubble_fit(self, k, xi_pts, n):
        """Pseudo-inverse fitting F points at xi_pts with the modes of degree < n traced on face k;
        the caller keeps the face-interior part. Cached by the point positions."""
        key = (k, n, np.round(xi_pts, 12).tobytes())
        if key not in self._face_fit:
            small = {tuple(t) for t in np.asarray(self.ex.mode_triples(self.shape, (n, n, n))).tolist()}
            cols = np.array([i for i in np.flatnonzero(self.on_face_any[k]) if self.triples[i] in small])
            A = self.phi(xi_pts)[:, cols]
            if np.linalg.matrix_rank(A) < len(cols):
                self._face_fit[key] = None
            else:
                keep = np.isin(cols, self.fidx[k])
                self._face_fit[key] = (cols[keep], np.linalg.pinv(A)[keep])
        return self._face_fit[key]


@lru_cache(maxsize=None)
def _space(shape, P) -> _Space:
    return _Space(shape, P)


def _edge_curve(mesh: _Mesh, e, P, fwd, path):
    """Nektar++'s curved edge (§2.12 step 1) at the P-space edge samples, read from the local
    edge's first vertex (fwd: the mesh edge's v0) to its second."""
    ptype, pts = mesh.curved_edges[e]
    z = _points_1d(ptype, len(pts), path, f"curved edge {e}")
    M = _curve_matrix(ptype, len(pts), P, fwd, z.tobytes())
    x0, x1 = (mesh.verts[v] for v in mesh.edges[e])
    return M[0] @ pts + M[1] * x0 + M[2] * x1


@lru_cache(maxsize=None)
def _curve_matrix(ptype, n, P, fwd, zbytes):
    """(L, w0, w1): curve samples = L @ points + w0 x0 + w1 x1. Overwriting the vertex modes
    moves the interpolant's ends onto the vertices linearly."""
    z = np.frombuffer(zbytes)
    s = _space_samples(P) * (1 if fwd else -1)
    L = _lagrange_matrix(z, np.concatenate([s, [-1.0, 1.0]]))
    w0, w1 = ((1 - s) / 2)[:, None], ((1 + s) / 2)[:, None]
    return L[:-2] - w0 * L[-2] - w1 * L[-1], w0, w1


def _space_samples(P):
    return gll_points(max(P + 1, 3))  # one more than the modes: the edge fit is overdetermined


def _face_param_points(mesh: _Mesh, fid, path, warnings):
    """(param points, kind) of a curved face's F points in the face's own frame, or None when
    the interior positions are unknown (then only the edges shape the face)."""
    tag = mesh.faces[fid][0]
    ptype, pts = mesh.curved_faces[fid]
    what = f"curved face {fid}"
    if tag == "Q":
        n = int(round(np.sqrt(len(pts))))
        if n * n != len(pts):
            raise NektarError(f"{path}: {what}: {len(pts)} points is not n*n for a quadrilateral")
        z = _points_1d(ptype, n, path, what)
        a, b = np.meshgrid(z, z)  # first index (fastest) along face axis 0
        return np.stack([a.ravel(), b.ravel()], axis=1), n
    n = int(round((np.sqrt(8 * len(pts) + 1) - 1) / 2))
    if ptype == "NodalTriEvenlySpaced" and n * (n + 1) // 2 == len(pts) and n >= 2:
        return _tri_evenly(n), n
    if n * (n + 1) // 2 == len(pts) and n <= 3:  # vertices and edge points only: nothing interior
        return None, n
    warnings.append(f"{path}: curved triangle face {fid} ({ptype}, {len(pts)} points): interior point "
                    "positions of this type are not reproduced; the face follows its edge curves only")
    return None, n


def _face_xi(space: _Space, topo: _Topo, k, fverts, uv, tag):
    """Element reference coordinates of face-frame points uv on local face k."""
    ref = VERTICES[space.shape]
    pos = {v: ref[i] for i, v in enumerate(topo.verts)}
    c = np.array([pos[v] for v in fverts])
    a, b = uv[:, :1], uv[:, 1:]
    if tag == "Q":
        u, v = (1 + a) / 2, (1 + b) / 2
        return c[0] * (1 - u) * (1 - v) + c[1] * u * (1 - v) + c[2] * u * v + c[3] * (1 - u) * v
    return c[0] * (-(a + b) / 2) + c[1] * (1 + a) / 2 + c[2] * (1 + b) / 2


def _element_order(mesh: _Mesh, topo: _Topo):
    P = 2
    for e, _ in topo.edges:
        if e in mesh.curved_edges:
            P = max(P, len(mesh.curved_edges[e][1]))
    for f, _ in topo.faces:
        if f in mesh.curved_faces:
            npts = len(mesh.curved_faces[f][1])
            n = int(round(np.sqrt(npts))) if mesh.faces[f][0] == "Q" else int(round((np.sqrt(8 * npts + 1) - 1) / 2))
            P = max(P, n)
    return P


def _element_geometry(mesh: _Mesh, eid, shape, topo: _Topo, P, warnings, edge_cache):
    sp = _space(shape, P)
    path = mesh.path
    c = np.zeros((sp.K, 3))
    X = np.array([mesh.verts[v] for v in topo.verts])
    c[sp.vidx] = sp.phi_vv_inv @ X
    cv = c[sp.vidx]
    for k, (e, fwd) in enumerate(topo.edges):
        if e not in mesh.curved_edges or not len(sp.eidx[k]):
            continue
        key = (e, fwd, P)
        if key not in edge_cache:
            edge_cache[key] = _edge_curve(mesh, e, P, fwd, path)
        pinv, phv = sp.edge_fit[k]
        c[sp.eidx[k]] = pinv @ (edge_cache[key] - phv @ cv)
    for k, (f, fverts) in enumerate(topo.faces):
        if f not in mesh.curved_faces:
            continue
        uv, n = _face_param_points(mesh, f, path, warnings)
        if uv is None:
            continue
        tag = mesh.faces[f][0]
        xi = _face_xi(sp, topo, k, fverts, uv, tag)
        fit = sp.face_bubble_fit(k, xi, n)
        if fit is None:
            raise NektarError(f"{path}: curved face {f}: its points do not determine a surface")
        cols, rows = fit
        c[cols] = rows @ mesh.curved_faces[f][1]
    return c


def _straight_coeffs(shape, X):
    """(N, K, 3) two-mode geometry of straight elements: vertex modes = vertex coordinates."""
    sp = _space(shape, 2)
    c = np.zeros((X.shape[0], sp.K, 3))
    c[:, sp.vidx] = np.einsum("vw,nwj->nvj", sp.phi_vv_inv, X)
    return c


def _check_jacobians(path, shape, P, ids, coeffs):
    """NektarError for the first inverted or degenerate element (det dx/dxi <= 0 somewhere sampled)."""
    from ..core import expansions as ex

    if not len(ids):
        return
    modes = np.array([P, P, P])
    K = ex.num_coeffs(shape, modes)
    ref = VERTICES[shape]
    centre = ref.mean(axis=0)
    pts = np.concatenate([np.asarray(ex.fit_points(shape, modes), float), centre + 0.98 * (ref - centre)])
    G = np.asarray(ex.eval_modal_grad(shape, modes, np.eye(K), pts))  # (M, K, 3)
    for start in range(0, len(ids), 4096):
        C = coeffs[start : start + 4096]
        J = np.einsum("mkd,nkj->nmjd", G, C)  # dx_j/dxi_d
        det = np.linalg.det(J)
        ext = np.ptp(C[:, _space(shape, P).vidx], axis=1).max(axis=1)  # element size
        tol = 1e-10 * np.maximum(ext, 1e-300) ** 3
        bad = np.flatnonzero(~np.all(det > tol[:, None], axis=1))
        if len(bad):
            i = int(bad[0])
            kind = "inverted (negative Jacobian)" if np.nanmin(det[i]) < -tol[i] else "degenerate (zero Jacobian)"
            raise NektarError(f"{path}: {NAMES[shape]} {ids[start + i]} is {kind}")


# ----------------------------------------------------------------------------- field files

@dataclass
class _Block:
    shape: int
    basis: tuple
    fields: list
    ids: np.ndarray  # (n,) element IDs
    modes: np.ndarray  # (n, 3)
    data: np.ndarray  # all values, field-major
    what: str


def _ncoeffs(shape, modes):
    from ..core import expansions as ex

    uniq, inv = np.unique(np.asarray(modes).reshape(-1, 3), axis=0, return_inverse=True)
    per = np.array([ex.num_coeffs(shape, m) for m in uniq.tolist()], dtype=np.int64)
    return per[inv.ravel()]


def _block_header(path, what, shape_s, basis, fields, nummodes, extra_attrs):
    if "Homogen" in shape_s or "Strips" in shape_s or "HOMOGENEOUSLENGTHS" in extra_attrs:
        raise NektarError(f"{path}: {what}: SHAPE={shape_s!r}: homogeneous (Fourier-extruded) fields are not supported")
    if shape_s not in FLD_SHAPES:
        raise NektarError(f"{path}: {what}: SHAPE={shape_s!r}; only 3-D elements (Hexahedron, Prism, Tetrahedron, Pyramid)")
    shape = FLD_SHAPES[shape_s]
    for key in ("POINTSTYPE", "NUMPOINTSPERDIR"):
        if key in extra_attrs:
            raise NektarError(f"{path}: {what}: {key} (point data rather than coefficients) is not supported")
    basis = tuple(basis)
    if basis != MODIFIED_BASES[shape] and not (shape == HEX and basis == ("GLL_Lagrange",) * 3):
        raise NektarError(f"{path}: {what}: BASIS={','.join(basis)} for {NAMES[shape]}s is not supported; "
                          f"expected {','.join(MODIFIED_BASES[shape])}" + (" or GLL_Lagrange x3" if shape == HEX else ""))
    fields = [f.strip() for f in fields]
    if not fields or any(not f for f in fields) or len(set(fields)) != len(fields):
        raise NektarError(f"{path}: {what}: bad FIELDS list {','.join(fields)!r}")
    m = re.fullmatch(r"\s*(UNIORDER|MIXORDER)\s*:?\s*([\d,\s]*)", nummodes or "")
    if not m:
        raise NektarError(f"{path}: {what}: NUMMODESPERDIR={nummodes!r}; expected UNIORDER:a,b,c or MIXORDER:...")
    return shape, basis, fields, m.group(1), m.group(2)


def _modes_array(path, what, kind, nums, nel):
    try:
        vals = [int(v) for v in nums.replace(" ", "").split(",") if v != ""] if isinstance(nums, str) else list(nums)
    except ValueError:
        raise NektarError(f"{path}: {what}: bad mode counts {nums!r}") from None
    want = 3 if kind == "UNIORDER" else 3 * nel
    if len(vals) != want:
        raise NektarError(f"{path}: {what}: {kind} gives {len(vals)} mode counts, expected {want}")
    modes = np.array(vals, dtype=np.int64).reshape(-1, 3)
    if np.any(modes < 1) or np.any(modes > MAX_MODES):
        raise NektarError(f"{path}: {what}: mode counts {sorted(set(modes.ravel().tolist()))[:6]} outside 1..{MAX_MODES} "
                          "(the renderer's limit)")
    return modes


def _block_ncoeffs(path, what, shape, modes):
    try:
        return _ncoeffs(shape, modes)
    except ValueError as exc:  # e.g. a prism with more modes in direction 0 than in direction 2
        raise NektarError(f"{path}: {what}: mode counts invalid for {NAMES[shape]}s ({exc})") from None


class _Budget:
    """What the mesh lets a field file declare: each field once per mesh element. Claimed from
    the headers before any data is inflated or read, so the data is bounded by elements x
    fields x the coefficients of the declared modes."""

    def __init__(self, n_elements):
        self.n = n_elements
        self.claimed = {}

    def claim(self, path, what, nel, fields):
        if nel > self.n:
            raise NektarError(f"{path}: {what}: declares {nel:,} elements; the mesh has {self.n:,}")
        for f in fields:
            self.claimed[f] = self.claimed.get(f, 0) + nel
            if self.claimed[f] > self.n:
                raise NektarError(f"{path}: {what}: gives field {f!r} for {self.claimed[f]:,} elements in all; "
                                  f"the mesh has {self.n:,}")


def _finish_block(path, what, shape, basis, fields, kind, nums, ids, get_data):
    """Check a block's modes and data against its element IDs (already bounded by _Budget)."""
    nel = len(ids)
    if nel == 0:
        raise NektarError(f"{path}: {what}: no element IDs")
    modes = _modes_array(path, what, kind, nums, nel)
    per = _block_ncoeffs(path, what, shape, modes)
    want = len(fields) * (nel * int(per[0]) if kind == "UNIORDER" else int(per.sum()))
    data = get_data(want)
    if data.size != want:
        raise NektarError(f"{path}: {what}: {data.size} values, expected {want} "
                          f"({len(fields)} fields x {nel} elements, {NAMES[shape]} modes)")
    if len(np.unique(ids)) != nel:
        raise NektarError(f"{path}: {what}: an element ID appears twice")
    if kind == "UNIORDER":
        modes = np.broadcast_to(modes, (nel, 3)).copy()
    return _Block(shape, basis, fields, ids, modes, data, what)


def _xml_blocks(path: Path, root, budget):
    """The ELEMENTS blocks of an XML field file; with budget None their headers only."""
    blocks = []
    for k, b in enumerate(root.iter("ELEMENTS")):
        what = f"ELEMENTS block {k} (ID={b.attrib.get('ID', '?')[:40]})"
        shape, basis, fields, kind, nums = _block_header(
            path, what, b.attrib.get("SHAPE", ""), [s.strip() for s in b.attrib.get("BASIS", "").split(",")],
            b.attrib.get("FIELDS", "").split(","), b.attrib.get("NUMMODESPERDIR", ""), b.attrib)
        endian = _endianness(b, path, what, default="B64Z-LittleEndian") or "<"  # bodies are always B64Z (§2.6)
        if budget is None:
            blocks.append(_Block(shape, basis, fields, None, None, None, what))
            continue
        ranges = _parse_ranges(b.attrib.get("ID"), path, what)
        budget.claim(path, what, _range_count(ranges), fields)

        def get(want, text=b.text or "", what=what, endian=endian):
            raw = _inflate(text, path, what, 8 * want)
            if len(raw) % 8:
                raise NektarError(f"{path}: {what}: {len(raw)} bytes is not a whole number of float64 values")
            return np.frombuffer(raw, dtype=endian + "f8")

        blocks.append(_finish_block(path, what, shape, basis, fields, kind, nums, _expand_ranges(ranges), get))
    if not blocks:
        raise NektarError(f"{path}: no <ELEMENTS> blocks")
    return blocks


def _attr_str(v):
    if isinstance(v, bytes):
        return v.decode("utf-8", "replace")
    if isinstance(v, np.ndarray) and v.shape == ():
        return _attr_str(v.item())
    return str(v)


def _attr_list(v):
    if isinstance(v, (bytes, str)):
        return [s.strip() for s in _attr_str(v).split(",")]
    return [_attr_str(x).strip() for x in np.asarray(v).ravel().tolist()]


def _hdf5_blocks(path: Path, fh, budget):
    try:
        import h5py
    except ImportError:
        raise NektarError(f"{path}: is an HDF5 field file; reading it needs the h5py package (pip install h5py)") from None
    try:
        with h5py.File(fh, "r") as h5:  # the checked descriptor: HDF5 never opens the path itself
            return _hdf5_blocks_open(path, h5, budget)
    except (NektarError, limits.ResourceLimitError, limits.UnsafeFileError):
        raise
    except (OSError, KeyError, ValueError, TypeError, RuntimeError) as exc:
        raise NektarError(f"{path}: unreadable HDF5 field file ({type(exc).__name__}: {exc})") from exc


def _hdf5_dataset(path, grp, name, kinds, required=True):
    """The 1-D dataset /NEKTAR/name (None if absent and not required), reached by a hard link and
    stored in the file; kinds "f": real floating point, "iu": integer."""
    import h5py

    what = f"{path}: /NEKTAR/{name}"
    ds = limits.hdf5_child(grp, name, what)
    if ds is None:
        if required:
            raise NektarError(f"{path}: HDF5 field file lacks /NEKTAR/{name}")
        return None
    if not isinstance(ds, h5py.Dataset) or ds.ndim != 1:
        raise NektarError(f"{what}: not a 1-D dataset")
    if ds.dtype.kind == "c":
        raise NektarError(f"{what}: holds complex values ({ds.dtype}); only real values can be rendered")
    if ds.dtype.kind not in kinds:
        raise NektarError(f"{what}: values of type {ds.dtype}, expected {'real floating point' if kinds == 'f' else 'integers'}")
    return ds


def _hdf5_values(path, ds, name, count):
    """The values of a dataset from _hdf5_dataset, which must hold exactly `count` of them."""
    size = 0 if ds is None else ds.size
    if size != count:
        raise NektarError(f"{path}: DECOMPOSITION accounts for {count:,} values of /NEKTAR/{name}, which holds {size:,}")
    if ds is None:
        return np.zeros(0)
    v = limits.hdf5_read(ds, count, f"{path}: /NEKTAR/{name}")
    if ds.dtype.kind == "i" and np.any(v < 0):
        raise NektarError(f"{path}: /NEKTAR/{name}: negative entries")
    return v


def _hdf5_attr(path, at, key, what):
    if key not in at:
        raise NektarError(f"{path}: {what}: definition lacks the {key} attribute")
    if int(np.prod(at.get_id(key).shape or ())) > MAX_ATTRIBUTE_VALUES:
        raise NektarError(f"{path}: {what}: attribute {key} holds more than {MAX_ATTRIBUTE_VALUES} values")
    return at[key]


def _hdf5_header(path, g, h, what):
    """(shape, basis, fields, kind, nums) of field definition group /NEKTAR/<h> (§2.7)."""
    import h5py

    grp = limits.hdf5_child(g, str(h), f"{path}: /NEKTAR/{h}")
    if not isinstance(grp, h5py.Group):
        raise NektarError(f"{path}: {what}: no field definition group /NEKTAR/{h}")
    at = grp.attrs
    try:
        basis = [BASIS_ENUM[int(b)] for b in np.asarray(_hdf5_attr(path, at, "BASIS", what)).ravel()]
    except (IndexError, ValueError, TypeError):
        raise NektarError(f"{path}: {what}: unknown BASIS attribute") from None
    fields, shape, nummodes = (_hdf5_attr(path, at, k, what) for k in ("FIELDS", "SHAPE", "NUMMODESPERDIR"))
    return _block_header(path, what, _attr_str(shape).strip(), basis, _attr_list(fields), _attr_str(nummodes),
                         set(at.keys()))


def _hdf5_blocks_open(path, h5, budget):
    import h5py

    g = limits.hdf5_child(h5, "NEKTAR", f"{path}: /NEKTAR")
    if not isinstance(g, h5py.Group):
        raise NektarError(f"{path}: HDF5 file without a /NEKTAR group (not a Nektar++ field file)")
    ds = _hdf5_dataset(path, g, "DECOMPOSITION", "iu")
    # the index of the data, read for headers too: bounded by the file (it is far smaller than the data)
    dec = limits.hdf5_read(ds, h5.id.get_filesize() // ds.dtype.itemsize, f"{path}: /NEKTAR/DECOMPOSITION")
    if dec.size % 7:
        raise NektarError(f"{path}: DECOMPOSITION has {dec.size} entries, not a multiple of 7")
    if ds.dtype.kind == "i" and np.any(dec < 0):
        raise NektarError(f"{path}: DECOMPOSITION has negative entries")
    rows = dec.reshape(-1, 7).tolist()
    heads = {}  # definition hash -> header, in the order of first use
    for r, (nel, nd, npoly, ny, nz, ns, h) in enumerate(rows):
        what = f"DECOMPOSITION row {r} (definition {h})"
        if ny or nz or ns:
            raise NektarError(f"{path}: {what}: homogeneous (Fourier-extruded) fields are not supported")
        if h not in heads:
            heads[h] = _hdf5_header(path, g, h, what)
    if not heads:
        raise NektarError(f"{path}: HDF5 field file holds no field definitions")
    if budget is None:
        return [_Block(shape, basis, fields, None, None, None, f"definition {h}")
                for h, (shape, basis, fields, _, _) in heads.items()]
    for r, (nel, nd, npoly, _, _, _, h) in enumerate(rows):
        what = f"DECOMPOSITION row {r} (definition {h})"
        shape, _, fields, kind, nums = heads[h]
        budget.claim(path, what, nel, fields)
        largest = _modes_array(path, what, kind, nums, 1) if kind == "UNIORDER" else [[MAX_MODES] * 3]
        most = len(fields) * nel * int(_block_ncoeffs(path, what, shape, largest)[0])
        if nd > most:
            raise NektarError(f"{path}: {what}: declares {nd:,} values; {len(fields)} fields on {nel:,} "
                              f"{NAMES[shape]}s hold at most {most:,}")
        if npoly > 3 * nel:
            raise NektarError(f"{path}: {what}: {npoly:,} POLYORDERS entries for {nel:,} elements")
    ids_all = _hdf5_values(path, _hdf5_dataset(path, g, "ELEMENTIDS", "iu"), "ELEMENTIDS", sum(r[0] for r in rows))
    data_all = _hdf5_values(path, _hdf5_dataset(path, g, "DATA", "f"), "DATA", sum(r[1] for r in rows))
    poly_all = _hdf5_values(path, _hdf5_dataset(path, g, "POLYORDERS", "iu", required=False), "POLYORDERS",
                            sum(r[2] for r in rows))
    blocks = []
    oi = od = op = 0
    for r, (nel, nd, npoly, _, _, _, h) in enumerate(rows):
        what = f"DECOMPOSITION row {r} (definition {h})"
        shape, basis, fields, kind, nums = heads[h]
        if kind == "MIXORDER":
            if npoly != 3 * nel:
                raise NektarError(f"{path}: {what}: {npoly} POLYORDERS entries for {nel} elements (3 each expected)")
            nums = poly_all[op : op + npoly].astype(np.int64).tolist()
        ids = ids_all[oi : oi + nel].astype(np.int64)
        chunk = data_all[od : od + nd].astype(np.float64)
        blocks.append(_finish_block(path, what, shape, basis, fields, kind, nums, ids, lambda want, c=chunk: c))
        oi, od, op = oi + nel, od + nd, op + npoly
    return blocks


def _file_blocks(path: Path, budget):
    try:
        with limits.open_regular(path, "field file") as fh:
            if fh.read(8) == _HDF5_MAGIC:
                return _hdf5_blocks(path, fh, budget)
    except OSError as exc:
        raise NektarError(f"{path}: cannot read ({exc.strerror or exc})") from exc
    return _xml_blocks(path, _parse_xml(path, "field file"), budget)


def _field_blocks(path: Path, n_elements=None):
    """All ELEMENTS blocks of a field file or of a multi-part .fld/ directory (§2.1). Given the
    mesh's element count, every size the file declares is checked against it before data is
    inflated or read; without it (None) only headers are read (names, shapes, bases; no data)."""
    budget = None if n_elements is None else _Budget(n_elements)
    if not path.is_dir():
        if not path.exists():
            raise NektarError(f"{path}: no such field file")
        return _file_blocks(path, budget)
    info = path / "Info.xml"
    if not info.exists():
        raise NektarError(f"{path}: a field directory needs an Info.xml listing its parts")
    root = _parse_xml(info, "field directory index")
    parts = list(root.iter("Partition"))
    if not parts:
        raise NektarError(f"{info}: no <Partition> entries")
    blocks = []
    for p in parts:
        name = p.attrib.get("FileName", "")
        if not re.fullmatch(r"[A-Za-z0-9_.\-]+", name) or name in (".", ".."):
            raise NektarError(f"{info}: Partition FileName={name!r} is not a plain file name in the directory")
        ranges = _parse_ranges(p.text, info, f"Partition {name}")
        part_blocks = _file_blocks(path / name, budget)
        if budget is not None:
            got = set()
            for b in part_blocks:
                got.update(b.ids.tolist())
            # compare counts before expanding the (untrusted) list
            listed = set(_expand_ranges(ranges).tolist()) if _range_count(ranges) == len(got) else set()
            if got != listed:
                raise NektarError(f"{info}: Partition {name} lists {_range_count(ranges)} elements but the file holds "
                                  f"{len(got)} (other IDs or counts)")
        blocks.extend(part_blocks)
    return blocks


def _field_names(blocks):
    names = []
    for b in blocks:
        for n in b.fields:
            if n not in names:
                names.append(n)
    return names


def list_fields(solution_path) -> list[str]:
    """Names of the fields in a Nektar++ field file (.fld/.chk/.rst, XML or HDF5, or a .fld/ directory)."""
    path = Path(solution_path)
    return _guard(path, lambda: _field_names(_field_blocks(path)))


def _field_coeffs(path, blocks, field):
    """{element ID: (shape, modes, Modified coefficients)} of one field."""
    from ..core import expansions as ex

    out = {}
    for b in blocks:
        if field not in b.fields:
            continue
        nc = _ncoeffs(b.shape, b.modes)
        total = int(nc.sum())
        f = b.fields.index(field)
        seg = b.data[f * total : (f + 1) * total]
        bad = ~np.isfinite(seg)
        offs = np.concatenate([[0], np.cumsum(nc)])
        if bad.any():
            e = int(np.searchsorted(offs, np.flatnonzero(bad)[0], side="right") - 1)
            raise NektarError(f"{path}: {b.what}: element {int(b.ids[e])}, field {field!r}: coefficients contain NaN or Inf")
        gll = b.basis[0] == "GLL_Lagrange"
        for i, (e, m) in enumerate(zip(b.ids.tolist(), b.modes)):
            if e in out:
                raise NektarError(f"{path}: {b.what}: element {e} appears twice for field {field!r}")
            c = np.array(seg[offs[i] : offs[i + 1]], dtype=np.float64)
            if gll:
                c = _gll_to_modal(tuple(int(v) for v in m)) @ c
            out[e] = (b.shape, m, c)
    return out


@lru_cache(maxsize=None)
def _gll_to_modal(modes):
    """The (K, K) matrix taking GLL_Lagrange nodal values of a hex to Modified_A coefficients."""
    from ..core import expansions as ex

    K = int(np.prod(modes))
    return np.asarray(ex.gll_lagrange_hex_to_modal(modes, np.eye(K)), dtype=np.float64).reshape(K, K)


# ----------------------------------------------------------------------------- public entry point

def _guard(path, fn):
    """Run fn; an exception that is not a NektarError becomes one naming the file (marked
    'unexpected' so tests can tell a reader bug from a diagnosed input error)."""
    try:
        return fn()
    except NektarError:
        raise
    except MeshError as exc:
        raise NektarError(f"{path}: {exc}") from exc
    except (limits.ResourceLimitError, limits.UnsafeFileError) as exc:  # their messages name the file
        raise NektarError(str(exc)) from exc
    except (ValueError, IndexError, KeyError, TypeError, OverflowError, ZeroDivisionError,
            ArithmeticError, np.linalg.LinAlgError, RecursionError, UnicodeError) as exc:
        raise NektarError(f"{path}: unexpected {type(exc).__name__} while reading ({exc})") from exc


SOLUTION_EXTENSIONS = (".fld", ".chk", ".rst")


def find_solution(mesh_path) -> Path | None:
    """The field file beside a mesh: its name with .fld, .chk or .rst (a file or a multi-part
    .fld/ folder), the first that exists; None if there is none."""
    mesh_path = Path(mesh_path)
    return next((p for p in (mesh_path.with_suffix(e) for e in SOLUTION_EXTENSIONS) if p.exists()), None)


def read_nektar(mesh_path, solution_path=None, field=None) -> VolumeMesh:
    """VolumeMesh of one field of a Nektar++ mesh (.xml) and its field file (.fld/.chk/.rst, XML or
    HDF5, or a multi-part .fld/ directory). Without a field file (none given and none beside the
    mesh: find_solution) the geometry comes with a zero field named "(none)" and has_field False.
    The returned mesh carries ``warnings`` (list of str) and ``has_field``."""
    mesh_path = Path(mesh_path)
    if solution_path is None:
        solution_path = find_solution(mesh_path)
    if solution_path is None and field is not None:
        raise NektarError(f"{mesh_path}: field {field!r} requested but there is no field file "
                          f"(no {', '.join(mesh_path.with_suffix(e).name for e in SOLUTION_EXTENSIONS)} "
                          "beside the mesh)")
    sol = Path(solution_path) if solution_path is not None else None
    return _guard(mesh_path, lambda: _read(mesh_path, sol, field))


def _read(mesh_path, sol, field):
    warnings: list[str] = []
    mesh = _read_mesh(mesh_path)
    if sol is not None:
        blocks = _guard(sol, lambda: _field_blocks(sol, len(mesh.elements)))
        names = _field_names(blocks)
        if field is None:
            if len(names) != 1:
                raise NektarError(f"{sol}: holds fields {', '.join(names) or '(none)'}; name the one to render")
            field = names[0]
        elif field not in names:
            raise NektarError(f"{sol}: no field {field!r}; it holds {', '.join(names)}")
        coeffs = _guard(sol, lambda: _field_coeffs(sol, blocks, field))
        ids = [e for e, _, _ in mesh.elements]
        idset = set(ids)
        missing = [i for i in ids if i not in coeffs]
        if missing:
            raise NektarError(f"{sol}: no coefficients of field {field!r} for mesh element(s) "
                              f"{missing[:10]}{' ...' if len(missing) > 10 else ''}")
        extra = sorted(set(coeffs) - idset)
        if extra:
            raise NektarError(f"{sol}: element(s) {extra[:10]} are not in the mesh {mesh_path.name}")
        for e, shape, _ in mesh.elements:
            if coeffs[e][0] != shape:
                raise NektarError(f"{sol}: element {e} is a {NAMES[coeffs[e][0]]} in the field file but a "
                                  f"{NAMES[shape]} in {mesh_path.name}")
    n = len(mesh.elements)
    shapes = np.array([s for _, s, _ in mesh.elements], dtype=np.int32)
    # geometry per element
    fcache, ecache = {}, {}
    gmodes = np.full((n, 3), 2, dtype=np.int32)
    gco: list = [None] * n
    straight: dict = {}
    curved: dict = {}
    for k, (e, shape, fids) in enumerate(mesh.elements):
        topo = _topology(mesh, e, shape, fids, fcache)
        P = _element_order(mesh, topo)
        if P == 2:
            straight.setdefault(shape, []).append((k, [mesh.verts[v] for v in topo.verts]))
        else:
            gmodes[k] = P
            gco[k] = _element_geometry(mesh, e, shape, topo, P, warnings, ecache)
            curved.setdefault((shape, P), []).append(k)
    for shape, items in straight.items():
        ks = [k for k, _ in items]
        C = _straight_coeffs(shape, np.array([v for _, v in items]))
        _check_jacobians(mesh_path, shape, 2, [mesh.elements[k][0] for k in ks], C)
        for k, c in zip(ks, C):
            gco[k] = c
    for (shape, P), ks in curved.items():
        _check_jacobians(mesh_path, shape, P, [mesh.elements[k][0] for k in ks], np.stack([gco[k] for k in ks]))
    if sol is None:
        from ..core import expansions as ex

        modes = np.full((n, 3), 2, dtype=np.int32)
        fco = [np.zeros(ex.num_coeffs(int(s), (2, 2, 2))) for s in shapes]
        name = NO_FIELD
    else:
        modes = np.array([coeffs[e][1] for e, _, _ in mesh.elements], dtype=np.int32)
        fco = [coeffs[e][2] for e, _, _ in mesh.elements]
        name = field
    try:
        out = VolumeMesh.from_elements(shapes, modes, fco, gmodes, gco, field_name=name, source=str(mesh_path))
    except MeshError as exc:
        # from_elements numbers elements by position: name the Nektar++ element ID too
        m = re.match(r"element (\d+):(.*)", str(exc), re.S)
        if m and int(m.group(1)) < n:
            raise NektarError(f"{mesh_path}: element {mesh.elements[int(m.group(1))][0]}:{m.group(2)}") from exc
        raise NektarError(f"{mesh_path}: {exc}") from exc
    out.element_ids = np.array([e for e, _, _ in mesh.elements], dtype=np.int64)
    out.has_field = sol is not None
    out.warnings = sorted(set(warnings))
    return out
