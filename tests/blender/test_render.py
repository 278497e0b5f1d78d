"""F12 through the HOVR engine: the written EXR equals the core renderer's image of the
same view built from the render contract, survives save/reload, and failures are reported."""
import math

import numpy as np
import pytest

bpy = pytest.importorskip("bpy", reason="bpy (Blender as a Python module) is not installed")
pytestmark = pytest.mark.blender

from hovr_blender.blender import render  # noqa: E402
from hovr_blender.blender.camera import ray_camera_from_blender  # noqa: E402
from hovr_blender.core.camera import RayCamera  # noqa: E402
from hovr_blender.core.renderer import Renderer  # noqa: E402
from hovr_blender.core.transfer_function import TransferFunction  # noqa: E402
from hovr_blender.core.view import RenderOptions  # noqa: E402
from hovr_blender.io import builtin  # noqa: E402

from blender_helpers import build_sphere_scene, render_to_exr  # noqa: E402

W, H = 64, 48
# The sphere's inner ball (f < 1, where the ramp below is non-zero) seen from outside its box:
# the density vanishes before the box faces, so the image has no silhouette edge, only smooth
# shells. Blender keeps camera parameters in float32 (rays differ from the contract's float64
# ones by ~1e-7); a sharp edge would turn that into more than the 1e-5 this test demands.
PERSPECTIVE = {"projection": "perspective", "eye": [4.0, 3.0, 3.5], "target": [0.25, -0.5, 0.5],
               "up": [0.0, 0.0, 1.0], "fov_y_deg": 40.0}
ORTHOGRAPHIC = {"projection": "orthographic", "eye": [4.0, 3.0, 3.5], "target": [0.25, -0.5, 0.5],
                "up": [0.0, 0.0, 1.0], "height": 3.0}
# Dyadic values survive Blender's float32 storage exactly. Ramp positions 0..1 map onto f in [0, 2].
STOPS = [(0.0, (1.0, 0.875, 0.25, 0.5)), (0.125, (1.0, 0.5, 0.25, 1.0)), (0.25, (0.25, 1.0, 0.375, 0.25)),
         (0.375, (0.125, 0.5, 1.0, 0.75)), (0.5, (1.0, 0.25, 0.5, 0.0)), (1.0, (0.0, 0.0, 0.0, 0.0))]
VALUE_RANGE, DENSITY_SCALE = (0.0, 2.0), 2.0
BACKGROUND = (0.0625, 0.03125, 0.125)
OBJECT_LOCATION, OBJECT_ANGLE_Z = (0.25, -0.5, 0.5), 0.5


def object_matrix():
    """The sphere object's transform, built here independently of Blender."""
    c, s = math.cos(OBJECT_ANGLE_Z), math.sin(OBJECT_ANGLE_Z)
    m = np.eye(4)
    m[:3, :3] = [[c, -s, 0], [s, c, 0], [0, 0, 1]]
    m[:3, 3] = OBJECT_LOCATION
    return m


def build_scene(scene, contract, method="classified", film_transparent=False, percentage=100):
    return build_sphere_scene(scene, contract, W, H, STOPS, VALUE_RANGE, DENSITY_SCALE, BACKGROUND,
                              OBJECT_LOCATION, OBJECT_ANGLE_Z, method, film_transparent, percentage)


def core_render(contract, method, film_transparent, camera=None, matrix=None):
    """The same view through the core API only: contract camera, ramp lists, numpy transform."""
    camera = RayCamera.from_contract(contract, W, H) if camera is None else camera
    tf = TransferFunction.from_rgba_ramp([p for p, _ in STOPS], [c for _, c in STOPS], DENSITY_SCALE, *VALUE_RANGE)
    bg = np.zeros(3) if film_transparent else np.array(BACKGROUND)
    mesh = builtin.sphere().transformed(object_matrix() if matrix is None else matrix)
    options = RenderOptions(method=method, h=0.01, tolerance=1e-6, device="cpu")
    return Renderer(mesh, device="cpu").render(camera, tf, bg, options).rgba


@pytest.mark.parametrize("contract,method,film_transparent,percentage", [
    (PERSPECTIVE, "classified", False, 100),
    (PERSPECTIVE, "trapezoid", True, 50),
    (ORTHOGRAPHIC, "classified", False, 100),
])
def test_f12_matches_core_render(scene, tmp_path, contract, method, film_transparent, percentage):
    obj = build_scene(scene, contract, method, film_transparent, percentage)
    got = render_to_exr(scene, tmp_path / "f12.exr")
    want = core_render(contract, method, film_transparent)
    assert got.shape == (H, W, 4)
    assert want[..., 3].max() > 0.2 and want[..., 3].min() < 1e-6  # the volume fills part of the frame
    if film_transparent:
        np.testing.assert_allclose(got, want, atol=1e-5)  # RGB = C (premultiplied), alpha = 1 - T
    else:
        np.testing.assert_allclose(got[..., :3], want[..., :3], atol=1e-5)  # RGB = C + T * world colour
        np.testing.assert_array_equal(got[..., 3], 1.0)
    # With the engine's own (float32-derived) camera and object transform the core gives the EXR
    # to the bit: TF, transform, background, row order and alpha all pass through unchanged.
    blender_camera = ray_camera_from_blender(scene.camera, bpy.context.evaluated_depsgraph_get(), scene.render)
    same = core_render(contract, method, film_transparent, camera=blender_camera, matrix=np.array(obj.matrix_world))
    if not film_transparent:
        same[..., 3] = 1.0
    np.testing.assert_array_equal(got, same)


def test_save_reload_renders_identically(scene, tmp_path):
    build_scene(scene, PERSPECTIVE)
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
    obj = build_scene(scene, PERSPECTIVE)
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
    build_scene(scene, PERSPECTIVE)
    breakage(scene)
    before = _fingerprint(scene)
    with pytest.raises(RuntimeError, match=message):
        bpy.ops.render.render(write_still=False)
    assert _fingerprint(scene) == before


def test_several_volumes_render_the_first_with_a_warning(scene, tmp_path, capfd):
    build_scene(scene, PERSPECTIVE)
    bpy.ops.hovr.add_sphere_volume()  # a second volume at the origin, named "HOVR Sphere.001"
    before = _fingerprint(scene)
    got = render_to_exr(scene, tmp_path / "two.exr")
    np.testing.assert_allclose(got[..., :3], core_render(PERSPECTIVE, "classified", False)[..., :3], atol=1e-5)
    assert _fingerprint(scene) == before
    assert "2 HOVR volumes; rendering only 'HOVR Sphere'" in capfd.readouterr().out
