"""Mutation test of the .vtu reader, quick form of tests/fuzz/vtu_mutation.py: every mutation kind on
every vtk-written encoding (in-process: none of these can hang the reader) must load or raise a
VtuError that names the file and is not read_vtu's catch-all; the mutator itself is checked
(re-encoding round trip, a change it writes is seen); and the corruptions that found reader bugs
are pinned with the diagnosis they must get."""
from __future__ import annotations

import re

import numpy as np
import pytest

from hovr_blender.io.vtu import VtuError, read_vtu

from ..helpers import data_file as shared_file


@pytest.fixture(scope="module")
def vtk_files(vm, tmp_path_factory):
    tmp = tmp_path_factory.mktemp("vtu_sources")
    out = {enc: vm.write_vtk_lagrange(tmp / f"{enc}.vtu", **kw) for enc, kw in vm.VTK_ENCODINGS.items()}
    out["raw-none"] = vm.write_vtk_lagrange(tmp / "raw-none.vtu", mode="raw", header=32, compressor=None)
    return out


def expect(path, data, pattern, field="g"):
    """data written to path must raise a VtuError naming the file whose message matches pattern."""
    path.write_bytes(data)
    with pytest.raises(VtuError) as info:
        read_vtu(path, field)
    msg = str(info.value)
    assert msg.startswith(f"{path}: ") and type(info.value) is VtuError, msg
    assert ": unreadable (" not in msg, msg  # read_vtu's catch-all: an undiagnosed reader bug
    assert re.search(pattern, msg), msg
    return msg


def same_mesh(a, b):
    return (np.array_equal(a.coeffs, b.coeffs) and np.array_equal(a.geom_coeffs, b.geom_coeffs)
            and np.array_equal(a.shape, b.shape))


def test_reencoding_round_trip_and_edits_are_seen(vm, vtk_files, tmp_path):
    """Every array decoded and re-encoded in its file's own encoding reads back identically (the
    real PyFR file too: two pieces, raw UInt64 blocks, moved offsets); a changed field is seen."""
    files = dict(vtk_files)
    files["pyfr"] = shared_file("vtu", "pyfr_tgv_hexprism_p4_t4.vtu")
    for name, path in files.items():
        field = "Density" if name == "pyfr" else "g"
        doc = vm.Doc(path.read_bytes())
        q = tmp_path / f"{name}_identity.vtu"
        q.write_bytes(doc.identity())
        orig = read_vtu(path, field)
        assert same_mesh(orig, read_vtu(q, field)), name
        a = next(a for a in doc.arrays if a.name == field and a.piece == 0)
        q.write_bytes(doc.with_values(a, doc.values(a) + 1.0))
        shifted = read_vtu(q, field)
        # +1 at every node of piece 0: the constant mode moves, the geometry does not
        assert np.array_equal(shifted.geom_coeffs, orig.geom_coeffs), name
        assert not np.array_equal(shifted.coeffs, orig.coeffs), name


def test_every_kind_on_every_encoding(vm):
    """4 encodings x 17 kinds (the bench's first 68 cases): loaded or a diagnosed VtuError."""
    n = len(vm.VTK_ENCODINGS) * len(vm.KINDS)
    s = vm.run_cases(n, seed=7, in_process=True, only=["vtk"])
    assert s["cases"] == n and set(s["by_kind"]) == set(vm.KINDS)
    assert set(s["outcomes"]) <= {"loaded", "vtu_error"}, s["failures"]
    assert s["outcomes"].get("vtu_error", 0) > 0 and s["outcomes"].get("loaded", 0) > 0, s["outcomes"]


def test_cell_level_corruptions_get_their_diagnosis(vm, vtk_files, tmp_path):
    for enc in ("ascii", "raw-lzma-uint64"):
        doc = vm.Doc(vtk_files[enc].read_bytes())
        conn, offs, pts = (doc.find(0, "Cells", "connectivity"), doc.find(0, "Cells", "offsets"),
                           doc.find(0, "Points"))
        C, O = doc.values(conn).copy(), doc.values(offs)
        P = doc.values(pts).reshape(-1, 3).copy()
        c1 = slice(int(O[0]), int(O[1]))  # cell 1: the cubic hexahedron
        p = tmp_path / f"{enc}.vtu"
        bad = C.copy()
        bad[int(O[0]) + 5] = P.shape[0]
        expect(p, doc.with_values(conn, bad), r"cell 1: point index out of range")
        bad = C.copy()
        bad[int(O[0])], bad[int(O[0]) + 6] = C[int(O[0]) + 6], C[int(O[0])]
        expect(p, doc.with_values(conn, bad), r"cell 1: inverted or tangled")
        Q = P.copy()
        Q[C[c1][3], 1] = np.nan
        expect(p, doc.with_values(pts, Q.ravel()), r"cell 1: node coordinates are NaN or Inf")
        Q = P.copy()
        Q[C[c1], 2] = Q[C[c1], 2].mean()
        expect(p, doc.with_values(pts, Q.ravel()), r"cell 1: degenerate")
        Q = P.copy()
        Q[C[c1], 0] = 2 * Q[C[c1], 0].mean() - Q[C[c1], 0]  # mirrored in place: valid
        p.write_bytes(doc.with_values(pts, Q.ravel()))
        assert read_vtu(p, "g").num_elements == O.size
        t = doc.values(doc.find(0, "Cells", "types")).copy()
        t[2] = 74
        expect(p, doc.with_values(doc.find(0, "Cells", "types"), t), r"cell 2: VTK_LAGRANGE_PYRAMID")


def test_raw_appended_damage_is_diagnosed(vm, vtk_files, tmp_path):
    """Found by the mutation test: meshio's raw-appended parser raised AssertionError,
    RuntimeError, LZMAError, UnicodeDecodeError or ParseError on truncated files, block sizes
    that miss the next offset and broken compressed blocks; the reader's own decoding names each."""
    p = tmp_path / "bad.vtu"
    for enc in ("raw-lzma-uint64", "raw-none"):
        doc = vm.Doc(vtk_files[enc].read_bytes())
        raw = doc.raw
        expect(p, raw[: doc.app_start + 100], r"truncated \(<AppendedData> has no closing tag\)")
        pts = doc.find(0, "Points")
        blk = doc.block(pts)
        if doc.compressor is None:
            blk.header[0] += 8  # nbytes larger than the block: the next offset is missed
            want = r"piece 0 points: its data header declares \d+ bytes, the piece needs \d+ \(\d+ points x 3"
        else:
            payload = bytearray(blk.payload)
            payload[len(payload) // 2] ^= 0x40
            blk.payload = bytes(payload)
            want = r"piece 0 points block 0: not a valid lzma stream"
        expect(p, doc.build((), {pts.index: doc.encode_block(blk)}), want)
        expect(p, doc.build([doc.attr_edit(pts.tag, "offset", "-1")]),
               r"piece 0 points: offset -1 is outside the appended data \(\d+ bytes\)")
        expect(p, doc.build([doc.attr_edit(doc.app_tag, "encoding", "Float128")]),
               r"<AppendedData> encoding 'Float128'")
    doc = vm.Doc(vtk_files["raw-lzma-uint64"].read_bytes())
    s, e = doc.vtkfile_tag
    m = re.search(rb'\scompressor="[^"]*"', doc.raw[s:e])
    # the compression header's block count read as an uncompressed size
    expect(p, doc.build([(s + m.start(), s + m.end(), b"")]), r"piece 0 points: its data header declares 1 bytes")


def test_overflowing_coordinates_are_named(vm, vtk_files, tmp_path):
    """Found by the mutation test: a finite node coordinate of 1e308 made the Jacobian test
    overflow, and the cell was reported 'inverted or tangled (Jacobian determinant changes sign:
    nan .. nan)'."""
    doc = vm.Doc(vtk_files["binary-zlib"].read_bytes())
    conn, offs, pts = doc.find(0, "Cells", "connectivity"), doc.find(0, "Cells", "offsets"), doc.find(0, "Points")
    O = doc.values(offs)
    nodes = doc.values(conn)[int(O[0]):int(O[1])]
    for big in (1e308, -1e308):
        P = doc.values(pts).reshape(-1, 3).copy()
        P[nodes[3], 0] = big
        expect(tmp_path / "big.vtu", doc.with_values(pts, P.ravel()), r"cell 1: .* too large for double precision")
