"""Blender camera -> RayCamera (render contract §4), from Blender's own matrices. No bpy here.

Blender already folds lens, sensor fit, shift, ortho scale and pixel aspect into the
projection matrix of ``Object.calc_matrix_camera``; unprojecting NDC points through it
(notes §3.5) avoids re-deriving that model by hand. The contract's u, v relate to NDC by
x_ndc = u H / W and y_ndc = v, and both projections are affine in (x_ndc, y_ndc), so
three unprojected points give the RayCamera's o0, ou, ov, d0, du, dv exactly.
"""
from __future__ import annotations

import numpy as np

from .camera import CameraError, RayCamera


def _as_matrix(m, what):
    a = np.asarray([list(row) for row in m], dtype=np.float64)
    if a.shape != (4, 4) or not np.all(np.isfinite(a)):
        raise CameraError(f"{what} must be a finite 4x4 matrix")
    return a


def normalized_camera_to_world(matrix_world) -> np.ndarray:
    """Blender renders with the camera matrix's axes normalised (object scale ignored)."""
    m = _as_matrix(matrix_world, "camera matrix_world").copy()
    for k in range(3):
        n = np.linalg.norm(m[:3, k])
        if n < 1e-12:
            raise CameraError("camera object has zero scale along one axis")
        m[:3, k] /= n
    return m


def is_orthographic(projection) -> bool:
    """A perspective projection puts -z_cam into w; an orthographic one keeps w = 1."""
    p = _as_matrix(projection, "projection")
    return bool(np.allclose(p[3], [0.0, 0.0, 0.0, 1.0]))


def ray_camera_from_matrices(projection, matrix_world, width: int, height: int) -> RayCamera:
    """The RayCamera of a Blender camera.

    Args:
        projection: 4x4 from ``cam.calc_matrix_camera(depsgraph, x=width, y=height,
            scale_x=pixel_aspect_x, scale_y=pixel_aspect_y)`` (camera space -> clip space).
        matrix_world: the camera object's 4x4 world matrix (camera -> world); scale is ignored.
        width, height: the render size in pixels (resolution times percentage).

    Perspective rays start at the eye (t from 0, as in the contract, not at clip_start);
    orthographic rays start on the plane through the camera position. Clipping distances
    are not applied.
    """
    width, height = int(width), int(height)
    if width < 1 or height < 1:
        raise CameraError(f"image size must be positive, got {width}x{height}")
    P = _as_matrix(projection, "projection")
    C = normalized_camera_to_world(matrix_world)
    try:
        P_inv = np.linalg.inv(P)
    except np.linalg.LinAlgError as exc:
        raise CameraError("camera projection matrix is singular") from exc
    eye = C[:3, 3]
    forward = -C[:3, 2]  # Blender cameras look down local -Z
    ortho = is_orthographic(P)

    def cam_point(x, y, z):
        h = P_inv @ np.array([x, y, z, 1.0])
        return h[:3] / h[3]

    def ray(x, y):
        """(origin, direction) in world space for NDC (x, y); direction scaled to unit depth."""
        near, far = cam_point(x, y, -1.0), cam_point(x, y, 1.0)
        if ortho:
            # Slide the near point along the view axis onto the plane z_cam = 0.
            origin = near - (near[2] / (far[2] - near[2])) * (far - near)
            d = far - near
        else:
            origin = np.zeros(3)
            d = near
        d = d / -d[2]  # camera looks down -z; unit depth keeps d0 the forward axis
        return C[:3, :3] @ origin + eye, C[:3, :3] @ d

    o00, d00 = ray(0.0, 0.0)
    o10, d10 = ray(1.0, 0.0)
    o01, d01 = ray(0.0, 1.0)
    s = height / width  # d(x_ndc)/du
    cam = RayCamera(
        width, height,
        o0=o00, ou=(o10 - o00) * s, ov=o01 - o00,
        d0=d00, du=(d10 - d00) * s, dv=d01 - d00,
        projection="orthographic" if ortho else "perspective",
        extra={"eye": eye.tolist(), "forward": forward.tolist()},
    )
    # The affine model is exact for pinhole and parallel projections; anything else
    # (a hand-made or oblique-depth matrix) would silently mis-render, so check a corner.
    o11, d11 = ray(1.0, 1.0)
    u1 = width / height
    if not (np.allclose(cam.o0 + u1 * cam.ou + cam.ov, o11, rtol=1e-9, atol=1e-9 * (1 + np.abs(o11).max()))
            and np.allclose(cam.d0 + u1 * cam.du + cam.dv, d11, rtol=1e-9, atol=1e-9)):
        raise CameraError("camera projection is not a pinhole or orthographic projection")
    return cam


def render_size(render) -> tuple[int, int]:
    """Pixel size of a final render from Blender's RenderSettings (percentage applied)."""
    scale = render.resolution_percentage / 100.0
    return int(render.resolution_x * scale), int(render.resolution_y * scale)


def ray_camera_from_blender(camera_object, depsgraph, render) -> RayCamera:
    """Thin bpy-side wrapper (duck-typed, so this module still imports no bpy): the RayCamera
    a final render of ``camera_object`` (evaluated in ``depsgraph``) with ``render`` settings uses."""
    cam = camera_object.evaluated_get(depsgraph)
    if cam.type == "CAMERA" and cam.data.type == "PANO":
        raise CameraError(f"camera {cam.name!r} is panoramic; HOVR supports perspective and orthographic cameras")
    width, height = render_size(render)
    projection = cam.calc_matrix_camera(depsgraph, x=width, y=height,
                                        scale_x=render.pixel_aspect_x, scale_y=render.pixel_aspect_y)
    return ray_camera_from_matrices(projection, cam.matrix_world, width, height)
