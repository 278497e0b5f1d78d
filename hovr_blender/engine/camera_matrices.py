"""Blender's camera model without bpy: the RayCamera (render contract §4) of a Blender camera from its
own matrices (ui/blender_camera.py reads them from Blender; engine/first_view.py makes them as
Blender would for the import's Frame Camera, so the command line's first view is Blender's camera),
its clip planes, and the perspective projection Blender computes in float32.

Blender already folds lens, sensor fit, shift, ortho scale and pixel aspect into the
projection matrix of ``Object.calc_matrix_camera``; unprojecting NDC points through it
avoids re-deriving that model by hand. The contract's u, v relate to NDC by
x_ndc = u H / W and y_ndc = v, and both projections are affine in (x_ndc, y_ndc), so
three unprojected points give the RayCamera's o0, ou, ov, d0, du, dv exactly.
"""
from __future__ import annotations

from dataclasses import replace

import numpy as np

from .camera import CameraError, RayCamera


def as_matrix(m, what):
    a = np.asarray([list(row) for row in m], dtype=np.float64)
    if a.shape != (4, 4) or not np.all(np.isfinite(a)):
        raise CameraError(f"{what} must be a finite 4x4 matrix")
    return a

def normalized_camera_to_world(matrix_world) -> np.ndarray:
    """Blender renders with the camera matrix's axes normalised (object scale ignored)."""
    m = as_matrix(matrix_world, "camera matrix_world").copy()
    for k in range(3):
        n = np.linalg.norm(m[:3, k])
        if n < 1e-12:
            raise CameraError("camera object has zero scale along one axis")
        m[:3, k] /= n
    return m

def is_orthographic(projection) -> bool:
    """A perspective projection puts -z_cam into w; an orthographic one keeps w = 1."""
    p = as_matrix(projection, "projection")
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
    P = as_matrix(projection, "projection")
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

def clip_range(projection) -> tuple[float, float]:
    """(near, far) view-axis distances encoded in a Blender projection matrix.

    calc_matrix_camera and the viewport's window_matrix both build the clip planes into
    row 2, so one formula serves F12 and the viewport (camera view included)."""
    P = as_matrix(projection, "projection")
    a, b = P[2, 2], P[2, 3]
    if is_orthographic(P):
        near, far = (b + 1.0) / a, (b - 1.0) / a
    else:
        near, far = b / (a - 1.0), b / (a + 1.0)
    if not (np.isfinite(near) and np.isfinite(far) and far > near):
        raise CameraError(f"camera clip range is empty or invalid (start {near:g}, end {far:g})")
    return float(near), float(far)

def view_axis(cam: RayCamera) -> np.ndarray:
    # Blender cameras record their view axis; a contract camera's d0 is its forward vector.
    f = np.asarray(cam.extra.get("forward", cam.d0), dtype=np.float64)
    return f / np.linalg.norm(f)

def clipped(cam: RayCamera, near: float, far: float) -> RayCamera:
    """The camera with Blender's clip planes (distances along the view axis) as a t range.

    Orthographic: d is the view axis, so t = z - z0 exactly; origins move onto the near
    plane when it lies behind the camera (viewport ortho views clip at negative starts).
    Perspective: t = z / cos(angle to the axis) differs per ray: the kernel clips each ray
    at [near / c, far / c] with c = d . axis (RayCamera.clip_axis/clip_near/clip_far).
    """
    fwd = view_axis(cam)
    extra = dict(cam.extra, clip=(float(near), float(far)))
    if cam.projection == "orthographic":
        z0 = float(min(near, 0.0))
        extra["z_offset"] = z0
        return replace(cam, o0=cam.o0 + z0 * fwd, t_min=float(near - z0), t_max=float(far - z0), extra=extra)
    U = cam.width / cam.height
    cos_min = min(float(np.dot(fwd, d / np.linalg.norm(d)))
                  for d in (cam.d0 + u * cam.du + v * cam.dv for u in (-U, U) for v in (-1.0, 1.0)))
    if cos_min <= 1e-6:
        raise CameraError("camera field of view reaches 90 degrees off its axis")
    extra["z_offset"] = 0.0
    return replace(cam, t_min=0.0, t_max=float("inf"), clip_axis=tuple(map(float, fwd)),
                   clip_near=float(max(near, 0.0)), clip_far=float(far), extra=extra)


def perspective_matrix(width: int, height: int, lens_mm: float, sensor_mm: float, clip_start: float,
                       clip_end: float) -> np.ndarray:
    """calc_matrix_camera of a perspective camera with sensor fit Auto, no shift, square pixels, as
    Blender computes it, in float32 (BKE_camera_params_compute_viewplane and perspective_m4): the
    matrix F12 reads, to its last bit (tests/blender/test_first_view.py)."""
    f = np.float32
    width, height = int(width), int(height)
    clip_start, clip_end = f(clip_start), f(clip_end)
    pixsize = (f(sensor_mm) * clip_start) / f(lens_mm) / f(max(width, height))
    xmin, xmax = f(-0.5) * f(width) * pixsize, f(0.5) * f(width) * pixsize
    ymin, ymax = f(-0.5) * f(height) * pixsize, f(0.5) * f(height) * pixsize
    depth = clip_end - clip_start
    m = np.zeros((4, 4), np.float32)
    m[0, 0] = clip_start * f(2.0) / (xmax - xmin)
    m[1, 1] = clip_start * f(2.0) / (ymax - ymin)
    m[0, 2] = (xmax + xmin) / (xmax - xmin)
    m[1, 2] = (ymax + ymin) / (ymax - ymin)
    m[2, 2] = -(clip_end + clip_start) / depth
    m[2, 3] = (f(-2.0) * clip_start * clip_end) / depth
    m[3, 2] = f(-1.0)
    return m
