"""Import > Walls as Mesh: the domain's boundary as a triangle mesh beside the HOVR volume
(core/walls.py), and the volume still renders."""
import shutil

import numpy as np
import pytest

bpy = pytest.importorskip("bpy", reason="bpy (Blender as a Python module) is not installed")
pytestmark = pytest.mark.blender

from hovr_blender.core import walls as core_walls  # noqa: E402
from hovr_blender.io import sources  # noqa: E402

from ..helpers import data_file  # noqa: E402
from .blender_helpers import add_camera, render_to_exr, set_contract_camera  # noqa: E402

ANNULUS = "RotPerBcs3D_Annulus"  # 60 curved hexahedra, 112 boundary faces, no field
VIEW = {"eye": [2.6, -1.9, 2.2], "target": [0.5, 0.5, 0.5], "up": [0.0, 0.0, 1.0], "fov_y_deg": 40.0}


def _walls_vertices(obj):
    co = np.empty(len(obj.data.vertices) * 3, np.float32)
    obj.data.vertices.foreach_get("co", co)
    return co.reshape(-1, 3)


def test_import_annulus_with_walls(scene, tmp_path):
    xml = tmp_path / f"{ANNULUS}.xml"
    shutil.copy(data_file("nektar", f"{ANNULUS}.xml"), xml)
    assert bpy.ops.import_scene.hovr_nektar(filepath=str(xml), frame=False, walls=True) == {'FINISHED'}
    volume = bpy.context.active_object
    assert volume.hovr.is_volume and volume.name == ANNULUS
    walls = bpy.data.objects[f"{ANNULUS} Walls"]
    assert walls.parent == volume and not walls.hovr.is_volume and walls.name in scene.objects
    bpy.context.view_layer.update()
    np.testing.assert_allclose(np.array(walls.matrix_world), np.array(volume.matrix_world))
    me = walls.data
    assert all(len(p.vertices) == 3 for p in me.polygons)
    n = len(me.polygons)
    # 112 faces of at least 2 triangles, curved ones refined, far below the cap's 112 x 2 x 64^2
    assert 2 * 112 < n < 20000
    # the core's tessellation at the default tolerance (1e-3 of the diagonal), exactly
    h = volume.hovr
    mesh = sources._MESHES.get(sources.VolumeSource.resolve(h.source, h.solution, h.field, scene.frame_current).key)
    expect = core_walls.tessellate(mesh, core_walls.default_tolerance(mesh, 1e-3))
    assert n == len(expect.triangles)
    np.testing.assert_allclose(_walls_vertices(walls), expect.vertices, atol=1e-6)
    r = np.hypot(*_walls_vertices(walls)[:, :2].T)
    assert r.min() > 0.3 - 2e-3 and r.max() < 1.0 + 2e-3

    # the volume still renders, the same with the walls as without (Surfaces are off by default)
    add_camera(scene)
    set_contract_camera(scene, VIEW, 24, 16)
    volume.hovr.value_min, volume.hovr.value_max = -1.0, 1.0  # the zero field mid-ramp: visible
    volume.hovr.density = 20.0
    with_walls = render_to_exr(scene, tmp_path / "with.exr")
    assert np.isfinite(with_walls).all() and with_walls[..., 3].max() > 0.05  # the volume is in view
    walls.hide_render = True
    without = render_to_exr(scene, tmp_path / "without.exr")
    np.testing.assert_array_equal(with_walls, without)


def test_walls_off_by_default_and_tolerance_option(scene, tmp_path):
    xml = tmp_path / f"{ANNULUS}.xml"
    shutil.copy(data_file("nektar", f"{ANNULUS}.xml"), xml)
    before = len(bpy.data.objects)
    assert bpy.ops.import_scene.hovr_nektar(filepath=str(xml), frame=False) == {'FINISHED'}
    assert len(bpy.data.objects) == before + 1 and f"{ANNULUS} Walls" not in bpy.data.objects
    assert bpy.ops.import_scene.hovr_nektar(filepath=str(xml), frame=False, walls=True,
                                            walls_tolerance=1e-4) == {'FINISHED'}
    volume = bpy.context.active_object
    fine = bpy.data.objects[f"{volume.name} Walls"]
    assert len(fine.data.polygons) > 10000  # 25304 at 1e-4 of the diagonal against 1604 at 1e-3


def test_vtu_import_has_the_option(scene, tmp_path):
    meshio = pytest.importorskip("meshio")
    pts = np.array([[0, 0, 0], [1, 0, 0], [1, 1, 0], [0, 1, 0], [0, 0, 1], [1, 0, 1], [1, 1, 1], [0, 1, 1]], float)
    path = tmp_path / "cube.vtu"
    meshio.write(str(path), meshio.Mesh(pts, [("hexahedron", np.arange(8)[None])], point_data={"s": pts[:, 2]}),
                 binary=False)
    assert bpy.ops.import_scene.hovr_vtu(filepath=str(path), frame=False, walls=True) == {'FINISHED'}
    walls = bpy.data.objects["cube Walls"]
    assert len(walls.data.polygons) == 12  # a straight hexahedron: 6 faces of 2 triangles
    assert walls.parent == bpy.context.active_object


def test_walls_from_a_boundary_region_and_add_walls(scene, tmp_path):
    """Walls From picks the annulus' boundary regions (B[3] its outer wall r = 1, B[4] the inner
    r = 0.3); a selection the file cannot satisfy cancels the import and names the composite;
    Add Walls makes another region's walls for the imported volume."""
    xml = tmp_path / f"{ANNULUS}.xml"
    shutil.copy(data_file("nektar", f"{ANNULUS}.xml"), xml)
    before = set(bpy.data.objects.keys())
    with pytest.raises(RuntimeError, match=r"composite C\[0\] holds hexahedra \(H\[\.\.\.\]\), not faces"):
        bpy.ops.import_scene.hovr_nektar(filepath=str(xml), frame=False, walls=True, walls_from="C[0]")
    assert set(bpy.data.objects.keys()) == before  # nothing made

    assert bpy.ops.import_scene.hovr_nektar(filepath=str(xml), frame=False, walls=True,
                                            walls_from="B[3]") == {'FINISHED'}
    volume = bpy.context.active_object
    outer = bpy.data.objects[f"{ANNULUS} Walls"]
    r = np.hypot(*_walls_vertices(outer)[:, :2].T)
    np.testing.assert_allclose(r, 1.0, atol=2e-3)  # within the tolerance (1e-3 of the diagonal) of the cylinder
    assert len(outer.data.polygons) < 1604  # less than the whole boundary

    bpy.context.view_layer.objects.active = volume
    assert bpy.ops.hovr.add_walls(walls_from="B[4]") == {'FINISHED'}
    inner = bpy.data.objects[f"{ANNULUS} Walls B[4]"]
    assert inner.parent == volume
    np.testing.assert_allclose(np.hypot(*_walls_vertices(inner)[:, :2].T), 0.3, atol=2e-3)
    bpy.context.view_layer.objects.active = volume
    assert bpy.ops.hovr.add_walls() == {'FINISHED'}  # empty: the whole boundary
    assert len(bpy.data.objects[f"{ANNULUS} Walls.001"].data.polygons) == 1604
    bpy.context.view_layer.objects.active = volume
    with pytest.raises(RuntimeError, match=r"no boundary region B\[0\]; the file has B\[1\]"):
        bpy.ops.hovr.add_walls(walls_from="B[0]")


def test_add_walls_of_a_vtu_volume_takes_no_composites(scene, tmp_path):
    meshio = pytest.importorskip("meshio")
    pts = np.array([[0, 0, 0], [1, 0, 0], [1, 1, 0], [0, 1, 0], [0, 0, 1], [1, 0, 1], [1, 1, 1], [0, 1, 1]], float)
    path = tmp_path / "cube.vtu"
    meshio.write(str(path), meshio.Mesh(pts, [("hexahedron", np.arange(8)[None])], point_data={"s": pts[:, 2]}),
                 binary=False)
    assert bpy.ops.import_scene.hovr_vtu(filepath=str(path), frame=False) == {'FINISHED'}
    with pytest.raises(RuntimeError, match=r"composites and boundary regions are a Nektar\+\+ mesh's"):
        bpy.ops.hovr.add_walls(walls_from="C[1]")
    assert bpy.ops.hovr.add_walls() == {'FINISHED'}
    assert len(bpy.data.objects["cube Walls"].data.polygons) == 12
