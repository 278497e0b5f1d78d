"""F12 through the HOVR engine: the written EXR equals the core renderer's image of the
same view built from the render contract, survives save/reload, and failures are reported."""
import numpy as np
import pytest

bpy = pytest.importorskip("bpy", reason="bpy (Blender as a Python module) is not installed")
pytestmark = pytest.mark.blender

from hovr_blender.blender import render  # noqa: E402
from hovr_blender.blender.camera import ray_camera_from_blender  # noqa: E402

from ..helpers import SPHERE  # noqa: E402
from .blender_helpers import render_to_exr  # noqa: E402


@pytest.mark.parametrize("contract,method,film_transparent,percentage", [
    (SPHERE.PERSPECTIVE, "classified", False, 100),
    (SPHERE.PERSPECTIVE, "trapezoid", True, 50),
    (SPHERE.ORTHOGRAPHIC, "classified", False, 100),
])
def test_f12_matches_core_render(scene, tmp_path, contract, method, film_transparent, percentage):
    obj = SPHERE.build_scene(scene, contract, method, film_transparent, percentage)
    got = render_to_exr(scene, tmp_path / "f12.exr")
    want = SPHERE.core_render(contract, method, film_transparent)
    assert got.shape == (SPHERE.H, SPHERE.W, 4)
    assert want[..., 3].max() > 0.2 and want[..., 3].min() < 1e-6  # the volume fills part of the frame
    if film_transparent:
        np.testing.assert_allclose(got, want, atol=1e-5)  # RGB = C (premultiplied), alpha = 1 - T
    else:
        np.testing.assert_allclose(got[..., :3], want[..., :3], atol=1e-5)  # RGB = C + T * world colour
        np.testing.assert_array_equal(got[..., 3], 1.0)
    # With the engine's own (float32-derived) camera and object transform the core gives the EXR
    # to the bit: TF, transform, background, row order and alpha all pass through unchanged.
    blender_camera = ray_camera_from_blender(scene.camera, bpy.context.evaluated_depsgraph_get(), scene.render)
    same = SPHERE.core_render(contract, method, film_transparent, camera=blender_camera, matrix=np.array(obj.matrix_world))
    if not film_transparent:
        same[..., 3] = 1.0
    np.testing.assert_array_equal(got, same)


def test_save_reload_renders_identically(scene, tmp_path):
    SPHERE.build_scene(scene, SPHERE.PERSPECTIVE)
    first = render_to_exr(scene, tmp_path / "a.exr")
    path = str(tmp_path / "scene.blend")
    bpy.ops.wm.save_as_mainfile(filepath=path)
    render.clear_cache()
    bpy.ops.wm.read_factory_settings(use_empty=True)
    bpy.ops.wm.open_mainfile(filepath=path)
    loaded = bpy.context.scene
    assert loaded.render.engine == 'HOVR' and loaded.hovr.method == "classified"
    assert loaded.hovr.transfer_function is not None
    assert [o.name for o in loaded.objects if o.hovr.is_volume] == ["HOVR Sphere"]
    second = render_to_exr(loaded, tmp_path / "b.exr")
    np.testing.assert_array_equal(first, second)


def test_renderer_is_cached_per_object_transform(scene, tmp_path):
    obj = SPHERE.build_scene(scene, SPHERE.PERSPECTIVE)
    render.clear_cache()
    render_to_exr(scene, tmp_path / "a.exr")
    render_to_exr(scene, tmp_path / "b.exr")
    assert len(render.RENDERERS) == 1
    obj.location.x += 1.0
    moved = render_to_exr(scene, tmp_path / "c.exr")
    assert len(render.RENDERERS) == 2
    obj.location.x -= 1.0
    back = render_to_exr(scene, tmp_path / "d.exr")
    assert len(render.RENDERERS) == 2  # the first upload was reused
    assert np.abs(moved - back).max() > 1e-3


def _fingerprint(scene):
    """The user data a render must not touch."""
    s = scene.hovr
    ramp = s.transfer_function.color_ramp if s.transfer_function else None
    return (
        sorted((o.name, o.location[:], o.rotation_euler[:], o.scale[:], o.hovr.is_volume, o.hovr.source)
               for o in scene.objects),
        (s.method, s.h, s.tolerance, s.min_transmittance, s.device, s.density_scale, s.value_min, s.value_max),
        ramp and (ramp.interpolation, [(e.position, tuple(e.color)) for e in ramp.elements]),
        len(bpy.data.textures), len(bpy.data.meshes),
        len([i for i in bpy.data.images if i.type != 'RENDER_RESULT']),  # Blender adds its Render Result
    )


def _no_volume(scene):
    for o in [o for o in scene.objects if o.hovr.is_volume]:
        bpy.data.objects.remove(o)


def _ease(scene):
    scene.hovr.transfer_function.color_ramp.interpolation = 'EASE'


def _empty_range(scene):
    scene.hovr.value_max = scene.hovr.value_min


def _no_tf(scene):
    scene.hovr.transfer_function = None


def _unknown_source(scene):
    next(o for o in scene.objects if o.hovr.is_volume).hovr.source = "builtin:teapot"


def _pano(scene):
    scene.camera.data.type = 'PANO'


@pytest.mark.parametrize("breakage,message", [
    (_no_volume, "no HOVR volume"), (_ease, "Linear interpolation"), (_empty_range, "Value Max"),
    (_no_tf, "no transfer function"), (_unknown_source, "teapot"), (_pano, "panoramic"),
])
def test_errors_are_reported_and_leave_data_untouched(scene, tmp_path, breakage, message):
    SPHERE.build_scene(scene, SPHERE.PERSPECTIVE)
    breakage(scene)
    before = _fingerprint(scene)
    with pytest.raises(RuntimeError, match=message):
        bpy.ops.render.render(write_still=False)
    assert _fingerprint(scene) == before


def test_several_volumes_render_the_first_with_a_warning(scene, tmp_path, capfd):
    SPHERE.build_scene(scene, SPHERE.PERSPECTIVE)
    bpy.ops.hovr.add_sphere_volume()  # a second volume at the origin, named "HOVR Sphere.001"
    before = _fingerprint(scene)
    got = render_to_exr(scene, tmp_path / "two.exr")
    np.testing.assert_allclose(got[..., :3], SPHERE.core_render(SPHERE.PERSPECTIVE, "classified", False)[..., :3], atol=1e-5)
    assert _fingerprint(scene) == before
    assert "2 HOVR volumes; rendering only 'HOVR Sphere'" in capfd.readouterr().out
