"""The minimal Nektar++ reader on ElVis's test hexahedron and on malformed variants of it."""
from __future__ import annotations

import base64
import re
import zlib
from pathlib import Path

import numpy as np
import pytest

from hovr_blender.engine.mesh import MeshError
from hovr_blender.io.nektar import NektarError, read_nektar

DATA = Path(__file__).parents[2].parent / "shared" / "data" / "nektar"
STEM = "Hex_01_01_01_03Modes_x2_Offset3"

pytestmark = pytest.mark.skipif(
    not (DATA / f"{STEM}.xml").exists(), reason=f"Nektar++ test data not found at {DATA} (../shared/data/nektar)"
)


def encode(values) -> str:
    """Nektar++'s body encoding: zlib, NUL-padded to a multiple of 3, base64 without '=' (spec §2.3)."""
    raw = zlib.compress(np.asarray(values, dtype="<f8").tobytes())
    raw += b"\0" * (-len(raw) % 3)
    return base64.b64encode(raw).decode()


def original():
    return (DATA / f"{STEM}.xml").read_text(), (DATA / f"{STEM}.fld").read_text()


def original_values():
    body = re.search(r">([^<]+)</ELEMENTS>", original()[1]).group(1)
    return np.frombuffer(zlib.decompress(base64.b64decode(body + "=" * (-len(body) % 4))), "<f8")


def write(tmp_path, xml=None, fld=None):
    x, f = original()
    (tmp_path / "m.xml").write_text(x if xml is None else xml)
    (tmp_path / "m.fld").write_text(f if fld is None else fld)
    return tmp_path / "m.xml"


def with_body(values):
    return re.sub(r">[^<]+</ELEMENTS>", f">{encode(values)}</ELEMENTS>", original()[1])


def test_elvis_hexahedron_reproduces_the_sphere_field():
    mesh = read_nektar(DATA / f"{STEM}.xml")
    assert mesh.num_elements == 1
    assert mesh.field_name == "p"
    assert mesh.modes[0].tolist() == [3, 3, 3]
    lo, hi = mesh.bounds()
    np.testing.assert_array_equal(lo[0], [-1, -1, -4])
    np.testing.assert_array_equal(hi[0], [1, 1, -2])
    x = np.random.default_rng(0).uniform([-1, -1, -4], [1, 1, -2], (200, 3))
    np.testing.assert_allclose(mesh.evaluate(0, x), (x * x).sum(axis=1), rtol=0, atol=1e-12)


def test_explicit_solution_and_field_name_and_nul_padding(tmp_path):
    vals = original_values()
    raw = zlib.compress(vals.astype("<f8").tobytes()) + b"\0" * 6  # trailing NULs after the stream
    fld = re.sub(r">[^<]+</ELEMENTS>", f">{base64.b64encode(raw).decode().rstrip('=')}</ELEMENTS>", original()[1])
    path = write(tmp_path, fld=fld)
    sol = tmp_path / "other.fld"
    sol.write_text(fld)
    (tmp_path / "m.fld").unlink()
    mesh = read_nektar(path, sol, field="p")
    np.testing.assert_array_equal(mesh.coeffs, vals)


def test_field_needed_when_no_fld_beside_the_mesh(tmp_path):
    path = write(tmp_path)
    (tmp_path / "m.fld").unlink()
    with pytest.raises(NektarError, match="field is needed"):
        read_nektar(path)


def test_unknown_or_ambiguous_field_lists_the_fields(tmp_path):
    vals = original_values()
    two = with_body(np.concatenate([vals, 2 * vals])).replace('FIELDS="p"', 'FIELDS="p,q"')
    path = write(tmp_path, fld=two)
    with pytest.raises(NektarError, match="p, q"):
        read_nektar(path)
    mesh = read_nektar(path, field="q")
    np.testing.assert_array_equal(mesh.coeffs, 2 * vals)
    with pytest.raises(NektarError, match="no field 'u'.*p, q"):
        read_nektar(path, field="u")


def malformed_cases():
    x, f = original()
    vals = original_values()
    nan = vals.copy()
    nan[5] = np.nan
    body = re.search(r">([^<]+)</ELEMENTS>", f).group(1)
    return {
        "truncated mesh XML": (x[: len(x) // 2], None, "not well-formed XML", "m.xml"),
        "truncated field XML": (None, f[:200], "not well-formed XML", "m.fld"),
        "corrupted base64": (None, f.replace(body, body[:20] + "!!" + body[22:]), "not valid base64", "m.fld"),
        "corrupted zlib": (None, f.replace(body, body[:30] + ("A" if body[30] != "A" else "B") + body[31:]), "zlib", "m.fld"),
        "truncated zlib": (None, with_body(vals).replace(encode(vals), encode(vals)[:-12]), "zlib", "m.fld"),
        "wrong coefficient count": (None, with_body(vals[:-1]), "26 values, expected 27", "m.fld"),
        "NaN coefficient": (None, with_body(nan), "element 0, field 'p'.*NaN", "m.fld"),
        "missing face": (re.sub(r'<Q ID="5">[^<]*</Q>', "", x), None, "hexahedron 0 refers to missing face 5", "m.xml"),
        "missing vertex": (re.sub(r'<V ID="6">[^<]*</V>', "", x), None, "edge 6 refers to missing vertex 6", "m.xml"),
        "bad vertex": (x.replace("<V ID=\"2\">1 1 -4</V>", "<V ID=\"2\">1 one -4</V>"), None, "vertex 2", "m.xml"),
        "wrong faces": (x.replace('<H ID="0">0 1 2 3 4 5</H>', '<H ID="0">0 1 2 3 4 4</H>'), None, "local vertex", "m.xml"),
        "missing element in field": (None, f.replace('ID="0"', 'ID="1"'), r"no coefficients for mesh element\(s\) \[0\]", "m.fld"),
        "DOCTYPE": (x.replace("<NEKTAR>", '<!DOCTYPE NEKTAR [<!ENTITY a "b">]>\n<NEKTAR>', 1), None, "DOCTYPE", "m.xml"),
    }


@pytest.mark.parametrize("case", list(malformed_cases()))
def test_malformed_input_raises_nektar_error_naming_file_and_record(tmp_path, case):
    xml, fld, pattern, name = malformed_cases()[case]
    path = write(tmp_path, xml, fld)
    with pytest.raises(NektarError, match=pattern) as info:
        read_nektar(path)
    assert name in str(info.value)


def unsupported_cases():
    x, f = original()
    curved = '<CURVED><E ID="0" EDGEID="0" NUMPOINTS="3" TYPE="PolyEvenlySpaced">-1 -1 -4 0 -1.1 -4 1 -1 -4</E></CURVED>'
    return {
        "curved": (x.replace("<COMPOSITE>", curved + "<COMPOSITE>"), None, "CURVED"),
        "compressed mesh": (x.replace("<VERTEX>", '<VERTEX COMPRESSED="B64Z-LittleEndian">'), None, "compressed VERTEX"),
        "prism element": (x.replace('<H ID="0">', '<R ID="0">').replace("</H>", "</R>"), None, "element 0 is a prism"),
        "other shape in field": (None, f.replace('SHAPE="Hexahedron"', 'SHAPE="Prism"'), "SHAPE='Prism'"),
        "other basis": (None, f.replace("Modified_A,Modified_A,Modified_A", "GLL_Lagrange,GLL_Lagrange,GLL_Lagrange"), "BASIS"),
        "mixorder": (None, f.replace("UNIORDER:3,3,3", "MIXORDER:3,3,3"), "MIXORDER"),
        "big endian": (None, f.replace("<ELEMENTS ", '<ELEMENTS COMPRESSED="B64Z-BigEndian" '), "B64Z-BigEndian"),
    }


@pytest.mark.parametrize("case", list(unsupported_cases()))
def test_unsupported_input_is_refused_clearly(tmp_path, case):
    xml, fld, pattern = unsupported_cases()[case]
    path = write(tmp_path, xml, fld)
    with pytest.raises(NektarError, match=pattern) as info:
        read_nektar(path)
    assert "m.xml" in str(info.value) or "m.fld" in str(info.value)


def test_non_parallelepiped_hex_raises_mesh_error_with_the_file_name(tmp_path):
    x, _ = original()
    path = write(tmp_path, x.replace('<V ID="6">1 1 -2</V>', '<V ID="6">1.5 1 -2</V>'))
    with pytest.raises(MeshError, match=r"m\.xml: element 0: hexahedron is not a parallelepiped"):
        read_nektar(path)
