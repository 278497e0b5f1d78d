"""Blender camera -> RayCamera (render contract §4), from Blender's own matrices. No bpy here.

Blender already folds lens, sensor fit, shift, ortho scale and pixel aspect into the
projection matrix of ``Object.calc_matrix_camera``; unprojecting NDC points through it
avoids re-deriving that model by hand. The contract's u, v relate to NDC by
x_ndc = u H / W and y_ndc = v, and both projections are affine in (x_ndc, y_ndc), so
three unprojected points give the RayCamera's o0, ou, ov, d0, du, dv exactly.
"""
from __future__ import annotations

from dataclasses import replace

import numpy as np

from ..engine.camera import CameraError, RayCamera


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
    # The camera's own clip values: recovering far from the float32 matrix loses ~1e-3.
    near, far = (cam.data.clip_start, cam.data.clip_end) if cam.type == "CAMERA" else clip_range(projection)
    return clipped(ray_camera_from_matrices(projection, cam.matrix_world, width, height), float(near), float(far))


def clip_range(projection) -> tuple[float, float]:
    """(near, far) view-axis distances encoded in a Blender projection matrix.

    calc_matrix_camera and the viewport's window_matrix both build the clip planes into
    row 2, so one formula serves F12 and the viewport (camera view included)."""
    P = _as_matrix(projection, "projection")
    a, b = P[2, 2], P[2, 3]
    if is_orthographic(P):
        near, far = (b + 1.0) / a, (b - 1.0) / a
    else:
        near, far = b / (a - 1.0), b / (a + 1.0)
    if not (np.isfinite(near) and np.isfinite(far) and far > near):
        raise CameraError(f"camera clip range is empty or invalid (start {near:g}, end {far:g})")
    return float(near), float(far)


def _forward(cam: RayCamera) -> np.ndarray:
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
    fwd = _forward(cam)
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


def view_depth(cam: RayCamera, t) -> np.ndarray:
    """Distance along the view axis (Blender's Depth/Z convention, as Cycles' camera_z_depth)
    of the points at ray parameter t (H, W), for this camera's pixels."""
    t = np.asarray(t, dtype=np.float64)
    z0 = float(cam.extra.get("z_offset", 0.0))
    if cam.projection == "orthographic":
        return z0 + t
    _, d = cam.rays()
    return z0 + t * (d @ _forward(cam))


def sub_camera(cam: RayCamera, x0: int, y0_top: int, width: int, height: int) -> RayCamera:
    """The pixels [x0, x0+width) x [y0_top, y0_top+height) (rows from the top) of `cam` as a
    camera of their own: pixel (i, j) of the result is pixel (x0+i, y0_top+j) of `cam`.

    With s = height/H, the sub-image's (u', v') relate to the full image's by
    u = s u' + (width + 2 x0 - W)/H and v = s v' + 1 - s - 2 y0_top/H, so the affine ray
    model is re-expressed exactly (up to rounding) for border renders and viewport bands."""
    W, H = int(cam.width), int(cam.height)
    x0, y0_top, width, height = int(x0), int(y0_top), int(width), int(height)
    if not (0 <= x0 and 0 <= y0_top and width >= 1 and height >= 1 and x0 + width <= W and y0_top + height <= H):
        raise CameraError(f"sub-image {width}x{height}+{x0}+{y0_top} outside the {W}x{H} image")
    s = height / H
    cu = (width + 2 * x0 - W) / H
    cv = 1.0 - s - 2 * y0_top / H
    return replace(
        cam, width=width, height=height,
        o0=cam.o0 + cu * cam.ou + cv * cam.ov, ou=s * cam.ou, ov=s * cam.ov,
        d0=cam.d0 + cu * cam.du + cv * cam.dv, du=s * cam.du, dv=s * cam.dv,
    )


def ray_camera_from_view(window_matrix, view_matrix, width: int, height: int) -> RayCamera:
    """Viewport rays: rv3d.window_matrix already holds the lens, zoom, camera-view
    offset and clip range, rv3d.view_matrix is world -> view; clip planes applied (taken from
    the float32 matrix: the far plane is good to ~1e-3 relative, the near one to ~1e-7)."""
    view = _as_matrix(view_matrix, "view matrix")
    try:
        view_to_world = np.linalg.inv(view)
    except np.linalg.LinAlgError as exc:
        raise CameraError("view matrix is singular") from exc
    cam = ray_camera_from_matrices(window_matrix, view_to_world, width, height)
    return clipped(cam, *clip_range(window_matrix))


def border_region(width: int, height: int, use_border: bool, xmin: float, xmax: float,
                  ymin: float, ymax: float) -> tuple[int, int, int, int]:
    """(x0, y0 from the bottom, w, h) of the pixels Blender renders for a border.

    Blender truncates float32 products (render_init: disprect = border * winx); the same
    arithmetic is repeated so the rays cover exactly the result Blender allocates."""
    width, height = int(width), int(height)
    if not use_border:
        return 0, 0, width, height
    f = np.float32
    x0, x1 = int(f(xmin) * f(width)), int(f(xmax) * f(width))
    y0, y1 = int(f(ymin) * f(height)), int(f(ymax) * f(height))
    x0, x1 = max(0, min(x0, width)), max(0, min(x1, width))
    y0, y1 = max(0, min(y0, height)), max(0, min(y1, height))
    if x1 - x0 < 1 or y1 - y0 < 1:
        return 0, 0, width, height  # Blender renders the full frame for an empty border
    return x0, y0, x1 - x0, y1 - y0
