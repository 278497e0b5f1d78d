"""A Nektar++ mesh's composites and boundary regions (io/nektar/composites.py): the faces a
composite lists as (element, face) pairs, checked against the file's own face vertices; the
boundary regions of hump3D, whose union is the domain's whole boundary; and clear errors for
selections the file cannot satisfy."""
from __future__ import annotations

import re

import numpy as np
import pytest

from hovr_blender.engine import shapes, walls
from hovr_blender.io.nektar import NektarError, mesh_boundaries, read_nektar
from hovr_blender.io.nektar.mesh_file import read_mesh
from hovr_blender.io.nektar.ranges import expand_ranges, parse_ranges
from hovr_blender.io.nektar.topology import face_vertices

from ..helpers import data_dir

DATA = data_dir("nektar")
HUMP = "hump3D_GLL.xml"


def _listed_face_ids(composite):
    """The face IDs a composite lists, as composite_faces orders them (by ID within each list)."""
    lists = re.finditer(r"([A-Z])\s*\[([^\]]*)\]", composite.text)
    return np.concatenate([np.unique(expand_ranges(parse_ranges(m.group(2), "", ""))) for m in lists])


@pytest.mark.parametrize("name", ["CubeAllElements.xml", "Womersley_PipeFlow.xml", HUMP, "Pyr_channel_m6.xml"])
def test_composite_faces_are_the_files_faces(name):
    """Every face composite's (element, face): the element's corners on that face (VolumeMesh
    vertices at FACE_PLANES' face) are the Nektar++ face's own vertices; faces of all four shapes."""
    path = DATA / name
    mesh = read_nektar(path)  # geometry only: none of these has a field file named like it
    file_mesh = read_mesh(path)
    b = mesh_boundaries(path)
    assert b.face_composites
    for comp in b.face_composites:
        elem, face = b.composite_faces(comp.id)
        ids = _listed_face_ids(comp)
        assert len(elem) == len(ids) == comp.declared_count
        for e, f, fid in zip(elem.tolist(), face.tolist(), ids.tolist()):
            got = mesh.vertices[e][shapes.plane_vertices(int(mesh.shape[e]))[f]]
            want = np.array([file_mesh.vertices[v] for v in face_vertices(file_mesh, fid)])
            assert len(got) == len(want), (comp.id, fid)
            # each corner of the element's face is one of the file face's vertices, and all are met
            match = np.abs(got[:, None, :] - want[None, :, :]).max(axis=2) < 1e-12
            assert match.any(axis=1).all() and match.any(axis=0).all(), (name, comp.id, fid)
    on = {int(mesh.shape[e]) for c in b.face_composites for e in b.composite_faces(c.id)[0]}
    assert on == {"CubeAllElements.xml": {shapes.HEX, shapes.PRISM, shapes.TET},  # its pyramids are inside
                  "Womersley_PipeFlow.xml": {shapes.PRISM, shapes.TET}, HUMP: {shapes.HEX},
                  "Pyr_channel_m6.xml": {shapes.PYR}}[name]


def test_hump3d_regions_and_its_wall():
    b = mesh_boundaries(DATA / HUMP)
    assert sorted(b.regions) == [0, 1, 2, 3, 4, 5]
    assert [b.regions[r].composites for r in range(6)] == [(1,), (2,), (3,), (4,), (5,), (6,)]
    assert b.regions[0].conditions == ("WallViscous",)
    assert b.regions[3].conditions == ("PressureOutflow",)
    assert b.regions[4].conditions == ("Periodic",)
    assert [c.id for c in b.face_composites] == [1, 2, 3, 4, 5, 6]  # C[0] holds the hexahedra
    choices = dict(b.choices())
    assert choices["B[0]"] == "B[0]: C[1] WallViscous" and choices["C[1]"] == "C[1]: 160 faces (in B[0])"

    mesh = read_nektar(DATA / HUMP)
    # the regions together are the domain's whole boundary, each face once
    e, f = b.select("B[0-5]")
    be, bf = walls.boundary_faces(mesh)
    assert len(e) == len(be) == 1288
    assert set(zip(e.tolist(), f.tolist())) == set(zip(be.tolist(), bf.tolist()))

    # the wall: B[0], its composite, its condition type and its name select the same 160 faces
    wall = b.select("B[0]")
    for text in ("C[1]", "wallviscous", " C[1], B[0] "):
        np.testing.assert_array_equal(np.stack(b.select(text)), np.stack(wall))
    assert len(wall[0]) == 160 and b.select("") is None and b.select("  ") is None
    # the bottom of the channel (z = 0) with the hump, 1.16 mm high, in the middle
    corners = np.concatenate([mesh.vertices[e][shapes.plane_vertices(shapes.HEX)[f]] for e, f in zip(*wall)])
    assert corners[:, 2].min() == 0.0 and corners[:, 2].max() == pytest.approx(0.00116454, abs=1e-8)
    peak = corners[np.argmax(corners[:, 2])]
    assert peak[0] == pytest.approx(0.05) and abs(peak[1]) < 1e-12
    np.testing.assert_allclose(corners[:, :2].min(axis=0), [0.04, -0.005])
    np.testing.assert_allclose(corners[:, :2].max(axis=0), [0.06, 0.005])
    top = b.select("C[2]")
    assert np.all(np.concatenate([mesh.vertices[e][shapes.plane_vertices(shapes.HEX)[f]]
                                  for e, f in zip(*top)])[:, 2] == 0.003)


@pytest.mark.parametrize("selection, message", [
    ("C[0]", "composite C[0] holds hexahedra (H[...]), not faces; the file's face composites are C[1], C[2]"),
    ("C[9]", "no composite C[9]"),
    ("C[5-8]", "no composite C[7]"),
    ("B[6]", "no boundary region B[6]; the file has B[0], B[1], B[2], B[3], B[4], B[5]"),
    ("hump", "no composite or boundary region named 'hump' (choose from: B[0]: C[1] WallViscous;"),
    ("X[1]", "'X[1]' is neither C[...] (composites) nor B[...] (boundary regions)"),
    ("C[2-1]", "bad ID range"),
])
def test_bad_selections_on_hump3d(selection, message):
    b = mesh_boundaries(DATA / HUMP)
    with pytest.raises(NektarError, match=re.escape(message)):
        b.select(selection)


def _variant(tmp_path, name, composites="", regions=None, faces=""):
    """A copy of Pyr_channel_m6.xml (6 pyramids, plain text) with composites, faces and boundary
    regions added or replaced."""
    text = (DATA / "Pyr_channel_m6.xml").read_text()
    text = text.replace("</COMPOSITE>", composites + "</COMPOSITE>")
    text = text.replace("</FACE>", faces + "</FACE>")
    if regions is not None:
        text = re.sub(r"<BOUNDARYREGIONS>.*?</BOUNDARYREGIONS>", f"<BOUNDARYREGIONS>{regions}</BOUNDARYREGIONS>",
                      text, flags=re.S)
    path = tmp_path / name
    path.write_text(text)
    return path


def test_pyramid_channel_names_interior_faces_and_conditions(tmp_path):
    path = _variant(tmp_path, "named.xml",
                    composites='<C ID="7" NAME="Cut"> T[1] </C><C ID="8"> Q[0] T[1] </C>',
                    regions='<B ID="0" NAME="Inlet"> C[1] </B><B ID="1"> C[6] </B><B ID="2" NAME="Walls"> C[2-5] </B>')
    b = mesh_boundaries(path)
    assert b.regions[0].name == "Inlet" and b.regions[2].composites == (2, 3, 4, 5)
    assert b.regions[0].conditions == ("Dirichlet", "H")  # D entries without a type, then USERDEFINEDTYPE="H"
    assert b.regions[1].conditions == ("Neumann", "Dirichlet")
    np.testing.assert_array_equal(np.stack(b.select("inlet")), np.stack(b.select("B[0]")))
    assert len(b.select("walls")[0]) == 4
    # face 1, a triangle shared by pyramids 0 (its second face) and 1: given once, on pyramid 0,
    # as FACE_PLANES' face of Nektar++'s local face 1 (vertices 0, 1, 4: the plane xi1 = -1)
    assert shapes.PLANE_OF_FACE[shapes.PYR][1] == 1
    for text in ("Cut", "C[7]"):
        e, f = b.select(text)
        assert e.tolist() == [0] and f.tolist() == [1]
    e, f = b.select("C[8]")  # a quadrilateral and a triangle in one composite
    assert sorted(zip(e.tolist(), f.tolist())) == [(0, 1), (0, 2)]
    # an interior face is tessellated like any other: one triangle
    mesh = read_nektar(path)
    w = walls.tessellate(mesh, faces=b.select("Cut"))
    assert len(w.triangles) == 1 and w.element.tolist() == [0]


@pytest.mark.parametrize("composites, regions, faces, selection, message", [
    ('<C ID="7"> F[40] </C>', None, "", "C[7]", "composite C[7] refers to missing face 40"),
    ('<C ID="7"> T[0] </C>', None, "", "C[7]", "composite C[7] lists T[0] but face 0 is a quadrilateral"),
    ('<C ID="7"> Q[1] </C>', None, "", "C[7]", "composite C[7] lists Q[1] but face 1 is a triangle"),
    ('<C ID="7"> F[18] </C>', None, '<Q ID="18"> 0 1 2 3 </Q>', "C[7]",
     "composite C[7]: face 18 is on no element of the DOMAIN"),
    ('<C ID="7"> E[0-3] </C>', None, "", "C[7]", "composite C[7] holds edges (E[...]), not faces"),
    ('<C ID="7"> </C>', None, "", "C[7]", "composite C[7] lists nothing"),
    ("", "<B ID=\"0\"> C[1] </B><B ID=\"0\"> C[2] </B>", "", "B[0]", "boundary region B[0] is defined twice"),
    ("", "<B ID=\"0\"> C[9] </B>", "", "B[0]", "boundary region B[0] names missing composite C[9]"),
    ("", "<B ID=\"0\"> F[1] </B>", "", "B[0]", "boundary region B[0] must list composites as C[...]"),
    # a file whose regions name the composites over and over is refused before they are expanded
    ("", "".join(f'<B ID="{i}"> C[0-6] </B>' for i in range(200)), "", "B[0]",
     "the boundary regions name 1057 composites or more in all, for 7 composites; refused"),
])
def test_bad_composites_and_regions(tmp_path, composites, regions, faces, selection, message):
    path = _variant(tmp_path, "bad.xml", composites, regions, faces)
    with pytest.raises(NektarError, match=re.escape(message)):
        mesh_boundaries(path).select(selection)


def test_regions_from_a_separate_session_file(tmp_path):
    """The boundary regions in a session file beside a mesh without CONDITIONS."""
    text = (DATA / "Pyr_channel_m6.xml").read_text()
    mesh_only = tmp_path / "mesh.xml"
    mesh_only.write_text(re.sub(r"<CONDITIONS>.*?</CONDITIONS>", "", text, flags=re.S))
    session = tmp_path / "session.xml"
    session.write_text('<NEKTAR><CONDITIONS><BOUNDARYREGIONS><B ID="0" NAME="Outlet"> C[6] </B>'
                       "</BOUNDARYREGIONS></CONDITIONS></NEKTAR>")
    assert mesh_boundaries(mesh_only).regions == {}
    with pytest.raises(NektarError, match=re.escape("no boundary region B[0]; the file has no BOUNDARYREGIONS")):
        mesh_boundaries(mesh_only).select("B[0]")
    b = mesh_boundaries(mesh_only, session)
    assert b.regions[0].name == "Outlet" and b.regions[0].conditions == ()
    np.testing.assert_array_equal(np.stack(b.select("outlet")), np.stack(b.select("C[6]")))
    with pytest.raises(NektarError, match="no <CONDITIONS> section"):
        mesh_boundaries(mesh_only, mesh_only)
