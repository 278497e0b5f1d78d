"""MFEM inside Blender: the registry gives File > Import > HOVR MFEM (.mesh); importing the
vendored zoo (tests/data/mfem, with pyramids) finds its GridFunction beside the mesh, makes a
volume, and F12 renders it as the engine renders the same read; a GridFunction cut short is
reported in one line with the scene unchanged."""
import numpy as np
import pytest

bpy = pytest.importorskip("bpy", reason="bpy (Blender as a Python module) is not installed")
pytestmark = pytest.mark.blender

from hovr_blender.io.mfem import read_mfem  # noqa: E402
from hovr_blender.ui import import_operators  # noqa: E402

from ..helpers import data_file  # noqa: E402
from .blender_helpers import f12_and_engine  # noqa: E402

W, H = 24, 20
CONTRACT = {"eye": [3.4, -2.6, 2.4], "target": [1.0, 0.5, 0.5], "up": [0.0, 0.0, 1.0], "fov_y_deg": 36.0}


@pytest.fixture
def scene():
    import hovr_blender

    bpy.ops.wm.read_factory_settings(use_empty=True)
    hovr_blender.register()
    try:
        sc = bpy.context.scene
        sc.render.engine = 'HOVR'
        yield sc
    finally:
        hovr_blender.unregister()
        bpy.ops.wm.read_factory_settings(use_empty=True)


def test_mfem_import_renders_like_the_engine(scene, tmp_path):
    mesh = tmp_path / "zoo.mesh"
    mesh.write_bytes(data_file("mfem", "zoo.mesh").read_bytes())
    (tmp_path / "zoo-u.gf").write_bytes(data_file("mfem", "zoo-u.gf").read_bytes())
    assert import_operators.OPERATORS["mfem"].menu_text == "HOVR MFEM (.mesh)"
    assert bpy.ops.import_scene.hovr_mfem(filepath=str(mesh), frame=False) == {'FINISHED'}
    obj = bpy.context.active_object
    assert obj.hovr.is_volume and obj.hovr.field == "zoo-u" and obj.hovr.solution.endswith("zoo-u.gf")
    assert obj.hovr.value_min < obj.hovr.value_max
    img, engine = f12_and_engine(scene, obj, read_mfem(mesh, tmp_path / "zoo-u.gf"), CONTRACT, W, H, 2.0, tmp_path)
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
