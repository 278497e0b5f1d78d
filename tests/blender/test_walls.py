"""Import > Walls as Mesh: the domain's boundary, or a Nektar++ file's chosen boundary regions, as
a triangle mesh beside the HOVR volume (engine/walls.py), and the volume still renders; hump3D's
hump wall shaded by Cycles under its exact volume (the user guide's picture: HOVR_UPDATE_DOCS=1
copies it into docs/)."""
import math
import os
import shutil

import numpy as np
import pytest

bpy = pytest.importorskip("bpy", reason="bpy (Blender as a Python module) is not installed")
pytestmark = pytest.mark.blender

from hovr_blender.ui.blender_camera import ray_camera_from_blender  # noqa: E402
from hovr_blender.engine import image_io  # noqa: E402
from hovr_blender.engine import walls as core_walls  # noqa: E402
from hovr_blender.engine.opaque import OpaqueMesh, OpaqueScene  # noqa: E402
from hovr_blender.io import sources  # noqa: E402
from hovr_blender.io.nektar import mesh_boundaries, read_nektar  # noqa: E402

from ..helpers import REPO, data_file  # noqa: E402
from .blender_helpers import (add_camera, material, render_to_exr, set_contract_camera, set_look,  # noqa: E402
                              set_world)

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


def test_import_options_list_the_files_regions(scene):
    """With Walls as Mesh ticked, the Nektar++ import options list the boundary regions and face
    composites Walls From can name."""
    from types import SimpleNamespace

    import time

    from hovr_blender.ui.import_operators import OPERATORS, _poll_listings

    labels = []

    class Layout:
        def __getattr__(self, name):
            def call(*args, **kwargs):
                if name == "label":
                    labels.append(kwargs.get("text", ""))
                return Layout()
            return call

    op = SimpleNamespace(layout=Layout(), filepath=str(data_file("nektar", "hump3D_GLL.xml")), solution="hump3D.rst",
                         field="", fit_range=True, frame=True, walls=True, walls_tolerance=1e-3, walls_from="")
    OPERATORS["nektar"].draw(op, bpy.context)
    if labels == ["Reading the file's composites..."]:  # the reader lists them; a timer redraws then
        deadline = time.monotonic() + 60
        while _poll_listings() is not None and time.monotonic() < deadline:
            time.sleep(0.05)
        labels.clear()
        OPERATORS["nektar"].draw(op, bpy.context)
    assert labels[:3] == ["Walls From (empty: all boundary faces):", "B[0]: C[1] WallViscous", "B[1]: C[2] Dirichlet"]
    assert "C[1]: 160 faces (in B[0])" in labels
    labels.clear()
    op.walls = False
    OPERATORS["nektar"].draw(op, bpy.context)
    assert labels == []


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


# hump3D (a 20 x 10 x 3 mm channel; the hump, 1.16 mm high, at x = 50 mm, y = 0): the camera low
# over the upstream corner looking at the hump; the volume is the x-momentum's iso-shell at half
# the free stream's (rhou = 27 of 54), draped over the hump, in blue; the wall a sand Cycles material
HUMP_VIEW = {"eye": [0.0435, -0.006, 0.0028], "target": [0.0503, 0.0, 0.0005], "up": [0.0, 0.0, 1.0],
             "fov_y_deg": 23.2}
HUMP_W, HUMP_H = 480, 270
BLUE = (0.05, 0.4, 1.0)
HUMP_STOPS = [(0.0, (*BLUE, 0.0)), (0.45, (*BLUE, 0.0)), (0.5, (*BLUE, 1.0)), (0.55, (*BLUE, 0.0)),
              (1.0, (*BLUE, 0.0))]
HUMP_WORLD = (0.05, 0.055, 0.065)
HUMP_WALL = (0.5, 0.47, 0.42)
HUMP_DOC_IMAGE = "user-guide-walls-hump3D.png"


def _eroded(mask, r=2):
    """The pixels of `mask` whose whole (2r+1)^2 neighbourhood is in it."""
    padded = np.pad(mask, r, constant_values=False)
    out = np.ones_like(mask)
    h, w = mask.shape
    for dy in range(2 * r + 1):
        for dx in range(2 * r + 1):
            out &= padded[dy: dy + h, dx: dx + w]
    return out


@pytest.mark.slow
def test_hump3d_wall_in_cycles_under_the_exact_volume(scene, tmp_path):
    """hump3D imported with only its hump wall (B[0], WallViscous) as walls, the wall shaded by
    Cycles and the volume by HOVR, composited by Set Up Compositing: the wall is where its
    triangles project (cast here from the core's tessellation), the volume is HOVR's pass laid
    over it, and F12 is their alpha-over."""
    xml, rst = data_file("nektar", "hump3D_GLL.xml"), data_file("nektar", "hump3D.rst")
    assert bpy.ops.import_scene.hovr_nektar(filepath=str(xml), solution=str(rst), field="rhou", walls=True,
                                            walls_from="B[0]", frame=False, fit_range=False) == {'FINISHED'}
    volume = bpy.context.active_object
    wall = bpy.data.objects[f"{volume.name} Walls"]
    geometry = read_nektar(str(xml))
    expect = core_walls.tessellate(geometry, core_walls.default_tolerance(geometry),
                                   faces=mesh_boundaries(xml).select("B[0]"))
    assert len(expect.element) == 160 and len(wall.data.polygons) == len(expect.triangles)
    np.testing.assert_allclose(_walls_vertices(wall), expect.vertices, atol=1e-9)

    wall.data.materials.append(material("Wall", HUMP_WALL, roughness=0.45))
    set_look(volume, HUMP_STOPS, (0.0, 54.0), 50.0, units="RELATIVE")
    camera = add_camera(scene)
    set_contract_camera(scene, HUMP_VIEW, HUMP_W, HUMP_H)
    camera.data.clip_start, camera.data.clip_end = 1e-4, 0.1  # a 2 cm domain, 1 cm away
    set_world(scene, HUMP_WORLD)
    sun = bpy.data.objects.new("Sun", bpy.data.lights.new("Sun", 'SUN'))
    sun.data.energy = 2.0
    sun.rotation_euler = (math.radians(40), math.radians(10), math.radians(-30))
    scene.collection.objects.link(sun)
    s = scene.hovr
    s.method, s.tolerance, s.device = "split", 1e-4, "cpu"  # split: the shell is a thin tent
    assert bpy.ops.hovr.setup_compositing(engine="CYCLES") == {'FINISHED'}
    other = bpy.data.scenes[scene.name + " Surfaces"]
    other.cycles.samples, other.cycles.use_denoising, other.cycles.device, other.cycles.seed = 16, False, 'CPU', 3
    composed = render_to_exr(scene, tmp_path / "composed.exr")
    image_io.write_png(tmp_path / HUMP_DOC_IMAGE, composed, alpha=False)
    cycles = render_to_exr(other, tmp_path / "cycles.exr")
    scene.render.use_compositing = False
    hovr = render_to_exr(scene, tmp_path / "hovr.exr")

    # F12 is Alpha Over of HOVR's pass on Cycles' image
    np.testing.assert_allclose(composed, hovr + (1.0 - hovr[..., 3:4]) * cycles, atol=1 / 255)
    # where the wall projects: the core's tessellation cast with the render's camera rays
    ray_camera = ray_camera_from_blender(scene.camera, bpy.context.evaluated_depsgraph_get(), scene.render)
    hits = OpaqueScene([OpaqueMesh(expect.vertices, expect.triangles, name="wall")]).cast(ray_camera)
    hit = hits.hit
    on_wall, off_wall = _eroded(hit), _eroded(~hit)
    assert on_wall.mean() > 0.5 and off_wall.mean() > 0.1
    o, d = ray_camera.rays()
    z = (o + np.where(hit, hits.t, 0.0)[..., None] * d)[..., 2]
    assert (on_wall & (z > 0.0004)).sum() > 300  # the hump's upper part is in view
    # Cycles: the wall's shading where it projects, the world's colour elsewhere
    np.testing.assert_allclose(cycles[off_wall][:, :3], np.broadcast_to(HUMP_WORLD, (off_wall.sum(), 3)), atol=1e-3)
    assert np.abs(cycles[on_wall][:, :3] - HUMP_WORLD).max(axis=1).min() > 0.01
    np.testing.assert_allclose(cycles[..., 3], 1.0, atol=1e-6)
    # HOVR: the shell in front of the wall, translucent, over all of it; and beyond it
    a = hovr[..., 3]
    print(f"hump3D: wall {on_wall.mean():.2f} of the image, HOVR alpha on the wall "
          f"{np.percentile(a[on_wall], [5, 50, 95]).round(3).tolist()}, beside it {np.percentile(a[off_wall], [5, 50, 95]).round(3).tolist()}")
    assert np.all(a[on_wall] < 0.99) and np.mean(a[on_wall] > 0.05) > 0.9
    assert np.mean(np.abs(composed - cycles)[..., :3].max(axis=-1) > 0.02) > 0.5  # the volume is in the picture
    if os.environ.get("HOVR_UPDATE_DOCS"):
        shutil.copy(tmp_path / HUMP_DOC_IMAGE, REPO / "docs" / HUMP_DOC_IMAGE)
