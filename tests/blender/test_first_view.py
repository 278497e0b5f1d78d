"""Issue 40: `hovr render FILE` (no view file) is Blender's first F12 after File > Import with the
defaults into its factory startup scene, at the same size, to within 1e-6 (bit for bit, as it
happens): the same solution and field, value range, look, Frame Camera (engine/first_view.py, one
home), on vendored files and, where ../shared/data has them, shared ones. Each case imports into a
factory scene, renders F12 at 64x36 and runs the CLI on the file."""
import numpy as np
import pytest

bpy = pytest.importorskip("bpy", reason="bpy (Blender as a Python module) is not installed")
pytestmark = pytest.mark.blender

import hovr_blender  # noqa: E402
from hovr_blender import cli  # noqa: E402

from ..helpers import data_file  # noqa: E402
from .blender_helpers import render_to_exr  # noqa: E402

W, H = 64, 36
IMPORTERS = {".xml": "hovr_nektar", ".vtu": "hovr_vtu", ".pyfrm": "hovr_pyfr", ".mesh": "hovr_mfem"}


@pytest.mark.parametrize("kind,name", [
    ("nektar", "hump3D_GLL.xml"),  # curved hexahedra, the solution hump3D.rst found by its name
    ("vtu", "mfem_fichera_cells_p4.vtu"),  # mixed Lagrange cells
    ("pyfr", "shell.pyfrm"),  # PyFR's own files
    ("vtu", "pyfr_tgv_hexprism_p4_t4.vtu"),  # shared: hexahedra and prisms, a vector shown as its magnitude
])
def test_hovr_render_of_a_data_file_is_blenders_first_f12(kind, name, tmp_path, capsys):
    path = data_file(kind, name)
    bpy.ops.wm.read_factory_settings(use_empty=False)
    hovr_blender.register()
    try:
        scene = bpy.context.scene
        scene.render.engine = "HOVR"
        scene.render.resolution_x, scene.render.resolution_y, scene.render.resolution_percentage = W, H, 100
        assert getattr(bpy.ops.import_scene, IMPORTERS[path.suffix])(filepath=str(path)) == {'FINISHED'}
        f12 = render_to_exr(scene, tmp_path / "f12.exr")
    finally:
        hovr_blender.unregister()
        bpy.ops.wm.read_factory_settings(use_empty=True)
    out = tmp_path / "cli.npy"
    assert cli.main(["render", str(path), "--size", f"{W}x{H}", "-o", str(out)]) == 0
    capsys.readouterr()
    rgba = np.load(out)
    assert rgba[..., 3].max() > 0.05  # the volume is in the picture
    assert np.abs(f12[..., :3] - rgba[..., :3]).max() <= 1e-6
