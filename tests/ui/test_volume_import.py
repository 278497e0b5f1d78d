"""bpy-free parts of File > Import: the domain outline, the mesh cache keyed by file stamps,
the component setting (ui/scene.py)."""
import os
import shutil

import numpy as np
import pytest

from hovr_blender.ui import scene as bs
from hovr_blender.engine.outline import outline_edges
from hovr_blender.io import sources
from hovr_blender.io import synthetic
from tests.helpers import data_file as shared_file


def _surface_counts(verts, edges):
    return len(verts), len(edges)


def test_outline_of_a_mixed_cube_is_its_surface():
    """Four shapes sharing faces: only faces on the cube's surface remain, drawn as their edges."""
    mesh = synthetic.mixed_cube(3, 2, lambda x, y, z: x)
    verts, edges = outline_edges(mesh)
    on_surface = (np.isclose(verts, 0) | np.isclose(verts, 1)).any(axis=1)
    assert on_surface.all() and len(verts) > 0
    mid = 0.5 * (verts[edges[:, 0]] + verts[edges[:, 1]])
    assert (np.isclose(mid, 0) | np.isclose(mid, 1)).any(axis=1).all()
    # all 8 cube corners and the 12 cube edges' grid points are there; no interior vertex
    grid = np.linspace(0, 1, 4)
    corners = np.array([[a, b, c] for a in (0, 1) for b in (0, 1) for c in (0, 1)], float)
    assert all(np.isclose(verts, c).all(axis=1).any() for c in corners)
    assert all(np.isclose(verts, [g, 0, 0]).all(axis=1).any() for g in grid)
    assert len(np.unique(edges, axis=0)) == len(edges) and (edges[:, 0] != edges[:, 1]).all()


def test_outline_of_nektar_tets_is_a_closed_triangulated_surface():
    from hovr_blender.io.nektar import read_nektar

    mesh = read_nektar(shared_file("nektar", "Tet_channel_m3.xml"), shared_file("nektar", "Tet_channel_m3.fld"), "u")
    verts, edges = outline_edges(mesh)
    # a closed triangulated sphere-like surface: E = 3F/2 and V - E + F = 2
    F = 2 * len(edges) // 3
    assert 2 * len(edges) % 3 == 0 and len(verts) - len(edges) + F == 2
    lo, hi = mesh.vertices.reshape(-1, 3).min(0), mesh.vertices.reshape(-1, 3).max(0)
    assert ((np.isclose(verts, lo) | np.isclose(verts, hi)).any(axis=1)).all()  # a box channel


def test_parse_component():
    assert sources.parse_component("") is None and sources.parse_component("  ") is None
    assert sources.parse_component("Magnitude") == "magnitude" and sources.parse_component("2") == 2
    with pytest.raises(sources.SourceError, match="component 'x'"):
        sources.parse_component("x")


def test_component_enters_the_key_and_the_reader(tmp_path):
    import meshio

    pts = np.array([[0, 0, 0], [1, 0, 0], [1, 1, 0], [0, 1, 0], [0, 0, 1], [1, 0, 1], [1, 1, 1], [0, 1, 1]], float)
    vel = np.c_[pts[:, 0] + 1, pts[:, 1], -pts[:, 2]]
    path = tmp_path / "v.vtu"
    meshio.write(str(path), meshio.Mesh(pts, [("hexahedron", np.arange(8)[None])], point_data={"vel": vel}),
                 binary=False)
    a = sources.VolumeSource.resolve(str(path), "", "vel", 1)
    b = sources.VolumeSource.resolve(str(path), "", "vel", 1, component="1")
    assert a.key != b.key and a.key == (str(path), "", "vel", a.stamps)  # no component: the old key
    assert sources.load_volume(b).field_name == "vel[1]"
    assert sources.load_volume(a).field_name == "|vel|" and hasattr(sources.load_volume(a), "derived_error")
    with pytest.raises(sources.SourceError, match="component"):
        sources.load_volume(sources.VolumeSource.resolve(str(path), "", "vel", component="y"))


def test_cached_volume_rereads_only_changed_files(tmp_path):
    for name in ("Tet_channel_m3.xml", "Tet_channel_m3.fld"):
        shutil.copy(shared_file("nektar", name), tmp_path / name)
    xml, fld = tmp_path / "Tet_channel_m3.xml", tmp_path / "Tet_channel_m3.fld"
    sources.clear_cache()
    src = sources.VolumeSource.resolve(str(xml), str(fld), "u", 1)
    first = sources.cached_volume(src)
    assert sources.cached_volume(sources.VolumeSource.resolve(str(xml), str(fld), "u", 1)) is first  # unchanged: no read
    st = os.stat(fld)
    os.utime(fld, ns=(st.st_atime_ns, st.st_mtime_ns + 2_000_000_000))  # touched: same size, new mtime
    second = sources.cached_volume(sources.VolumeSource.resolve(str(xml), str(fld), "u", 1))
    assert second is not first
    np.testing.assert_array_equal(second.coeffs, first.coeffs)
    with open(xml, "a") as f:  # grown (a trailing comment): another size
        f.write("<!-- edited -->\n")
    third = sources.cached_volume(sources.VolumeSource.resolve(str(xml), str(fld), "u", 1))
    assert third is not second
    assert len(sources._MESHES) <= sources._MESHES.size
    sources.clear_cache()
