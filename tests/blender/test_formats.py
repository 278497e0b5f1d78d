"""A toy format (tests/toy_format.py, one module and one registry line) inside Blender: the add-on
makes its File > Import operator and menu entry from the registry, the import makes a volume,
and F12 renders it as the engine does. The engine's side is tests/io/test_formats.py."""
import numpy as np
import pytest

bpy = pytest.importorskip("bpy", reason="bpy (Blender as a Python module) is not installed")
pytestmark = pytest.mark.blender

from hovr_blender.io import formats  # noqa: E402
from hovr_blender.ui import import_operators  # noqa: E402
from tests import toy_format  # noqa: E402

from .blender_helpers import f12_and_engine  # noqa: E402

W, H = 24, 16
CONTRACT = {"eye": [3.0, -2.2, 2.4], "target": [0.0, 0.0, 0.0], "up": [0.0, 0.0, 1.0], "fov_y_deg": 40.0}


@pytest.fixture
def toy_scene():
    """A fresh session whose add-on was registered with the toy format in the registry."""
    import hovr_blender

    formats.register(toy_format.FORMAT)  # the one registry line a new format needs
    bpy.ops.wm.read_factory_settings(use_empty=True)
    hovr_blender.register()
    try:
        scene = bpy.context.scene
        scene.render.engine = 'HOVR'
        yield scene
    finally:
        hovr_blender.unregister()
        formats.unregister("toy")
        bpy.ops.wm.read_factory_settings(use_empty=True)


def test_the_toy_format_gets_its_import_operator_and_menu_entry(toy_scene):
    assert list(import_operators.OPERATORS)[:2] == ["nektar", "vtu"]  # the users' own names, kept
    toy = import_operators.OPERATORS["toy"]
    assert toy.bl_idname == "import_scene.hovr_toy" and toy.menu_text == "HOVR Toy (.toy)"
    assert bpy.ops.import_scene.hovr_toy.get_rna_type().properties["filter_glob"].default == "*.toy"
    settings = set(bpy.ops.import_scene.hovr_toy.get_rna_type().properties.keys())
    assert {"field", "fit_range", "walls"} <= settings and not settings & {"solution", "component", "walls_from"}
    assert "solution" in bpy.ops.import_scene.hovr_nektar.get_rna_type().properties.keys()
    assert "component" in bpy.ops.import_scene.hovr_vtu.get_rna_type().properties.keys()


def test_an_imported_toy_volume_renders_like_the_engine(toy_scene, tmp_path):
    path = toy_format.write(tmp_path / "brick.toy")
    assert bpy.ops.import_scene.hovr_toy(filepath=str(path), frame=False) == {'FINISHED'}
    obj = bpy.context.active_object
    assert obj.hovr.is_volume and obj.hovr.source == str(path) and obj.hovr.field == "r2"
    assert obj.hovr.value_min == pytest.approx(0.0, abs=0.1) and obj.hovr.value_max == pytest.approx(3.0, abs=0.1)
    obj.location = (0.25, -0.5, 0.0)
    bpy.context.view_layer.update()
    img, engine = f12_and_engine(toy_scene, obj, toy_format.read(path, field="r2"), CONTRACT, W, H, 2.0, tmp_path)
    np.testing.assert_allclose(img, engine, atol=1e-5)
