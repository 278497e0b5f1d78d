"""Minimal Nektar++ reader: straight hexahedra with Modified_A fields (ElVis's test hexahedron).

Mesh: plain (uncompressed) XML with VERTEX/V, EDGE/E, FACE/Q and ELEMENT/H (spec/formats.md §2.2);
local vertex i of a hex is the unique mesh vertex common to the three faces of
VertexFaceConnectivity (§2.11). Field: XML .fld ELEMENTS blocks, base64 + zlib float64
little-endian, field-major, then element, then coefficients with direction 0 fastest (§2.6).
Everything else (compressed sections, CURVED, other shapes/bases, MIXORDER, HDF5) is refused with
a NektarError naming the file and the record; malformed input raises NektarError too.
"""
from __future__ import annotations

import base64
import binascii
import re
import xml.etree.ElementTree as ET
import zlib
from pathlib import Path

import numpy as np

from ..engine.basis import MODIFIED_A
from ..engine.mesh import MeshError, VolumeMesh, affine_from_hex_vertices


class NektarError(ValueError):
    """A Nektar++ file this reader cannot use; the message names the file and the record."""


# Local vertex i of a hex = the vertex shared by these three faces (positions in the <H> entry).
HEX_VERTEX_FACES = ((0, 1, 4), (0, 1, 2), (0, 2, 3), (0, 3, 4), (1, 4, 5), (1, 2, 5), (2, 3, 5), (3, 4, 5))
_FORBIDDEN = (b"<!doctype", b"<!entity")


def _parse_xml(path: Path) -> ET.Element:
    try:
        raw = path.read_bytes()
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


def _ints(text, n, path, what):
    try:
        vals = [int(v) for v in (text or "").split()]
    except ValueError:
        raise NektarError(f"{path}: {what}: expected {n} integers, got {text!r}") from None
    if len(vals) != n:
        raise NektarError(f"{path}: {what}: expected {n} integers, got {len(vals)}")
    return vals


def _entity_id(node, path, what):
    try:
        return int(node.attrib["ID"])
    except (KeyError, ValueError):
        raise NektarError(f"{path}: {what} <{node.tag}> without a valid integer ID") from None


def _refuse_compressed(node, path, what):
    for n in (node, *list(node)):
        if "COMPRESSED" in n.attrib:
            raise NektarError(
                f"{path}: compressed {what} ({n.attrib['COMPRESSED']}) is not supported yet; "
                "convert with NekMesh in.xml out.xml:xml:uncompress"
            )


def _number(text, path, what):
    try:
        v = float(text)
    except (TypeError, ValueError):
        raise NektarError(f"{path}: {what}: {text!r} is not a number (expressions are not supported)") from None
    if not np.isfinite(v):
        raise NektarError(f"{path}: {what}: {text!r} is not finite")
    return v


def _read_mesh(path: Path):
    """(element IDs, (N, 8, 3) local-order vertices) of the hexahedra in ID order."""
    root = _parse_xml(path)
    geom = root.find("GEOMETRY")
    if geom is None:
        raise NektarError(f"{path}: no <GEOMETRY> section (a mesh file is needed)")
    if geom.attrib.get("DIM", "3").strip() != "3" or geom.attrib.get("SPACE", "3").strip() != "3":
        raise NektarError(f"{path}: GEOMETRY DIM={geom.attrib.get('DIM')} SPACE={geom.attrib.get('SPACE')}; only 3-D meshes")
    sections = {}
    for name in ("VERTEX", "EDGE", "FACE", "ELEMENT"):
        sec = geom.find(name)
        if sec is None:
            raise NektarError(f"{path}: GEOMETRY has no <{name}> section")
        _refuse_compressed(sec, path, name)
        sections[name] = sec
    curved = geom.find("CURVED")
    if curved is not None and len(curved):
        first = curved[0]
        raise NektarError(
            f"{path}: CURVED entries are not supported yet (first: <{first.tag} ID={first.attrib.get('ID')!r}"
            f" EDGEID/FACEID={first.attrib.get('EDGEID', first.attrib.get('FACEID'))!r}>)"
        )

    sec = sections["VERTEX"]
    scale = [_number(sec.attrib.get(k, "1"), path, f"VERTEX {k}") for k in ("XSCALE", "YSCALE", "ZSCALE")]
    move = [_number(sec.attrib.get(k, "0"), path, f"VERTEX {k}") for k in ("XMOVE", "YMOVE", "ZMOVE")]
    verts = {}
    for v in sec:
        i = _entity_id(v, path, "VERTEX")
        if v.tag != "V":
            raise NektarError(f"{path}: unexpected <{v.tag} ID={i}> in VERTEX")
        xyz = (v.text or "").split()
        if len(xyz) != 3:
            raise NektarError(f"{path}: vertex {i}: expected 3 coordinates, got {len(xyz)}")
        verts[i] = np.array([_number(c, path, f"vertex {i}") for c in xyz]) * scale + move
    edges = {}
    for e in sections["EDGE"]:
        i = _entity_id(e, path, "EDGE")
        edges[i] = _ints(e.text, 2, path, f"edge {i}")
        for v in edges[i]:
            if v not in verts:
                raise NektarError(f"{path}: edge {i} refers to missing vertex {v}")
    faces = {}
    for f in sections["FACE"]:
        i = _entity_id(f, path, "FACE")
        if f.tag not in ("Q", "T"):
            raise NektarError(f"{path}: unexpected <{f.tag} ID={i}> in FACE")
        ids = _ints(f.text, 4 if f.tag == "Q" else 3, path, f"face {f.tag} {i}")
        vs = set()
        for e in ids:
            if e not in edges:
                raise NektarError(f"{path}: face {i} refers to missing edge {e}")
            vs.update(edges[e])
        faces[i] = (f.tag, vs)
    elems = []
    for el in sections["ELEMENT"]:
        i = _entity_id(el, path, "ELEMENT")
        if el.tag != "H":
            shape = {"A": "tetrahedron", "P": "pyramid", "R": "prism"}.get(el.tag, el.tag)
            raise NektarError(f"{path}: element {i} is a {shape} (<{el.tag}>); only hexahedra <H> are supported yet")
        fids = _ints(el.text, 6, path, f"hexahedron {i}")
        fv = []
        for f in fids:
            if f not in faces:
                raise NektarError(f"{path}: hexahedron {i} refers to missing face {f}")
            if faces[f][0] != "Q":
                raise NektarError(f"{path}: hexahedron {i}: face {f} is a triangle")
            fv.append(faces[f][1])
        local = []
        for k, (a, b, c) in enumerate(HEX_VERTEX_FACES):
            common = fv[a] & fv[b] & fv[c]
            if len(common) != 1:
                raise NektarError(
                    f"{path}: hexahedron {i}: faces {fids[a]}, {fids[b]}, {fids[c]} share {len(common)} vertices, "
                    f"not exactly one (local vertex {k}); the face list does not describe a hexahedron"
                )
            local.append(verts[common.pop()])
        elems.append((i, np.stack(local)))
    if not elems:
        raise NektarError(f"{path}: the mesh has no elements")
    elems.sort(key=lambda t: t[0])
    ids = [i for i, _ in elems]
    if len(set(ids)) != len(ids):
        raise NektarError(f"{path}: duplicate element IDs")
    return ids, np.stack([v for _, v in elems])


def _parse_id_list(text, path, what):
    out = []
    for tok in (text or "").replace(" ", "").split(","):
        m = re.fullmatch(r"(\d+)(?:-(\d+))?", tok)
        if not m:
            raise NektarError(f"{path}: {what}: bad element ID list {text!r}")
        a = int(m.group(1))
        b = int(m.group(2)) if m.group(2) else a
        if b < a:
            raise NektarError(f"{path}: {what}: bad ID range {tok!r}")
        out.extend(range(a, b + 1))
    return out


def _decode_body(text, path, what):
    s = re.sub(r"\s+", "", text or "")
    if not s:
        raise NektarError(f"{path}: {what}: empty data")
    try:
        packed = base64.b64decode(s + "=" * (-len(s) % 4), validate=True)  # Nektar++ omits '=' padding
    except (binascii.Error, ValueError) as exc:
        raise NektarError(f"{path}: {what}: data is not valid base64 ({exc})") from exc
    d = zlib.decompressobj()
    try:
        raw = d.decompress(packed)
    except zlib.error as exc:
        raise NektarError(f"{path}: {what}: data is not a valid zlib stream ({exc})") from exc
    if not d.eof:
        raise NektarError(f"{path}: {what}: zlib stream is truncated")
    if d.unused_data.strip(b"\0"):  # NUL padding to a multiple of 3 is normal, anything else is not
        raise NektarError(f"{path}: {what}: {len(d.unused_data)} unexpected bytes after the zlib stream")
    if len(raw) % 8:
        raise NektarError(f"{path}: {what}: {len(raw)} bytes is not a whole number of float64 values")
    return np.frombuffer(raw, dtype="<f8").astype(np.float64)


def _read_field(path: Path, field):
    """{element ID: (modes (3,), coefficients)} of the chosen field, and its name."""
    if path.is_dir():
        raise NektarError(f"{path}: parallel field directories (Info.xml + P*.fld) are not supported yet")
    root = _parse_xml(path)
    blocks = root.findall("ELEMENTS")
    if not blocks:
        raise NektarError(f"{path}: no <ELEMENTS> blocks (HDF5 field files are not supported yet)")
    names = []
    for b in blocks:
        for n in b.attrib.get("FIELDS", "").split(","):
            if n.strip() and n.strip() not in names:
                names.append(n.strip())
    if field is None:
        if len(names) != 1:
            raise NektarError(f"{path}: holds fields {', '.join(names) or '(none)'}; name the one to render")
        field = names[0]
    elif field not in names:
        raise NektarError(f"{path}: no field {field!r}; it holds {', '.join(names)}")

    out = {}
    for k, b in enumerate(blocks):
        what = f"ELEMENTS block {k} (ID={b.attrib.get('ID', '?')})"
        shape = b.attrib.get("SHAPE", "")
        if shape != "Hexahedron":
            raise NektarError(f"{path}: {what}: SHAPE={shape!r}; only Hexahedron is supported yet")
        basis = [s.strip() for s in b.attrib.get("BASIS", "").split(",")]
        if basis != ["Modified_A"] * 3:
            raise NektarError(f"{path}: {what}: BASIS={b.attrib.get('BASIS')!r}; only Modified_A x3 is supported yet")
        for key in ("POINTSTYPE", "NUMPOINTSPERDIR", "HOMOGENEOUSLENGTHS"):
            if key in b.attrib:
                raise NektarError(f"{path}: {what}: {key} (point or homogeneous data) is not supported")
        comp = b.attrib.get("COMPRESSED", "B64Z-LittleEndian")
        if comp != "B64Z-LittleEndian" or b.attrib.get("BITSIZE", "64") != "64":
            raise NektarError(f"{path}: {what}: COMPRESSED={comp!r} BITSIZE={b.attrib.get('BITSIZE')!r}; only B64Z-LittleEndian 64-bit")
        order = b.attrib.get("NUMMODESPERDIR", "")
        m = re.fullmatch(r"\s*UNIORDER:\s*(\d+)\s*,\s*(\d+)\s*,\s*(\d+)\s*", order)
        if not m:
            kind = "MIXORDER (per-element orders) is" if order.strip().startswith("MIXORDER") else f"NUMMODESPERDIR={order!r} is"
            raise NektarError(f"{path}: {what}: {kind} not supported; expected UNIORDER:a,b,c")
        modes = np.array([int(g) for g in m.groups()])
        if np.any(modes < 1):
            raise NektarError(f"{path}: {what}: mode counts must be positive, got {order!r}")
        fields = [n.strip() for n in b.attrib.get("FIELDS", "").split(",")]
        if field not in fields:
            raise NektarError(f"{path}: {what}: lacks field {field!r} (has {', '.join(fields)})")
        ids = _parse_id_list(b.attrib.get("ID"), path, what)
        data = _decode_body(b.text, path, what)
        nc = int(np.prod(modes))
        want = len(fields) * len(ids) * nc
        if data.size != want:
            raise NektarError(
                f"{path}: {what}: {data.size} values, expected {want} "
                f"({len(fields)} fields x {len(ids)} elements x {nc} coefficients)"
            )
        block = data.reshape(len(fields), len(ids), nc)[fields.index(field)]
        for e, c in zip(ids, block):
            if not np.all(np.isfinite(c)):
                raise NektarError(f"{path}: {what}: element {e}, field {field!r}: coefficients contain NaN or Inf")
            if e in out:
                raise NektarError(f"{path}: {what}: element {e} appears twice")
            out[e] = (modes, c.copy())
    return out, field


def read_nektar(mesh_path, solution_path=None, field=None) -> VolumeMesh:
    """VolumeMesh of one field of a Nektar++ mesh (.xml) and its field file (.fld)."""
    mesh_path = Path(mesh_path)
    if solution_path is None:
        solution_path = mesh_path.with_suffix(".fld")
        if not solution_path.exists():
            raise NektarError(
                f"{mesh_path}: a field is needed: no solution file given and {solution_path.name} "
                "does not exist beside the mesh (set data.solution to the .fld/.chk/.rst)"
            )
    solution_path = Path(solution_path)
    ids, vertices = _read_mesh(mesh_path)
    coeffs, field = _read_field(solution_path, field)
    missing = [i for i in ids if i not in coeffs]
    if missing:
        raise NektarError(f"{solution_path}: no coefficients for mesh element(s) {missing[:10]}{' ...' if len(missing) > 10 else ''}")
    extra = sorted(set(coeffs) - set(ids))
    if extra:
        raise NektarError(f"{solution_path}: element(s) {extra[:10]} are not in the mesh {mesh_path.name}")
    try:
        for i, v in zip(ids, vertices):  # checked with Nektar++ IDs so the message names the right element
            affine_from_hex_vertices(v, element=i)
        return VolumeMesh.from_affine_hexes(
            vertices,
            np.stack([coeffs[i][0] for i in ids]),
            [coeffs[i][1] for i in ids],
            basis=MODIFIED_A,
            field_name=field,
            source=str(mesh_path),
        )
    except MeshError as exc:
        raise MeshError(f"{mesh_path}: {exc}") from exc
