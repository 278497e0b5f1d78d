"""PyFR inside Blender: the registry gives File > Import > HOVR PyFR (.pyfrm); importing the
vendored shell case (tests/data/pyfr) finds its solution beside the mesh, makes a volume, and
F12 renders it as the engine renders the same read; a damaged solution is reported in one line
with the scene unchanged."""
import numpy as np
import pytest

bpy = pytest.importorskip("bpy", reason="bpy (Blender as a Python module) is not installed")
pytestmark = pytest.mark.blender

from hovr_blender.io.pyfr.format import read_pyfr  # noqa: E402  (the parser, in this process)
from hovr_blender.io.sources import VolumeSource, load_volume  # noqa: E402
from hovr_blender.ui import import_operators  # noqa: E402

from ..helpers import data_file  # noqa: E402
from .blender_helpers import f12_and_engine  # noqa: E402

W, H = 24, 20
CONTRACT = {"eye": [2.2, -1.6, 1.9], "target": [0.5, 0.45, 0.5], "up": [0.0, 0.0, 1.0], "fov_y_deg": 40.0}


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


def test_pyfr_import_renders_like_the_engine(scene, tmp_path):
    mesh = data_file("pyfr", "shell.pyfrm")
    assert import_operators.OPERATORS["pyfr"].menu_text == "HOVR PyFR (.pyfrm)"
    assert bpy.ops.import_scene.hovr_pyfr(filepath=str(mesh), field="rho", frame=False) == {'FINISHED'}
    obj = bpy.context.active_object
    assert obj.hovr.is_volume and obj.hovr.field == "rho" and obj.hovr.solution.endswith("shell-0.02.pyfrs")
    assert 0.4 < obj.hovr.value_min < 1.0 < obj.hovr.value_max < 1.6
    solution = data_file("pyfr", "shell-0.02.pyfrs")
    read = load_volume(VolumeSource(str(mesh), str(solution), "rho"))  # F12's read: in a reader process
    here = read_pyfr(mesh, solution, "rho")  # BLAS on more threads here than there: the same to rounding
    np.testing.assert_allclose(here.coeffs, read.coeffs, rtol=0, atol=1e-10)
    np.testing.assert_allclose(here.geom_coeffs, read.geom_coeffs, rtol=0, atol=1e-10)
    img, engine = f12_and_engine(scene, obj, read, CONTRACT, W, H, 2.0, tmp_path)
    assert np.ptp(img[..., :3]) > 0.05
    np.testing.assert_allclose(img, engine, atol=1e-5)


def test_a_damaged_solution_is_reported_and_the_scene_kept(scene, tmp_path):
    mesh = tmp_path / "shell.pyfrm"
    mesh.write_bytes(data_file("pyfr", "shell.pyfrm").read_bytes())
    soln = bytearray(data_file("pyfr", "shell-0.02.pyfrs").read_bytes())
    (tmp_path / "shell-0.02.pyfrs").write_bytes(bytes(soln[: len(soln) // 2]))  # cut in half
    before = len(bpy.data.objects)
    with pytest.raises(RuntimeError) as caught:
        bpy.ops.import_scene.hovr_pyfr(filepath=str(mesh), field="rho", frame=False)
    assert "shell-0.02.pyfrs" in str(caught.value) and len(bpy.data.objects) == before
