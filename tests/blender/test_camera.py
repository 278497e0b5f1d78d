"""The engine's camera (blender_camera via calc_matrix_camera) against Blender's own
camera-frame utilities: world_to_camera_view and Camera.view_frame."""
import itertools

import numpy as np
import pytest

bpy = pytest.importorskip("bpy", reason="bpy (Blender as a Python module) is not installed")
pytestmark = pytest.mark.blender

from bpy_extras.object_utils import world_to_camera_view  # noqa: E402
from mathutils import Vector  # noqa: E402

from hovr_blender.ui.blender_camera import ray_camera_from_blender  # noqa: E402

from .blender_helpers import add_camera  # noqa: E402

CASES = [
    # (type, sensor_fit, (res_x, res_y, percentage), (pixel_aspect_x, pixel_aspect_y), (shift_x, shift_y))
    ("PERSP", "AUTO", (64, 48, 100), (1, 1), (0.0, 0.0)),
    ("PERSP", "AUTO", (48, 64, 100), (1, 1), (0.1, -0.2)),
    ("PERSP", "HORIZONTAL", (64, 48, 50), (1, 1), (0.15, 0.05)),
    ("PERSP", "VERTICAL", (64, 48, 100), (2, 1), (-0.1, 0.1)),
    ("PERSP", "AUTO", (60, 50, 100), (1, 1.5), (0.05, 0.0)),
    ("PERSP", "HORIZONTAL", (30, 70, 100), (1.3, 1), (0.0, 0.3)),
    ("ORTHO", "AUTO", (64, 48, 100), (1, 1), (0.0, 0.0)),
    ("ORTHO", "VERTICAL", (64, 48, 75), (2, 1), (0.2, -0.1)),
    ("ORTHO", "HORIZONTAL", (40, 60, 100), (1, 1.5), (-0.1, 0.05)),
]


def _camera(scene, kind, fit, res, aspect, shift):
    cam = add_camera(scene)
    cam.location = (3.0, -4.0, 2.5)
    cam.rotation_euler = (1.1, 0.2, 0.6)
    cam.scale = (1.5, 1.5, 1.5)  # renders ignore camera scale; so must we
    cam.data.type, cam.data.sensor_fit = kind, fit
    cam.data.lens, cam.data.sensor_width, cam.data.sensor_height = 40.0, 36.0, 20.0
    cam.data.ortho_scale = 5.0
    cam.data.shift_x, cam.data.shift_y = shift
    r = scene.render
    r.resolution_x, r.resolution_y, r.resolution_percentage = res
    r.pixel_aspect_x, r.pixel_aspect_y = aspect
    return cam


@pytest.mark.parametrize("kind,fit,res,aspect,shift", CASES)
def test_pixel_rays_hit_their_pixel_centres(scene, kind, fit, res, aspect, shift):
    cam = _camera(scene, kind, fit, res, aspect, shift)
    depsgraph = bpy.context.evaluated_depsgraph_get()
    rc = ray_camera_from_blender(cam, depsgraph, scene.render)
    w, h = res[0] * res[2] // 100, res[1] * res[2] // 100
    assert (rc.width, rc.height) == (w, h)
    o, d = rc.rays()
    for j, i in itertools.product((0, h // 3, h - 1), (0, w // 2, w - 1)):
        for t in (0.5, 6.0):
            x, y, depth = world_to_camera_view(scene, cam, Vector(o[j, i] + t * d[j, i]))
            assert x == pytest.approx((i + 0.5) / w, abs=2e-5)
            assert y == pytest.approx(1 - (j + 0.5) / h, abs=2e-5)  # (0, 0) is bottom-left
            assert depth > 0
    cam_pos = np.array(cam.matrix_world.translation)
    if kind == "PERSP":
        np.testing.assert_allclose(o, np.broadcast_to(cam_pos, o.shape), atol=1e-6)  # from the eye
    else:
        forward = -np.array(cam.matrix_world.normalized().col[2][:3])
        np.testing.assert_allclose((o - cam_pos) @ forward, 0.0, atol=1e-5)  # from the camera plane


@pytest.mark.parametrize("kind,fit,res,aspect,shift", CASES)
def test_image_corners_follow_view_frame(scene, kind, fit, res, aspect, shift):
    """The affine model evaluated at the image corners (u = +-W/H, v = +-1) passes through the
    corners of Blender's camera frame."""
    cam = _camera(scene, kind, fit, res, aspect, shift)
    rc = ray_camera_from_blender(cam, bpy.context.evaluated_depsgraph_get(), scene.render)
    M = np.array(cam.matrix_world.normalized())
    # view_frame order: top-right, bottom-right, bottom-left, top-left (camera-local)
    frame = [np.array(v) for v in cam.data.view_frame(scene=scene)]
    U = rc.width / rc.height
    for (u, v), corner in zip([(U, 1), (U, -1), (-U, -1), (-U, 1)], frame):
        origin = rc.o0 + u * rc.ou + v * rc.ov
        direction = rc.d0 + u * rc.du + v * rc.dv
        if kind == "PERSP":
            want = M[:3, :3] @ corner
            np.testing.assert_allclose(np.cross(direction, want), 0.0, atol=1e-5 * np.linalg.norm(want))
            assert direction @ want > 0
        else:
            np.testing.assert_allclose(origin, M[:3, :3] @ [corner[0], corner[1], 0.0] + M[:3, 3], atol=1e-5)
            np.testing.assert_allclose(direction / np.linalg.norm(direction), -M[:3, 2], atol=1e-6)


def test_panoramic_camera_is_refused(scene):
    from hovr_blender.engine.camera import CameraError

    cam = _camera(scene, "PANO", "AUTO", (32, 24, 100), (1, 1), (0, 0))
    with pytest.raises(CameraError, match="panoramic"):
        ray_camera_from_blender(cam, bpy.context.evaluated_depsgraph_get(), scene.render)
