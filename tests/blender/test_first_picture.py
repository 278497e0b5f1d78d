"""Issue 16's first hour: real data imported with the importer's defaults into a factory-fresh
scene, then F12 through the scene camera, gives a picture (the volume covers >= 10% of the
frame with visible opacity, no warning); Frame Volume; solution discovery; the warnings of an
empty, faint or clipped render."""
import shutil

import numpy as np
import pytest

bpy = pytest.importorskip("bpy", reason="bpy (Blender as a Python module) is not installed")
pytestmark = pytest.mark.blender

import hovr_blender  # noqa: E402

from ..helpers import data_file  # noqa: E402
from .blender_helpers import render_to_exr, volume  # noqa: E402

PERCENT = 5  # of Blender's default 1920 x 1080: 96 x 54 pixels


@pytest.fixture
def factory_scene():
    """Blender's factory startup file (cube, light, camera, grey world), HOVR as the engine."""
    bpy.ops.wm.read_factory_settings(use_empty=False)
    hovr_blender.register()
    try:
        sc = bpy.context.scene
        sc.render.engine = 'HOVR'
        sc.render.resolution_percentage = PERCENT
        yield sc
    finally:
        hovr_blender.unregister()
        bpy.ops.wm.read_factory_settings(use_empty=True)


def coverage(img, background, threshold=0.02) -> float:
    """Share of pixels whose colour differs from the background by more than `threshold`."""
    return float((np.abs(img[..., :3] - np.asarray(background)[:3]).max(axis=2) > threshold).mean())


def f12(scene, path, capfd):
    capfd.readouterr()
    img = render_to_exr(scene, path)
    out = capfd.readouterr().out
    return img, [line for line in out.splitlines() if line.startswith("Warning")]


@pytest.mark.parametrize("kind,name,op", [
    ("nektar", "hump3D_GLL.xml", "hovr_nektar"),  # solution named hump3D.rst: found, not by the mesh's name
    ("vtu", "ngsolve_ball_poisson_hex_p6.vtu", "hovr_vtu"),
])
def test_import_defaults_then_f12_show_the_volume(factory_scene, tmp_path, capfd, kind, name, op):
    path = data_file(kind, name)
    scene = factory_scene
    camera = scene.camera
    assert getattr(bpy.ops.import_scene, op)(filepath=str(path)) == {'FINISHED'}
    obj = bpy.context.active_object
    if kind == "nektar":
        assert obj.hovr.solution.endswith("hump3D.rst") and obj.hovr.field == "rho"
    assert scene.camera == camera  # the scene's own camera, moved to frame the volume
    img, warnings = f12(scene, tmp_path / "f12.exr", capfd)
    share = coverage(img, scene.world.color)
    contrast = float(np.abs(img[..., :3] - np.asarray(scene.world.color)[:3]).max())
    print(f"{name}: volume covers {100 * share:.0f}% of the frame, largest contrast {contrast:.2f}")
    assert share >= 0.10 and contrast > 0.1
    assert warnings == []
    # the clip planes hold the volume: the default 0.1 m clip start would hide hump3D (2 cm)
    assert camera.data.clip_start < 0.1 or kind == "vtu"


def _ramp(obj):
    """The volume's ramp stops, flat: [position, r, g, b, a, position, ...]."""
    return [v for e in obj.hovr.transfer_function.color_ramp.elements for v in (e.position, *e.color)]


def _flat(stops):
    return [v for p, c in stops for v in (p, *c)]


def test_an_import_gets_the_look_chosen_from_its_data(factory_scene):
    """Issue 30: an import with the defaults gets scene.FIRST_LOOK (shells at the field's 10, 50
    and 90 % quantiles) placed by the field's own samples, with its Density; the smooth ramp of
    before stays a preset, and the other looks from the data are presets too."""
    from hovr_blender.ui import operators
    from hovr_blender.engine.looks import FIRST_LOOK, FIRST_LOOKS, TF_PRESETS, quantiles

    assert FIRST_LOOK == "QUANTILE_TENTS"
    assert bpy.ops.import_scene.hovr_nektar(filepath=str(data_file("nektar", "Tet_channel_m3.xml")), field="w") \
        == {'FINISHED'}
    obj = bpy.context.active_object
    values, weights = operators.volume_samples(obj, factory_scene)
    stops, density = FIRST_LOOKS[FIRST_LOOK][2](values, obj.hovr.value_min, obj.hovr.value_max, weights)
    assert _ramp(obj) == pytest.approx(_flat(stops), abs=1e-6) and obj.hovr.density == pytest.approx(density)
    assert obj.hovr.density_units == 'RELATIVE'
    top = max(stops, key=lambda st: st[1][3])[0]  # the opaque shell: w's 90 % quantile over the volume
    assert top == pytest.approx((quantiles(values, 0.9, weights) - obj.hovr.value_min)
                                / (obj.hovr.value_max - obj.hovr.value_min))

    assert bpy.ops.hovr.transfer_function_preset(preset="SMOOTH") == {'FINISHED'}  # today's look, by hand
    assert _ramp(obj) == pytest.approx(_flat(TF_PRESETS["SMOOTH"][2]), abs=1e-6)
    assert bpy.ops.hovr.transfer_function_preset(preset="MEDIAN_SHELL") == {'FINISHED'}
    shell = FIRST_LOOKS["MEDIAN_SHELL"][2](values, obj.hovr.value_min, obj.hovr.value_max, weights)
    assert _ramp(obj) == pytest.approx(_flat(shell[0]), abs=1e-6) and obj.hovr.density == pytest.approx(shell[1])


def test_a_constant_field_keeps_the_smooth_ramp(factory_scene):
    """No structure to place shells by: wss_3D_periodic's rho (constant) keeps the smooth ramp."""
    from hovr_blender.engine.looks import TF_PRESETS

    path = data_file("nektar", "wss_3D_periodic.xml")
    assert bpy.ops.import_scene.hovr_nektar(filepath=str(path), field="rho") == {'FINISHED'}
    obj = bpy.context.active_object
    assert _ramp(obj) == pytest.approx(_flat(TF_PRESETS["SMOOTH"][2]), abs=1e-6)
    assert obj.hovr.density == pytest.approx(4.0)


def test_frame_volume_brings_a_lost_volume_into_view(factory_scene, tmp_path, capfd):
    scene = factory_scene
    bpy.ops.hovr.add_sphere_volume()
    obj = bpy.context.active_object
    obj.scale = (0.01, 0.01, 0.01)  # a 5 cm volume: inside the default camera's clip start at 10 cm...
    cam = scene.camera
    cam.location = (0.03, -0.03, 0.02)  # ...seen from 4 cm away
    _, warnings = f12(scene, tmp_path / "before.exr", capfd)
    assert any("Clip Start" in w for w in warnings), warnings
    assert bpy.ops.hovr.frame_volume() == {'FINISHED'}
    img, warnings = f12(scene, tmp_path / "after.exr", capfd)
    assert warnings == [] and coverage(img, scene.world.color) >= 0.10
    assert 0 < cam.data.clip_start < (cam.location - obj.location).length - 0.025 * np.sqrt(3)


def test_empty_and_faint_renders_are_warnings(factory_scene, tmp_path, capfd):
    scene = factory_scene
    bpy.ops.hovr.add_sphere_volume()
    obj = bpy.context.active_object
    bpy.ops.hovr.frame_volume()
    obj.hovr.density = 1e-3
    _, warnings = f12(scene, tmp_path / "faint.exr", capfd)
    assert any("nearly transparent" in w for w in warnings), warnings
    obj.hovr.density = 4.0
    obj.location.x += 1000.0  # out of the camera's view
    _, warnings = f12(scene, tmp_path / "empty.exr", capfd)
    assert any("image is empty" in w for w in warnings), warnings


def test_frames_shaded_from_cached_segments_raise_no_empty_warning(factory_scene, tmp_path, capfd):
    """Issue 30: from a view's third F12 on, and after a ramp edit, the frame is shaded from cached
    segments (no field evaluations): the picture is there, and so no "empty" warning."""
    from hovr_blender.ui import render

    scene = factory_scene
    bpy.ops.hovr.add_sphere_volume()
    obj = bpy.context.active_object
    bpy.ops.hovr.frame_volume()
    first, warnings = f12(scene, tmp_path / "1.exr", capfd)
    assert warnings == [] and coverage(first, scene.world.color) >= 0.10
    for k in (2, 3):
        again, warnings = f12(scene, tmp_path / f"{k}.exr", capfd)
        assert warnings == [], (k, warnings)
    assert render.FINAL.cache is not None  # the third F12 was shaded from the second's segments
    np.testing.assert_allclose(again, first, atol=1e-5)
    obj.hovr.transfer_function.color_ramp.elements[0].color = (1.0, 0.2, 0.1, 1.0)
    edited, warnings = f12(scene, tmp_path / "edited.exr", capfd)
    assert warnings == [] and np.abs(edited - first).max() > 1e-3


def _tet_as(folder, mesh_name, solution_names):
    folder.mkdir(parents=True, exist_ok=True)
    shutil.copy(data_file("nektar", "Tet_channel_m3.xml"), folder / mesh_name)
    for n in solution_names:
        shutil.copy(data_file("nektar", "Tet_channel_m3.fld"), folder / n)
    return folder / mesh_name


def test_import_finds_the_latest_checkpoint_and_says_so(factory_scene, tmp_path, capfd):
    xml = _tet_as(tmp_path, "session.xml", ["session_12.chk", "session_123.chk"])
    capfd.readouterr()
    assert bpy.ops.import_scene.hovr_nektar(filepath=str(xml)) == {'FINISHED'}
    out = capfd.readouterr().out
    obj = bpy.context.active_object
    assert obj.hovr.solution.endswith("session_123.chk") and obj.hovr.field == "u"
    assert "solution session_123.chk" in out and "latest of 2" in out and "session_12.chk" in out


def test_geometry_only_import_is_a_warning(factory_scene, tmp_path, capfd):
    xml = _tet_as(tmp_path, "lonely.xml", [])
    capfd.readouterr()
    assert bpy.ops.import_scene.hovr_nektar(filepath=str(xml)) == {'FINISHED'}
    out = capfd.readouterr().out
    assert "Warning: HOVR: lonely: no solution file: geometry only" in out
    assert volume(factory_scene).hovr.solution == ""


@pytest.mark.parametrize("name,field,words", [
    ("Tet_channel_m3.xml", "u", "zero up to rounding"),  # u is 0 up to +-1.7e-16
    ("wss_3D_periodic.xml", "rho", "constant up to rounding"),  # rho is 0.0247601 everywhere
])
def test_a_field_constant_up_to_rounding_imports_with_a_warning_and_renders(factory_scene, tmp_path, capfd, name,
                                                                            field, words):
    """Issue 30: round-off is not stretched over the ramp, and a constant field does not fail at F12."""
    scene = factory_scene
    capfd.readouterr()
    assert bpy.ops.import_scene.hovr_nektar(filepath=str(data_file("nektar", name))) == {'FINISHED'}
    out = capfd.readouterr().out
    obj = bpy.context.active_object
    assert obj.hovr.field == field
    assert any(line.startswith("Warning") and words in line for line in out.splitlines()), out
    assert obj.hovr.value_max > obj.hovr.value_min
    if words.startswith("zero"):
        assert (obj.hovr.value_min, obj.hovr.value_max) == (-1.0, 1.0)
    else:
        assert obj.hovr.value_min < 0.0247601 < obj.hovr.value_max
    scene.render.resolution_percentage = 2
    img, warnings = f12(scene, tmp_path / "f12.exr", capfd)  # renders: no "Value Max > Value Min" error
    assert img.shape[0] > 0
    capfd.readouterr()
    assert bpy.ops.hovr.fit_value_range() == {'FINISHED'}
    assert words in capfd.readouterr().out


def test_a_background_render_logs_a_few_progress_lines(factory_scene, tmp_path, capfd):
    """Issue 30: in background mode (bpy is one) F12 says what it does, a few lines a frame:
    Blender 5.0 printed nothing for 425 s, 4.2 printed ~900 "tracing rays" lines."""
    scene = factory_scene
    bpy.ops.hovr.add_sphere_volume()
    bpy.ops.hovr.frame_volume()
    scene.render.resolution_percentage = 10  # 192 x 108: many progress tiles
    capfd.readouterr()
    render_to_exr(scene, tmp_path / "f12.exr")
    out = capfd.readouterr().out
    tracing = [line for line in out.splitlines() if "tracing rays" in line]
    assert 2 <= len(tracing) <= 12, out
    assert any("HOVR | reading" in line for line in out.splitlines()), out
    assert "tracing rays 100%" in tracing[-1]


def test_per_face_import_warnings_are_summarised(factory_scene, capfd):
    """Issue 30: Womersley's 136 per-face notes were repeated and ran into each other in one line."""
    capfd.readouterr()
    assert bpy.ops.import_scene.hovr_nektar(filepath=str(data_file("nektar", "Womersley_PipeFlow.xml"))) == {'FINISHED'}
    out = capfd.readouterr().out
    faces = [line for line in out.splitlines() if "curved triangle face" in line]
    assert len(faces) == 1 and faces[0].startswith("Warning") and "more faces like it" in faces[0], out
