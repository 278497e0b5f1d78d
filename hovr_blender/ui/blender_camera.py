"""Blender camera -> RayCamera (render contract §4), from Blender's own matrices (the model:
engine/camera_matrices.py). No bpy here: the camera objects are duck-typed."""
from __future__ import annotations

from dataclasses import replace

import numpy as np

from ..engine.camera_matrices import as_matrix, clip_range, clipped, ray_camera_from_matrices, view_axis
from ..engine.camera import CameraError, RayCamera


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


def view_depth(cam: RayCamera, t) -> np.ndarray:
    """Distance along the view axis (Blender's Depth/Z convention, as Cycles' camera_z_depth)
    of the points at ray parameter t (H, W), for this camera's pixels."""
    t = np.asarray(t, dtype=np.float64)
    z0 = float(cam.extra.get("z_offset", 0.0))
    if cam.projection == "orthographic":
        return z0 + t
    _, d = cam.rays()
    return z0 + t * (d @ view_axis(cam))


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
    view = as_matrix(view_matrix, "view matrix")
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
