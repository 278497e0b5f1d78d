"""VTK XML unstructured grids (.vtu) with Lagrange and Bézier cells -> VolumeMesh.

Cells: VTK_LAGRANGE_{TETRAHEDRON 71, HEXAHEDRON 72, WEDGE 73}, VTK_BEZIER_{TETRAHEDRON 78,
HEXAHEDRON 79, WEDGE 80} of any degree (HigherOrderDegrees cell data, else inferred from the
node count), and the linear VTK_TETRA 10 / VTK_HEXAHEDRON 12 / VTK_WEDGE 13 as degree 1.
Pyramids (14, 74, 81) are refused: VTK's higher-order pyramid space is not Nektar++'s.

Conversion (spec/formats.md §4): a cell of degree p is a polynomial in the same space as the
MODIFIED expansion with p+1 modes per direction (hex Q_p, tet P_p, wedge P_p(triangle) x
P_q(line)), so field and geometry are converted exactly: the cell's own interpolant (Lagrange
on equispaced nodes, or Bernstein) is evaluated at expansions.fit_points and fitted with
expansions.fit_modal. One (modes x nodes) matrix per cell kind and degree serves all its cells.

Node orders are derived from VTK's documented rules (corners, edges, faces, interior; recursive
"onion" order for tetrahedra; the wedge's triangle faces are row-by-row) and checked against
vtk's own cells in tests/core/test_vtu.py. Hexahedra in files older than version 2.1 use the
VTK 8 order (last two vertical edges swapped), as vtkXMLUnstructuredDataReader converts them
(it renumbers only when the file version is < 2.1; 2.1 and 2.2 are both the VTK 9 order).

Reading is done here, not by meshio: its VtuReader refuses VTKFile versions other than 0.1/1.0
and keeps only the last <Piece>, and its decoders trust the block headers (unbounded, quadratic
inflation of zlib/lzma blocks; raw appended data re-encoded as base64). The file is opened
through engine.limits (regular files only, size within the memory limit); ElementTree reads the
XML, and every DataArray is decoded with numpy (ascii; inline or appended base64; raw appended;
zlib or lzma blocks; UInt32/UInt64 headers; either byte order) to the size the piece's counts
give it: a block header that declares another size is refused before anything is allocated or
inflated, and each block is inflated, bounded, to exactly its declared size.
"""
from __future__ import annotations

import base64
import binascii
import math
import re
import warnings
import xml.etree.ElementTree as ET
from dataclasses import dataclass
from functools import lru_cache
from pathlib import Path

import numpy as np

from ..core import expansions as ex
from ..core import shapes
from ..core import limits
from ..core.shapes import MAX_MODES
from ..core.mesh import MeshError, VolumeMesh

HEX, PRISM, TET = shapes.HEX, shapes.PRISM, shapes.TET


class VtuError(ValueError):
    """A .vtu file this reader cannot use; the message names the file and, where known, the cell."""


# VTK type -> (name, our shape, basis family)
CELL_TYPES = {
    10: ("VTK_TETRA", TET, "linear"),
    12: ("VTK_HEXAHEDRON", HEX, "linear"),
    13: ("VTK_WEDGE", PRISM, "linear"),
    71: ("VTK_LAGRANGE_TETRAHEDRON", TET, "lagrange"),
    72: ("VTK_LAGRANGE_HEXAHEDRON", HEX, "lagrange"),
    73: ("VTK_LAGRANGE_WEDGE", PRISM, "lagrange"),
    78: ("VTK_BEZIER_TETRAHEDRON", TET, "bezier"),
    79: ("VTK_BEZIER_HEXAHEDRON", HEX, "bezier"),
    80: ("VTK_BEZIER_WEDGE", PRISM, "bezier"),
}
_PYRAMIDS = {14: "VTK_PYRAMID", 74: "VTK_LAGRANGE_PYRAMID", 81: "VTK_BEZIER_PYRAMID"}
_FORBIDDEN = (b"<!doctype", b"<!entity")


# ---------------------------------------------------------------------------------------------
# VTK node orders, as integer lattice indices (params = index / degree)

def _tri_onion(n):
    """Barycentric indices (b0, b1, b2), sum n, in VTK's recursive triangle order."""
    if n < 0:
        return []
    if n == 0:
        return [(0, 0, 0)]
    pts = [(n, 0, 0), (0, n, 0), (0, 0, n)]
    pts += [(n - i, i, 0) for i in range(1, n)]
    pts += [(0, n - i, i) for i in range(1, n)]
    pts += [(i, 0, n - i) for i in range(1, n)]
    return pts + [(a + 1, b + 1, c + 1) for a, b, c in _tri_onion(n - 3)]


_TET_EDGES = ((0, 1), (1, 2), (2, 0), (0, 3), (1, 3), (2, 3))
# each face's interior is a triangle whose corners lie next to these vertices, in this order
_TET_FACES = ((0, 1, 3), (2, 3, 1), (0, 3, 2), (0, 2, 1))


def tet_order(n):
    """(N, 4) barycentric lattice indices (weights of VTK vertices 0..3), in VTK point order."""
    if n < 0:
        return []
    if n == 0:
        return [(0, 0, 0, 0)]
    pts = [tuple(n if m == v else 0 for m in range(4)) for v in range(4)]
    for u, v in _TET_EDGES:
        for i in range(1, n):
            b = [0] * 4
            b[u], b[v] = n - i, i
            pts.append(tuple(b))
    for face in _TET_FACES:
        for t in _tri_onion(n - 3):
            b = [0] * 4
            for m, tm in zip(face, t):
                b[m] = tm + 1
            pts.append(tuple(b))
    return pts + [tuple(x + 1 for x in b) for b in tet_order(n - 4)]


def hex_order(p, q, r, vtk8=False):
    """(N, 3) lattice indices (i, j, k) in VTK point order; vtk8: pre-2.1 files' edge order."""
    pts = [(0, 0, 0), (p, 0, 0), (p, q, 0), (0, q, 0), (0, 0, r), (p, 0, r), (p, q, r), (0, q, r)]
    for k in (0, r):
        pts += [(i, 0, k) for i in range(1, p)] + [(p, j, k) for j in range(1, q)]
        pts += [(i, q, k) for i in range(1, p)] + [(0, j, k) for j in range(1, q)]
    verticals = ((0, 0), (p, 0), (0, q), (p, q)) if vtk8 else ((0, 0), (p, 0), (p, q), (0, q))
    for i, j in verticals:
        pts += [(i, j, k) for k in range(1, r)]
    for i in (0, p):
        pts += [(i, j, k) for k in range(1, r) for j in range(1, q)]
    for j in (0, q):
        pts += [(i, j, k) for k in range(1, r) for i in range(1, p)]
    for k in (0, r):
        pts += [(i, j, k) for j in range(1, q) for i in range(1, p)]
    return pts + [(i, j, k) for k in range(1, r) for j in range(1, q) for i in range(1, p)]


def wedge_order(p, q):
    """(N, 3) lattice indices (i, j, k): triangle (i, j) of degree p, line k of degree q."""
    corners = [(0, 0), (p, 0), (0, p)]
    sides = ([(i, 0) for i in range(1, p)], [(p - j, j) for j in range(1, p)], [(0, p - j) for j in range(1, p)])
    edges = sides[0] + sides[1] + sides[2]
    # the wedge's triangle-face and body points run row by row, not in the triangle's onion order
    inner = [(i, j) for j in range(1, p - 1) for i in range(1, p - j)]
    pts = [(i, j, 0) for i, j in corners] + [(i, j, q) for i, j in corners]
    pts += [(i, j, 0) for i, j in edges] + [(i, j, q) for i, j in edges]
    for i, j in corners:
        pts += [(i, j, k) for k in range(1, q)]
    pts += [(i, j, 0) for i, j in inner] + [(i, j, q) for i, j in inner]
    for side in sides:
        pts += [(i, j, k) for k in range(1, q) for i, j in side]
    return pts + [(i, j, k) for k in range(1, q) for i, j in inner]


def vtk_node_params(shape, degs, vtk8=False):
    """(N, 3) VTK parametric coordinates ([0, 1]-based) of a cell's nodes, in VTK point order."""
    if shape == HEX:
        return np.array(hex_order(*degs, vtk8=vtk8), dtype=np.float64) / np.asarray(degs, dtype=np.float64)
    if shape == TET:
        return np.array(tet_order(degs[0]), dtype=np.float64)[:, 1:] / degs[0]
    p, q = degs[0], degs[2]
    return np.array(wedge_order(p, q), dtype=np.float64) / np.array([p, p, q], dtype=np.float64)


# ---------------------------------------------------------------------------------------------
# Reference-cell correspondence. Hex and tet: xi = 2r - 1. Wedge: VTK's triangle (r, s) is our
# (xi3, xi1) triangle and VTK's t is our xi2 -- a cyclic permutation, so orientation is kept;
# VTK corners 0..5 land on our prism vertices 0, 4, 1, 3, 5, 2. Writers differ in handedness
# (NGSolve's hexahedra are all left-handed in VTK's frame), so a cell whose Jacobian is negative
# throughout is read through the mirrored correspondence: every element comes out right-handed.

def xi_to_vtk(shape, xi, mirror=False):
    r = 0.5 * (np.asarray(xi, dtype=np.float64) + 1.0)
    if shape == PRISM:
        return r[..., [0, 2, 1]] if mirror else r[..., [2, 0, 1]]
    if mirror and shape == TET:
        return r[..., [1, 0, 2]]
    if mirror:
        return np.concatenate([r[..., :2], 1.0 - r[..., 2:]], axis=-1)
    return r


def _lagrange_1d(n, x):
    """(M, n+1) equispaced Lagrange basis on [0, 1] at x (M,)."""
    z = n * x
    out = np.ones(x.shape + (n + 1,))
    for a in range(n + 1):
        for b in range(n + 1):
            if b != a:
                out[:, a] *= (z - b) / (a - b)
    return out


def _bernstein_1d(n, x):
    return np.stack([math.comb(n, a) * x**a * (1.0 - x) ** (n - a) for a in range(n + 1)], axis=-1)


def _simplex_factor(family, n, lam):
    """(M, n+1) per-barycentric factor: Lagrange (Silvester) prod_{s<a} (n lam - s)/(s+1) or
    Bernstein lam^a / a! (the n! is applied by the caller)."""
    out = np.ones(lam.shape + (n + 1,))
    for a in range(1, n + 1):
        if family == "bezier":
            out[:, a] = lam**a / math.factorial(a)
        else:
            out[:, a] = out[:, a - 1] * (n * lam - (a - 1)) / a
    return out


def cell_basis(shape, family, degs, params, vtk8=False):
    """(M, N) values of the cell's N nodal (Lagrange) or control-point (Bernstein) basis
    functions, VTK point order, at VTK parametric points (M, 3)."""
    params = np.asarray(params, dtype=np.float64)
    one_d = _bernstein_1d if family == "bezier" else _lagrange_1d
    if shape == HEX:
        idx = np.array(hex_order(*degs, vtk8=vtk8))
        t = [one_d(degs[d], params[:, d]) for d in range(3)]
        return t[0][:, idx[:, 0]] * t[1][:, idx[:, 1]] * t[2][:, idx[:, 2]]
    if shape == TET:
        n = degs[0]
        idx = np.array(tet_order(n))
        r, s, t = params.T
        lam = (1.0 - r - s - t, r, s, t)
        out = np.ones((params.shape[0], idx.shape[0]))
        for m in range(4):
            out *= _simplex_factor(family, n, lam[m])[:, idx[:, m]]
        return out * (math.factorial(n) if family == "bezier" else 1.0)
    p, q = degs[0], degs[2]
    idx = np.array(wedge_order(p, q))
    r, s, t = params.T
    lam = (1.0 - r - s, r, s)
    tri_idx = (p - idx[:, 0] - idx[:, 1], idx[:, 0], idx[:, 1])
    out = np.ones((params.shape[0], idx.shape[0]))
    for m in range(3):
        out *= _simplex_factor(family, p, lam[m])[:, tri_idx[m]]
    if family == "bezier":
        out *= math.factorial(p)
    return out * one_d(q, t)[:, idx[:, 2]]


def modes_for(shape, degs):
    if shape == HEX:
        return tuple(d + 1 for d in degs)
    if shape == TET:
        return (degs[0] + 1,) * 3
    return (degs[0] + 1, degs[2] + 1, degs[0] + 1)  # our prism triangle is (xi1, xi3)


@lru_cache(maxsize=64)
def conversion_matrix(shape, family, degs, vtk8=False, mirror=False):
    """(K, N): modal coefficients = matrix @ nodal values (VTK point order); read-only."""
    modes = modes_for(shape, degs)
    xi = np.asarray(ex.fit_points(shape, modes), dtype=np.float64)
    E = cell_basis(shape, family, degs, xi_to_vtk(shape, xi, mirror), vtk8)
    T = np.asarray(ex.fit_modal(shape, modes, E), dtype=np.float64)
    T.setflags(write=False)
    return T


@lru_cache(maxsize=64)
def _jacobian_probe(shape, modes):
    """Sample points and the (S, K, 3) reference gradients of every geometry mode at them."""
    xi = np.asarray(ex.fit_points(shape, modes), dtype=np.float64)
    k = ex.num_coeffs(shape, modes)
    G = np.asarray(ex.eval_modal_grad(shape, modes, np.eye(k), xi), dtype=np.float64)
    G.setflags(write=False)
    return G


# ---------------------------------------------------------------------------------------------
# File access. ElementTree reads the XML (up to <AppendedData>); every DataArray the reader
# needs is decoded here, its size fixed in advance by the piece's counts: a block header must
# declare exactly that size before anything is allocated or inflated, and compressed blocks are
# inflated one by one, bounded, into one preallocated buffer (linear time).

_NP_TYPES = {"Int8": "i1", "UInt8": "u1", "Int16": "i2", "UInt16": "u2", "Int32": "i4", "UInt32": "u4",
             "Int64": "i8", "UInt64": "u8", "Float32": "f4", "Float64": "f8"}
_CODECS = {"vtkZLibDataCompressor": "zlib", "vtkLZMADataCompressor": "lzma"}
_WHITESPACE = b" \t\n\r\f\v"
_APPENDED_TAG = re.compile(rb"<AppendedData\b[^>]*>")
_APPENDED_MARK = re.compile(rb"\s*_")


@dataclass(frozen=True)
class _Source:
    """A loaded file: what decoding its DataArrays needs."""
    path: Path
    order: str  # "<", ">" or "=": byte_order
    header: np.dtype  # block header words (header_type) in that byte order
    codec: str | None  # "zlib", "lzma" or None
    appended: memoryview | None  # after <AppendedData>'s '_', up to its closing tag
    appended_base64: bool
    budget: limits.InflationBudget  # what all compressed arrays together may inflate to


def _tag_attrs(path, tag: bytes, name):
    try:
        return ET.fromstring(tag[:-1].rstrip(b"/") + b"/>").attrib
    except ET.ParseError as exc:
        raise VtuError(f"{path}: malformed <{name}> element ({exc})") from None


def _load(path: Path):
    """(root element, without the appended data; _Source)."""
    try:
        raw = limits.read_regular(path, "VTU file")
    except FileNotFoundError:
        raise VtuError(f"{path}: cannot read (no such file)") from None
    except (limits.UnsafeFileError, limits.ResourceLimitError) as exc:
        raise VtuError(f"{path}: {exc}") from exc
    except OSError as exc:
        raise VtuError(f"{path}: cannot read ({exc.strerror or exc})") from exc
    cut = raw.find(b"<AppendedData")
    head = raw if cut < 0 else raw[:cut]
    low = head.lower()
    # DTDs can define entities (exponential expansion, external files): no VTK writer emits one.
    if any(p in low for p in _FORBIDDEN):
        raise VtuError(f"{path}: DOCTYPE/ENTITY declarations are refused")
    m = re.search(rb"<VTKFile\b[^>]*>", head)
    if m is None:
        raise VtuError(f"{path}: not a VTK XML file (no <VTKFile> element)")
    attrs = _tag_attrs(path, m.group(0), "VTKFile")
    if attrs.get("type") != "UnstructuredGrid":
        raise VtuError(f"{path}: VTKFile type {attrs.get('type')!r}; only UnstructuredGrid (.vtu) is read")
    header_type = attrs.get("header_type", "UInt32")
    if header_type not in ("UInt32", "UInt64"):
        raise VtuError(f"{path}: header_type {header_type!r} (VTK writes UInt32 or UInt64)")
    compressor = attrs.get("compressor")
    if compressor is not None and compressor not in _CODECS:
        raise VtuError(f"{path}: compressor {compressor!r} is not supported (vtkZLibDataCompressor and "
                       "vtkLZMADataCompressor are)")
    byte_order = attrs.get("byte_order")
    if byte_order not in (None, "LittleEndian", "BigEndian"):
        raise VtuError(f"{path}: byte_order {byte_order!r}")
    try:
        root = ET.fromstring(head + (b"</VTKFile>" if cut >= 0 else b""))
    except ET.ParseError as exc:
        raise VtuError(f"{path}: not well-formed XML ({exc})") from None

    appended, base64_appended = None, False
    if cut >= 0:
        tag = _APPENDED_TAG.match(raw, cut)
        if tag is None:
            raise VtuError(f"{path}: truncated (unterminated <AppendedData> tag)")
        enc = _tag_attrs(path, tag.group(0), "AppendedData").get("encoding")
        if enc not in ("raw", "base64"):
            raise VtuError(f"{path}: <AppendedData> encoding {enc!r} (VTK writes raw or base64)")
        mark = _APPENDED_MARK.match(raw, tag.end())
        if mark is None:
            raise VtuError(f"{path}: no '_' marks the start of the appended data")
        end = raw.rfind(b"</AppendedData>")
        if end < mark.end():
            raise VtuError(f"{path}: truncated (<AppendedData> has no closing tag)")
        appended, base64_appended = memoryview(raw)[mark.end():end], enc == "base64"
    order = {"LittleEndian": "<", "BigEndian": ">", None: "="}[byte_order]  # none: this machine's, as in VTK
    return root, _Source(path, order, np.dtype(order + _NP_TYPES[header_type]), _CODECS.get(compressor),
                         appended, base64_appended, limits.InflationBudget(len(raw), f"VTU file {path.name}"))


def _decode(src: _Source, arr, what, count, why):
    """The array's values, flat and in native byte order: exactly `count` of them, which `why`
    explains (for the error). Ascii arrays come as int64/uint64/float64 (no wrap-around)."""
    path = src.path
    tname = arr.attrib.get("type")
    if tname not in _NP_TYPES:
        raise VtuError(f"{path}: {what}: data type {tname!r} is not supported")
    dtype = np.dtype(src.order + _NP_TYPES[tname])
    need = (count * dtype.itemsize, f"{why}: {count} x {tname}")
    fmt = arr.attrib.get("format", "ascii")
    try:
        limits.check_bytes(need[0], what)
        if fmt == "ascii":
            return _ascii(src, arr.text or "", tname, count, what, why)
        if fmt == "binary":
            text = (arr.text or "").encode("ascii", "replace").translate(None, _WHITESPACE)
            data = _base64_array(src, text, 0, need, what, "its inline data")
        elif fmt == "appended":
            if src.appended is None:
                raise VtuError(f"{path}: {what}: format=\"appended\" but the file has no <AppendedData>")
            try:
                offset = int(arr.attrib["offset"])
            except (KeyError, ValueError):
                raise VtuError(f"{path}: {what}: missing or bad offset") from None
            if not 0 <= offset < len(src.appended):
                raise VtuError(f"{path}: {what}: offset {offset} is outside the appended data "
                               f"({len(src.appended)} bytes)")
            block = _base64_array if src.appended_base64 else _raw_array
            data = block(src, src.appended, offset, need, what, "the appended data")
        else:
            raise VtuError(f"{path}: {what}: format {fmt!r} (ascii, binary or appended)")
    except VtuError:
        raise
    except ValueError as exc:  # limits: the memory limit, a bomb, a broken or truncated zlib/lzma stream
        raise VtuError(f"{path}: {exc}") from exc
    return np.frombuffer(data, dtype).astype(dtype.newbyteorder("="), copy=False)


def _ascii(src, text, tname, count, what, why):
    """An ascii array's `count` numbers, parsed wide (int64, uint64 or float64)."""
    b = np.frombuffer(text.encode(), np.uint8)
    space = np.isin(b, np.frombuffer(_WHITESPACE, np.uint8))
    n = int(np.count_nonzero(space[:-1] & ~space[1:])) + int(b.size > 0 and not space[0])
    if n != count:  # counted first: the parse below is bounded by the piece's count
        raise VtuError(f"{src.path}: {what}: {n} values, the piece needs {count} ({why})")
    wide = np.float64 if tname.startswith("Float") else np.uint64 if tname == "UInt64" else np.int64
    if n == 0:
        return np.empty(0, wide)
    with warnings.catch_warnings():
        warnings.simplefilter("error", DeprecationWarning)  # numpy's "could not be read to its end"
        try:
            data = np.fromstring(text, wide, sep=" ")
        except (DeprecationWarning, ValueError):
            data = None
    if data is None or data.size != n:
        raise VtuError(f"{src.path}: {what}: not a list of {tname} numbers")
    return data


def _b64len(nbytes):
    return 4 * -(-nbytes // 3)


def _b64(src, text, pos, nbytes, what, where, exact=True):
    """Bytes of the base64 run encoding `nbytes` at text[pos:] (exact=False: a run's first
    nbytes; no padding expected there)."""
    nchars = _b64len(nbytes)
    if pos + nchars > len(text):
        raise VtuError(f"{src.path}: {what}: needs {nchars} base64 characters at {pos}, past the end of "
                       f"{where} ({len(text)} characters)")
    try:
        out = base64.b64decode(text[pos:pos + nchars], validate=True)
    except binascii.Error as exc:
        raise VtuError(f"{src.path}: {what}: not valid base64 ({exc})") from None
    if len(out) < nbytes or exact and len(out) != nbytes:
        raise VtuError(f"{src.path}: {what}: base64 run of {nchars} characters decodes to {len(out)} "
                       f"bytes, not {nbytes}")
    return out


def _check_declared(src, declared, need, what):
    if declared != need[0]:
        raise VtuError(f"{src.path}: {what}: its data header declares {declared} bytes, the piece needs "
                       f"{need[0]} ({need[1]})")


def _check_blocks(src, head, need, what):
    """The compression header [blocks, block size, last block size] against the piece's size."""
    nblocks, size, last = head
    _check_declared(src, 0 if nblocks == 0 else (nblocks - 1) * size + (last or size), need, what)
    if nblocks and (size == 0 or last > size):
        raise VtuError(f"{src.path}: {what}: compression header [{nblocks}, {size}, {last}, ...] is inconsistent")
    src.budget.spend(need[0], what)


def _block_ends(src, sizes, room, what, where):
    """End offsets of the compressed blocks, all inside `room` bytes."""
    ends = np.cumsum(sizes, dtype=np.uint64)
    wrapped = bool(np.any(ends[1:] < ends[:-1]))  # every size is below 2**64: a wrap-around shows as a decrease
    if ends.size and (wrapped or int(ends[-1]) > room):
        total = "more than 2**64" if wrapped else int(ends[-1])
        raise VtuError(f"{src.path}: {what}: its compressed blocks ({total} bytes) run past the end of {where} "
                       f"({room} bytes left)")
    return ends


def _inflate(src, comp, ends, head, need, what):
    """The compressed blocks comp[0:ends[0]], comp[ends[0]:ends[1]], ... inflated, each to
    exactly its declared size, into one buffer."""
    nblocks, size, last = head
    out = bytearray(need[0])
    view = memoryview(out)
    start = pos = 0
    for k in range(nblocks):
        end = int(ends[k])
        n = last if k == nblocks - 1 and last else size
        block, _ = limits.inflate(comp[start:end], n, f"{what} block {k}", src.codec, exact=True)
        view[pos:pos + n] = block
        start, pos = end, pos + n
    return out


def _raw_array(src, data, offset, need, what, where):
    """A raw appended block at data[offset:]: header words, then the (compressed) data."""
    h = src.header.itemsize

    def words(pos, n):
        if pos + n * h > len(data):
            raise VtuError(f"{src.path}: {what}: its {n}-word block header at {pos} runs past the end of "
                           f"{where} ({len(data)} bytes)")
        return np.frombuffer(data, src.header, n, pos)

    if src.codec is None:
        _check_declared(src, int(words(offset, 1)[0]), need, what)
        if offset + h + need[0] > len(data):
            raise VtuError(f"{src.path}: {what}: {need[0]} bytes at {offset + h} run past the end of {where} "
                           f"({len(data)} bytes)")
        return data[offset + h:offset + h + need[0]]
    head = [int(v) for v in words(offset, 3)]
    _check_blocks(src, head, need, what)
    start = offset + (3 + head[0]) * h
    ends = _block_ends(src, words(offset + 3 * h, head[0]), len(data) - start, what, where)
    return _inflate(src, data[start:], ends, head, need, what)


def _base64_array(src, text, pos, need, what, where):
    """A base64 block at text[pos:]: uncompressed, [nbytes][data] in one run (VTK) or in two
    (MFEM); compressed, the header and the blocks in two runs."""
    h = src.header.itemsize
    if src.codec is None:
        first = _b64(src, text, pos, h, what, where, exact=False)
        _check_declared(src, int(np.frombuffer(first, src.header, 1)[0]), need, what)
        if len(first) == h:  # the header is a run of its own, not the start of one with the data
            return _b64(src, text, pos + _b64len(h), need[0], what, where)
        return _b64(src, text, pos, h + need[0], what, where)[h:]
    head = [int(v) for v in np.frombuffer(_b64(src, text, pos, 3 * h, what, where, False), src.header, 3)]
    _check_blocks(src, head, need, what)
    nhead = (3 + head[0]) * h
    sizes = np.frombuffer(_b64(src, text, pos, nhead, what, where), src.header)[3:]
    start = pos + _b64len(nhead)
    ends = _block_ends(src, sizes, (len(text) - start) * 3 // 4, what, where)
    comp = _b64(src, text, start, int(ends[-1]) if ends.size else 0, what, where)
    return _inflate(src, memoryview(comp), ends, head, need, what)


def _version(path, root):
    """(major, minor); VTK treats a missing version as legacy (pre-2.1 hexahedron order)."""
    v = root.attrib.get("version")
    if v is None:
        return (0, 0)
    m = re.fullmatch(r"\s*(\d+)\.(\d+)\s*", v)
    if m is None:
        raise VtuError(f"{path}: unreadable VTKFile version {v!r}")
    return int(m.group(1)), int(m.group(2))


def _grid(path, root):
    grid = root.find("UnstructuredGrid")
    if grid is None:
        raise VtuError(f"{path}: no <UnstructuredGrid>")
    pieces = grid.findall("Piece")
    if not pieces:
        raise VtuError(f"{path}: no <Piece>")
    return pieces


def _point_arrays(piece):
    pd = piece.find("PointData")
    return [] if pd is None else [a for a in pd if a.tag == "DataArray"]


def _ncomp(path, arr, where):
    try:
        n = int(arr.attrib.get("NumberOfComponents", "1") or "1")
    except ValueError:
        raise VtuError(f"{path}: {where}: NumberOfComponents {arr.attrib.get('NumberOfComponents')!r}") from None
    if not 1 <= n <= 1024:
        raise VtuError(f"{path}: {where}: NumberOfComponents {n}")
    return n


def _fields(path, pieces):
    """Point-data arrays present in every piece: {name: number of components}, file order."""
    found = None
    for pi, piece in enumerate(pieces):
        here = {}
        for a in _point_arrays(piece):
            name = a.attrib.get("Name")
            if name:
                here[name] = _ncomp(path, a, f"piece {pi} point array {name!r}")
        found = here if found is None else {k: v for k, v in found.items() if here.get(k) == v}
    return found or {}


def list_fields(path) -> dict[str, int]:
    """Point-data arrays present in every piece: {name: number of components}, file order.
    Reads the XML only (no array is decoded)."""
    path = Path(path)
    try:
        root, _ = _load(path)
        return _fields(path, _grid(path, root))
    except VtuError:
        raise
    except Exception as exc:  # anything a malformed file provokes in the XML layer
        raise VtuError(f"{path}: unreadable ({type(exc).__name__}: {exc})") from exc


def _int_attr(path, el, key, where):
    try:
        v = int(el.attrib[key])
    except (KeyError, ValueError):
        raise VtuError(f"{path}: {where}: missing or bad {key}") from None
    if v < 0:
        raise VtuError(f"{path}: {where}: {key} = {v}")
    return v


def _infer_degs(shape, n):
    if shape == HEX:
        p = round(n ** (1.0 / 3.0)) - 1
        return (p, p, p) if p >= 1 and (p + 1) ** 3 == n else None
    for p in range(1, 64):
        cnt = (p + 1) * (p + 2) * (p + 3) // 6 if shape == TET else (p + 1) ** 2 * (p + 2) // 2
        if cnt == n:
            return (p, p, p)
        if cnt > n:
            return None
    return None


def _node_count(shape, degs):
    p, q, r = degs
    if shape == HEX:
        return (p + 1) * (q + 1) * (r + 1)
    if shape == TET:
        return (p + 1) * (p + 2) * (p + 3) // 6
    return (p + 1) * (p + 2) // 2 * (r + 1)


# ---------------------------------------------------------------------------------------------

def read_vtu(path, field=None, component=None) -> VolumeMesh:
    """Read a .vtu file into a VolumeMesh (field and geometry as modal expansions).

    field: a point-data array name (default: the first one). component: for multi-component
    arrays an index, or "magnitude" (the default for vectors; the magnitude is taken at the
    nodes and interpolated like any nodal field). Every problem raises VtuError."""
    path = Path(path)
    try:
        return _read(path, field, component)
    except VtuError:
        raise
    except limits.ResourceLimitError as exc:
        raise VtuError(f"{path}: {exc}") from exc
    except MeshError as exc:
        raise VtuError(f"{path}: {exc}".replace("element ", "cell ", 1)) from exc
    except Exception as exc:  # a malformed file must never surface as anything but VtuError
        raise VtuError(f"{path}: unreadable ({type(exc).__name__}: {exc})") from exc


def _select_component(path, values, name, ncomp, component):
    if ncomp == 1:
        if component not in (None, 0, "magnitude"):
            raise VtuError(f"{path}: field {name!r} is a scalar; component {component!r} does not exist")
        return values.reshape(-1), name
    values = values.reshape(-1, ncomp)
    if component is None or component == "magnitude":
        return np.sqrt(np.einsum("ij,ij->i", values, values)), f"|{name}|"
    if isinstance(component, (int, np.integer)) and not isinstance(component, bool) and 0 <= component < ncomp:
        return values[:, int(component)], f"{name}[{int(component)}]"
    raise VtuError(f"{path}: field {name!r} has {ncomp} components; component must be 0..{ncomp - 1} "
                   f"or 'magnitude', not {component!r}")


def _read(path, field, component):
    root, src = _load(path)
    pieces = _grid(path, root)
    available = _fields(path, pieces)
    if field is None:
        if not available:
            raise VtuError(f"{path}: no point-data array to render")
        field = next(iter(available))
    elif field not in available:
        cell_names = {a.attrib.get("Name") for p in pieces for cd in p.findall("CellData") for a in cd}
        hint = " (it is cell data: only point data is a polynomial field)" if field in cell_names else ""
        raise VtuError(f"{path}: no point-data field {field!r}{hint}; available: {sorted(available) or 'none'}")
    ncomp = available[field]
    vtk8 = _version(path, root) < (2, 1)

    cell_shape, cell_family, cell_degs, cell_nodes, cell_vals = [], [], [], [], []
    base = 0  # global cell index of the piece's first cell (error messages)
    for pi, piece in enumerate(pieces):
        where = f"piece {pi}"
        npts = _int_attr(path, piece, "NumberOfPoints", where)
        ncells = _int_attr(path, piece, "NumberOfCells", where)
        if ncells == 0:
            continue
        pel = piece.find("Points")
        if pel is None or len(pel) != 1:
            raise VtuError(f"{path}: {where}: <Points> must hold one DataArray")
        pts = _decode(src, pel[0], f"{where} points", 3 * npts, f"{npts} points x 3")
        pts = pts.astype(np.float64, copy=False).reshape(npts, 3)

        cel = piece.find("Cells")
        if cel is None:
            raise VtuError(f"{path}: {where}: no <Cells>")
        carr = {a.attrib.get("Name"): a for a in cel}
        if "faces" in carr:
            raise VtuError(f"{path}: {where}: polyhedral cells are not supported")
        for key in ("connectivity", "offsets", "types"):
            if key not in carr:
                raise VtuError(f"{path}: {where}: <Cells> lacks the {key} array")
        offs = _decode(src, carr["offsets"], f"{where} offsets", ncells, f"{ncells} cells")
        types = _decode(src, carr["types"], f"{where} types", ncells, f"{ncells} cells")
        for name, a in (("offsets", offs), ("types", types)):
            if a.dtype.kind not in "iu":
                raise VtuError(f"{path}: {where}: {name} array is {a.dtype}, not integer")
        offs = offs.astype(np.int64)
        starts = np.concatenate([[0], offs[:-1]])
        bad = np.flatnonzero(offs <= starts)
        if bad.size:
            raise VtuError(f"{path}: cell {base + bad[0]}: offsets are not increasing")
        conn = _decode(src, carr["connectivity"], f"{where} connectivity", int(offs[-1]),
                       f"offsets end at {offs[-1]}")
        if conn.dtype.kind not in "iu":
            raise VtuError(f"{path}: {where}: connectivity array is {conn.dtype}, not integer")
        # each connectivity entry becomes a node's coordinates and value, copied twice below
        limits.check_bytes(conn.size * 64, f"{where}: the cells' node coordinates and values")
        conn = conn.astype(np.int64)
        if conn.size and (conn.min() < 0 or conn.max() >= npts):
            c = int(np.searchsorted(offs, int(np.flatnonzero((conn < 0) | (conn >= npts))[0]), side="right"))
            raise VtuError(f"{path}: cell {base + c}: point index out of range (piece has {npts} points)")

        pdel = piece.find("PointData")
        farr = [a for a in _point_arrays(piece) if a.attrib.get("Name") == field]
        vals = _decode(src, farr[0], f"{where} field {field!r}", npts * ncomp, f"{npts} points x {ncomp}")
        vals, field_name = _select_component(path, vals.astype(np.float64, copy=False), field, ncomp, component)

        rw_name = pdel.attrib.get("RationalWeights") if pdel is not None else None
        weights = None
        if rw_name:
            w = [a for a in _point_arrays(piece) if a.attrib.get("Name") == rw_name]
            if w:
                weights = _decode(src, w[0], f"{where} rational weights", npts, f"{npts} points")

        degs_all = None
        cdel = piece.find("CellData")
        if cdel is not None:
            hod_name = cdel.attrib.get("HigherOrderDegrees", "HigherOrderDegrees")
            hod = [a for a in cdel if a.attrib.get("Name") == hod_name]
            if hod:
                d = _decode(src, hod[0], f"{where} HigherOrderDegrees", 3 * ncells, f"{ncells} cells x 3")
                if not np.all(np.isfinite(d)) or np.any(d != np.round(d)):
                    raise VtuError(f"{path}: {where}: HigherOrderDegrees are not all integers")
                degs_all = d.reshape(ncells, 3).astype(np.int64)

        for c in range(ncells):
            gc = base + c
            t = int(types[c])
            nodes = conn[starts[c]:offs[c]]
            if t in _PYRAMIDS:
                raise VtuError(f"{path}: cell {gc}: {_PYRAMIDS[t]} is not supported (VTK's pyramid space "
                               "differs from the Nektar++ pyramid expansion this renderer evaluates)")
            if t not in CELL_TYPES:
                raise VtuError(f"{path}: cell {gc}: VTK cell type {t} is not supported "
                               "(3-D Lagrange/Bézier tetrahedra, hexahedra and wedges are)")
            tname, shape, family = CELL_TYPES[t]
            n = nodes.size
            if family == "linear":
                degs = (1, 1, 1)
            elif degs_all is not None and shape != TET:
                degs = tuple(int(x) for x in degs_all[c])
                if shape == PRISM and degs[0] != degs[1]:
                    raise VtuError(f"{path}: cell {gc}: {tname} HigherOrderDegrees {degs}: the triangle "
                                   "degrees must agree")
            else:  # VTK's tetrahedra ignore HigherOrderDegrees too
                degs = _infer_degs(shape, n)
                if degs is None:
                    raise VtuError(f"{path}: cell {gc}: {tname} with {n} nodes matches no complete degree")
            if min(degs) < 1 or max(degs) > MAX_MODES - 1:
                raise VtuError(f"{path}: cell {gc}: {tname} degrees {degs}; 1..{MAX_MODES - 1} are supported")
            if _node_count(shape, degs) != n:
                raise VtuError(f"{path}: cell {gc}: {tname} of degrees {degs} needs "
                               f"{_node_count(shape, degs)} nodes, has {n}")
            x = pts[nodes]
            v = vals[nodes]
            if not np.all(np.isfinite(x)):
                raise VtuError(f"{path}: cell {gc}: node coordinates are NaN or Inf")
            if not np.all(np.isfinite(v)):
                raise VtuError(f"{path}: cell {gc}: field {field_name!r} is NaN or Inf at a node")
            if family == "bezier" and weights is not None and np.any(weights[nodes] != 1.0):
                raise VtuError(f"{path}: cell {gc}: rational Bézier cells (RationalWeights != 1) are not polynomial")
            cell_shape.append(shape)
            cell_family.append("lagrange" if family == "linear" else family)
            cell_degs.append(degs)
            cell_nodes.append(x)
            cell_vals.append(v)
        base += ncells

    if not cell_shape:
        raise VtuError(f"{path}: the file has no cells")

    n = len(cell_shape)
    coeffs, gcoeffs, modes = [None] * n, [None] * n, [None] * n
    groups = {}
    for e in range(n):
        groups.setdefault((cell_shape[e], cell_family[e], cell_degs[e]), []).append(e)
    for (shape, family, degs), members in groups.items():
        v8 = vtk8 and shape == HEX and family != "linear"
        md = modes_for(shape, degs)
        X = np.stack([cell_nodes[e] for e in members])  # (n, N, 3)
        V = np.stack([cell_vals[e] for e in members])  # (n, N)
        T = conversion_matrix(shape, family, degs, v8)
        with np.errstate(over="ignore", invalid="ignore"):  # overflow is diagnosed below
            G = np.matmul(T, X)  # (n, K, 3)
            C = V @ T.T
        flip = _orientation(path, shape, md, G, X, members)
        if flip.any():
            Tm = conversion_matrix(shape, family, degs, v8, True)
            G[flip] = np.matmul(Tm, X[flip])
            C[flip] = V[flip] @ Tm.T
        for i, e in enumerate(members):
            coeffs[e], gcoeffs[e], modes[e] = C[i], G[i], md
    return VolumeMesh.from_elements(cell_shape, modes, coeffs, modes, gcoeffs, field_name=field_name, source=str(path))


def _orientation(path, shape, modes, G, X, members):
    """(n,) bool: cells to read mirrored (Jacobian negative at every sample point). Cells whose
    Jacobian det(dx/dxi) changes sign or vanishes (inverted corners, tangled curved cells,
    collapsed cells) raise VtuError."""
    D = _jacobian_probe(shape, modes)  # (S, K, 3)
    n, k = G.shape[:2]
    s = D.shape[0]
    with np.errstate(over="ignore", invalid="ignore"):
        J = (G.transpose(0, 2, 1).reshape(n * 3, k) @ D.transpose(1, 0, 2).reshape(k, s * 3))
        det = np.linalg.det(J.reshape(n, 3, s, 3).transpose(0, 2, 1, 3))  # (n, S): J[e, s, c, d]
        h = np.ptp(X, axis=1).max(axis=1)  # cell size
        tol = 1e-12 * h**3
    # finite coordinates can still be too large for the test (and the geometry) in doubles:
    # an inf/NaN Jacobian or tolerance is neither inverted nor degenerate
    big = np.flatnonzero(~(np.isfinite(tol) & np.isfinite(det).all(axis=1)))
    if big.size:
        i = big[0]
        raise VtuError(f"{path}: cell {members[i]}: node coordinates too large (up to "
                       f"{np.abs(X[i]).max():.3g}): the geometry overflows double precision")
    lo, hi = det.min(axis=1), det.max(axis=1)
    for i in np.flatnonzero(~((lo > tol) | (hi < -tol))):
        gc = members[i]
        if h[i] == 0 or (hi[i] <= tol[i] and lo[i] >= -tol[i]):
            what = "degenerate (zero volume)"
        elif lo[i] > -tol[i] or hi[i] < tol[i]:
            what = f"degenerate (Jacobian determinant vanishes: {lo[i]:.3g} .. {hi[i]:.3g})"
        else:
            what = f"inverted or tangled (Jacobian determinant changes sign: {lo[i]:.3g} .. {hi[i]:.3g})"
        raise VtuError(f"{path}: cell {gc}: {what}")
    return hi < -tol
