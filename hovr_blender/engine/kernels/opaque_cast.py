"""Opaque surfaces: each pixel's camera ray cast against a triangle mesh (Warp's wp.Mesh BVH).

The same rays as the volume's (rays.camera_ray: the contract's unit direction, so t is in
world units), between the camera's near limit (t_min, the near clip plane) and its far one:
the first triangle hit there is where the ray's volume integral ends (engine/opaque.py).
float32 only: Warp's mesh is float32 in both precisions, as its BVH is.
"""
from __future__ import annotations

import warp as wp

from .args import CameraArgs
from .rays import camera_ray, camera_span

wp.set_module_options({"enable_backward": False})

NO_HIT = -1


@wp.kernel(enable_backward=False)
def cast_opaque(mesh: wp.uint64, cam: CameraArgs, t_out: wp.array(dtype=wp.float32),
                face_out: wp.array(dtype=wp.int32)):
    """t_out[pixel]: the first hit's t along the pixel's unit ray (+inf where none);
    face_out[pixel]: its triangle (NO_HIT where none)."""
    pixel = wp.tid()
    o, d = camera_ray(cam, pixel)
    span = camera_span(cam, d)
    t_lo = span[0]
    t_hi = span[1]
    t_out[pixel] = wp.inf
    face_out[pixel] = NO_HIT
    if t_hi > t_lo:
        hit = wp.mesh_query_ray(mesh, o + t_lo * d, d, t_hi - t_lo)
        if hit.result:
            t_out[pixel] = t_lo + hit.t
            face_out[pixel] = hit.face
