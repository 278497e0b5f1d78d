"""MFEM inside Blender: the registry gives File > Import > HOVR MFEM (.mesh); an import finds the
GridFunction beside the mesh; each vendored mesh and GridFunction (tests/data/mfem: curved mixed
meshes, v1.0, v1.2, v1.3, pyramids, a variable-order field) makes a volume that F12 renders as the
engine renders the same read; a GridFunction cut short is reported in one line with the scene
unchanged."""
import numpy as np
import pytest

bpy = pytest.importorskip("bpy", reason="bpy (Blender as a Python module) is not installed")
pytestmark = pytest.mark.blender

from hovr_blender.io.mfem.format import read_mfem  # noqa: E402  (the parser, in this process)
from hovr_blender.io.sources import VolumeSource, load_volume  # noqa: E402
from hovr_blender.ui import import_operators  # noqa: E402

from ..helpers import data_file  # noqa: E402
from ..data.mfem import VENDORED, camera_for  # noqa: E402
from .blender_helpers import f12_and_engine  # noqa: E402

W, H = 24, 20


def test_the_gridfunction_beside_the_mesh_is_imported(scene, tmp_path):
    mesh = tmp_path / "zoo.mesh"
    mesh.write_bytes(data_file("mfem", "zoo.mesh").read_bytes())
    (tmp_path / "zoo-u.gf").write_bytes(data_file("mfem", "zoo-u.gf").read_bytes())
    assert import_operators.OPERATORS["mfem"].menu_text == "HOVR MFEM (.mesh)"
    assert bpy.ops.import_scene.hovr_mfem(filepath=str(mesh), frame=False) == {'FINISHED'}
    obj = bpy.context.active_object
    assert obj.hovr.is_volume and obj.hovr.field == "zoo-u" and obj.hovr.solution.endswith("zoo-u.gf")
    assert obj.hovr.value_min < obj.hovr.value_max


@pytest.mark.parametrize("mesh_name,gf_name", VENDORED)
def test_each_vendored_file_renders_after_an_import(scene, tmp_path, mesh_name, gf_name):
    """Imported with its GridFunction named, F12 renders it as the engine renders the same read."""
    mesh, gf = data_file("mfem", mesh_name), data_file("mfem", gf_name)
    assert bpy.ops.import_scene.hovr_mfem(filepath=str(mesh), solution=str(gf), frame=False) == {'FINISHED'}
    obj = bpy.context.active_object
    read = load_volume(VolumeSource(str(mesh), str(gf), ""))  # F12's read: in a reader process
    here = read_mfem(mesh, gf)  # BLAS on more threads here than there: the same to rounding
    np.testing.assert_allclose(here.coeffs, read.coeffs, rtol=0, atol=1e-10)
    img, engine = f12_and_engine(scene, obj, read, camera_for(mesh_name), W, H, 2.0, tmp_path)
    assert np.ptp(img[..., :3]) > 0.05
    np.testing.assert_allclose(img, engine, atol=1e-5)


def test_a_damaged_gridfunction_is_reported_and_the_scene_kept(scene, tmp_path):
    mesh = tmp_path / "zoo.mesh"
    mesh.write_bytes(data_file("mfem", "zoo.mesh").read_bytes())
    gf = data_file("mfem", "zoo-u.gf").read_bytes()
    (tmp_path / "zoo-u.gf").write_bytes(gf[: len(gf) // 2])  # cut in half
    before = len(bpy.data.objects)
    with pytest.raises(RuntimeError) as caught:
        bpy.ops.import_scene.hovr_mfem(filepath=str(mesh), frame=False)
    assert "zoo-u.gf" in str(caught.value) and len(bpy.data.objects) == before
