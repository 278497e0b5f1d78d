"""A .vtu file opened: its header checked, the XML up to <AppendedData> parsed with ElementTree,
the appended data located; and what the XML says (version, pieces, point arrays).

The file is read through engine/limits.py (regular files only, size within the memory limit).
Reading is done here, not by meshio: its VtuReader refuses VTKFile versions other than 0.1/1.0
and keeps only the last <Piece>, and its decoders trust the block headers (unbounded, quadratic
inflation of zlib/lzma blocks; raw appended data re-encoded as base64).
"""
from __future__ import annotations

import re
from pathlib import Path

import numpy as np

from ...engine import limits
from .. import safe_xml
from .decoding import CODECS, NUMPY_TYPES, LoadedFile
from .errors import VtuError

_APPENDED_TAG = re.compile(rb"<AppendedData\b[^>]*>")
_APPENDED_MARK = re.compile(rb"\s*_")


def _tag_attributes(path, tag: bytes, name):
    try:
        return safe_xml.parse(tag[:-1].rstrip(b"/") + b"/>").attrib
    except (safe_xml.ParseError, safe_xml.XmlRefused) as exc:
        raise VtuError(f"{path}: malformed <{name}> element ({exc})") from None


def load(path: Path):
    """(root element, without the appended data; LoadedFile)."""
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
    header_type, compressor, byte_order = _file_attributes(path, head)
    # DTDs can define entities (exponential expansion, external files): no VTK writer emits one,
    # and safe_xml refuses them after decoding, whatever the file's encoding.
    try:
        root = safe_xml.parse(head + (b"</VTKFile>" if cut >= 0 else b""))
    except (safe_xml.XmlRefused, limits.ResourceLimitError) as exc:
        raise VtuError(f"{path}: {exc}") from None
    except safe_xml.ParseError as exc:
        raise VtuError(f"{path}: not well-formed XML ({exc})") from None
    appended, appended_base64 = _appended_data(path, raw, cut) if cut >= 0 else (None, False)
    order = {"LittleEndian": "<", "BigEndian": ">", None: "="}[byte_order]  # none: this machine's, as in VTK
    return root, LoadedFile(path, order, np.dtype(order + NUMPY_TYPES[header_type]), CODECS.get(compressor),
                            appended, appended_base64, limits.InflationBudget(len(raw), f"VTU file {path.name}"))


def _file_attributes(path, head):
    """(header_type, compressor, byte_order) of the <VTKFile> element, each one VTK writes."""
    match = re.search(rb"<VTKFile\b[^>]*>", head)
    if match is None:
        raise VtuError(f"{path}: not a VTK XML file (no <VTKFile> element)")
    attributes = _tag_attributes(path, match.group(0), "VTKFile")
    if attributes.get("type") != "UnstructuredGrid":
        raise VtuError(f"{path}: VTKFile type {attributes.get('type')!r}; only UnstructuredGrid (.vtu) is read")
    header_type = attributes.get("header_type", "UInt32")
    if header_type not in ("UInt32", "UInt64"):
        raise VtuError(f"{path}: header_type {header_type!r} (VTK writes UInt32 or UInt64)")
    compressor = attributes.get("compressor")
    if compressor is not None and compressor not in CODECS:
        raise VtuError(f"{path}: compressor {compressor!r} is not supported (vtkZLibDataCompressor and "
                       "vtkLZMADataCompressor are)")
    byte_order = attributes.get("byte_order")
    if byte_order not in (None, "LittleEndian", "BigEndian"):
        raise VtuError(f"{path}: byte_order {byte_order!r}")
    return header_type, compressor, byte_order


def _appended_data(path, raw, cut):
    """(the bytes after <AppendedData>'s '_' up to its closing tag, whether they are base64)."""
    tag = _APPENDED_TAG.match(raw, cut)
    if tag is None:
        raise VtuError(f"{path}: truncated (unterminated <AppendedData> tag)")
    encoding = _tag_attributes(path, tag.group(0), "AppendedData").get("encoding")
    if encoding not in ("raw", "base64"):
        raise VtuError(f"{path}: <AppendedData> encoding {encoding!r} (VTK writes raw or base64)")
    mark = _APPENDED_MARK.match(raw, tag.end())
    if mark is None:
        raise VtuError(f"{path}: no '_' marks the start of the appended data")
    end = raw.rfind(b"</AppendedData>")
    if end < mark.end():
        raise VtuError(f"{path}: truncated (<AppendedData> has no closing tag)")
    return memoryview(raw)[mark.end():end], encoding == "base64"


def version(path, root):
    """(major, minor); VTK treats a missing version as legacy (pre-2.1 hexahedron order)."""
    text = root.attrib.get("version")
    if text is None:
        return (0, 0)
    match = re.fullmatch(r"\s*(\d+)\.(\d+)\s*", text)
    if match is None:
        raise VtuError(f"{path}: unreadable VTKFile version {text!r}")
    return int(match.group(1)), int(match.group(2))


def pieces(path, root):
    grid = root.find("UnstructuredGrid")
    if grid is None:
        raise VtuError(f"{path}: no <UnstructuredGrid>")
    found = grid.findall("Piece")
    if not found:
        raise VtuError(f"{path}: no <Piece>")
    return found


def point_arrays(piece):
    point_data = piece.find("PointData")
    return [] if point_data is None else [a for a in point_data if a.tag == "DataArray"]


def _components(path, array, where):
    try:
        n = int(array.attrib.get("NumberOfComponents", "1") or "1")
    except ValueError:
        raise VtuError(f"{path}: {where}: NumberOfComponents {array.attrib.get('NumberOfComponents')!r}") from None
    if not 1 <= n <= 1024:
        raise VtuError(f"{path}: {where}: NumberOfComponents {n}")
    return n


def point_fields(path, all_pieces):
    """Point-data arrays present in every piece: {name: number of components}, file order."""
    found = None
    for index, piece in enumerate(all_pieces):
        here = {}
        for array in point_arrays(piece):
            name = array.attrib.get("Name")
            if name:
                here[name] = _components(path, array, f"piece {index} point array {name!r}")
        found = here if found is None else {k: v for k, v in found.items() if here.get(k) == v}
    return found or {}
