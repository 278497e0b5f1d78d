"""Rendered-shading viewport in bpy, everything but the GPU upload: rays from the region's
matrices (checked against bpy_extras.view3d_utils), change detection in view_draw's step,
and the converged viewport equal to F12 in camera view."""
from types import SimpleNamespace

import numpy as np
import pytest

bpy = pytest.importorskip("bpy", reason="bpy (Blender as a Python module) is not installed")
pytestmark = pytest.mark.blender

from bpy_extras import view3d_utils  # noqa: E402
from mathutils import Matrix  # noqa: E402

from hovr_blender.ui import render  # noqa: E402
from hovr_blender.ui.viewport import ProgressiveViewport  # noqa: E402

from ..helpers import SPHERE  # noqa: E402
from .blender_helpers import look_at, render_to_exr  # noqa: E402


def fake_context(window, view, width, height, kind="PERSP"):
    rv3d = SimpleNamespace(window_matrix=window, view_matrix=view, perspective_matrix=window @ view,
                           is_perspective=kind != "ORTHO", view_perspective=kind)
    return SimpleNamespace(region=SimpleNamespace(width=width, height=height), region_data=rv3d)


def ortho_window(half_w, half_h, near, far):
    return Matrix(((1 / half_w, 0, 0, 0), (0, 1 / half_h, 0, 0),
                   (0, 0, -2 / (far - near), -(far + near) / (far - near)), (0, 0, 0, 1)))


def camera_view(scene, w, h):
    """The window/view matrices of a viewport in camera view whose region is the camera frame."""
    depsgraph = bpy.context.evaluated_depsgraph_get()
    window = scene.camera.calc_matrix_camera(depsgraph, x=w, y=h)
    return fake_context(window, scene.camera.matrix_world.normalized().inverted(), w, h, "CAMERA")


@pytest.mark.parametrize("kind", ["PERSP", "ORTHO"])
def test_viewport_rays_follow_view3d_utils(scene, kind):
    SPHERE.build_scene(scene, SPHERE.PERSPECTIVE)
    w, h = 40, 30
    view = Matrix(look_at([5.0, -4.0, 3.0], [0.2, 0.1, 0.4], [0, 0, 1]).tolist()).inverted()
    if kind == "PERSP":
        scene.camera.data.clip_start, scene.camera.data.clip_end = 0.05, 80.0
        window = scene.camera.calc_matrix_camera(bpy.context.evaluated_depsgraph_get(), x=w, y=h)
    else:  # viewport ortho views clip symmetrically around the view origin
        window = ortho_window(2.5, 2.5 * h / w, -40.0, 40.0)
    ctx = fake_context(window, view, w, h, kind)
    _renderer, req = render.viewport_request(ctx, bpy.context.evaluated_depsgraph_get())
    cam = req.camera
    o, d = cam.rays()
    for j, i in [(0, 0), (h - 1, w - 1), (7, 31), (h // 2, w // 2)]:
        xy = (i + 0.5, h - 1 - j + 0.5)  # region coordinates: y up; our rows: from the top
        dv = np.array(view3d_utils.region_2d_to_vector_3d(ctx.region, ctx.region_data, xy))
        ov = np.array(view3d_utils.region_2d_to_origin_3d(ctx.region, ctx.region_data, xy))
        np.testing.assert_allclose(d[j, i], dv, atol=2e-5)
        np.testing.assert_allclose(o[j, i], ov, atol=2e-4 * max(1.0, np.abs(ov).max()))
    if kind == "ORTHO":  # rays start on the near plane, 40 behind the view origin
        assert cam.t_min == 0.0 and cam.t_max == pytest.approx(80.0, rel=1e-5)
    else:  # perspective: clipped per ray along the view axis by the kernel
        assert cam.clip_near == pytest.approx(0.05, rel=1e-4)


def test_camera_view_converges_to_the_f12_image(scene, tmp_path):
    SPHERE.build_scene(scene, SPHERE.PERSPECTIVE)
    f12 = render_to_exr(scene, tmp_path / "f12.exr")[::-1]  # bottom row first, like the viewport
    ctx = camera_view(scene, SPHERE.W, SPHERE.H)
    state = ProgressiveViewport()
    frames = []
    for _ in range(200):
        frame = render.viewport_step(state, ctx, bpy.context.evaluated_depsgraph_get())
        frames.append(frame.stage)
        if frame.converged:
            break
    assert frame.converged and frame.pixels.shape == (SPHERE.H, SPHERE.W, 4)
    assert frames[0] in ("refining", "converged") and state.log[0].kind == "preview"
    np.testing.assert_allclose(frame.pixels, f12, atol=1e-5)


def test_any_change_restarts_the_viewport(scene):
    obj = SPHERE.build_scene(scene, SPHERE.PERSPECTIVE)
    ctx = camera_view(scene, 24, 18)
    state = ProgressiveViewport()
    step = lambda: render.viewport_step(state, ctx, bpy.context.evaluated_depsgraph_get(), budget=0.01)
    step()
    assert state.restarts == 1
    step()
    assert state.restarts == 1  # nothing changed: keep refining

    def ramp():
        obj.hovr.transfer_function.color_ramp.elements[1].color = (0.5, 0.5, 0.5, 1.0)

    def move():
        obj.location.x += 0.25

    def setting():
        obj.hovr.density = 3.0

    def world():
        scene.world.color = (0.5, 0.0, 0.0)

    def view():
        ctx.region_data.view_matrix = Matrix.Translation((0.1, 0, 0)) @ ctx.region_data.view_matrix

    def frame():
        scene.frame_set(7)  # a builtin source does not change with the frame: no restart

    for n, change in enumerate((ramp, move, setting, world, view), start=2):
        change()
        f = step()
        assert state.restarts == n and f.stage in ("refining", "converged"), change.__name__
    frame()
    step()
    assert state.restarts == 6


def test_viewport_errors_are_raised_for_view_draw_to_show(scene):
    obj = SPHERE.build_scene(scene, SPHERE.PERSPECTIVE)
    obj.hovr.transfer_function.color_ramp.interpolation = 'EASE'
    ctx = camera_view(scene, 16, 12)
    with pytest.raises(ValueError, match="Linear"):
        render.viewport_step(ProgressiveViewport(), ctx, bpy.context.evaluated_depsgraph_get())


def test_a_look_edit_in_the_converged_viewport_is_shaded_from_its_bands(scene, tmp_path):
    """Rendered viewport, camera view, converged: an edit of the ramp's colour and the density
    is answered by one view_draw step that shades every band from its cached segments (no
    preview, no trace), and that frame is F12's picture of the new look."""
    obj = SPHERE.build_scene(scene, SPHERE.PERSPECTIVE)
    ctx = camera_view(scene, SPHERE.W, SPHERE.H)
    state = ProgressiveViewport()
    for _ in range(200):
        if render.viewport_step(state, ctx, bpy.context.evaluated_depsgraph_get()).converged:
            break
    caches = {y: c for y, (_, c) in state._caches.items()}
    assert state.converged and sum(rows for rows, _ in state._caches.values()) == SPHERE.H
    state.first_frame_seconds = 60.0  # the path is tested, not the machine's speed (a busy CPU misses 0.1 s)
    obj.hovr.transfer_function.color_ramp.elements[1].color = (1.0, 0.0, 0.0, 1.0)
    obj.hovr.density *= 2.0
    n = len(state.log)
    frame = render.viewport_step(state, ctx, bpy.context.evaluated_depsgraph_get())
    assert frame.converged and [r.kind for r in state.log[n:]] == ["reshade"]
    assert all(state._caches[y][1] is c for y, c in caches.items())
    f12 = render_to_exr(scene, tmp_path / "f12.exr")[::-1]
    np.testing.assert_allclose(frame.pixels, f12, atol=1e-5)
