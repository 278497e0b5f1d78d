"""bench/peer_pixels.py's sub-pixel scan: its rays are the image's pixel rays moved by the
stated fractions of a pixel (the contract's rays, written out in audit/reference.contract_ray)."""
import numpy as np

from bench.peer_pixels import scan_camera
from hovr_blender.audit.vtk_reference import contract_ray
from hovr_blender.engine.camera import RayCamera


def test_scan_rays_are_the_pixel_rays_moved_by_fractions_of_a_pixel():
    cam = {"eye": [2.0, -0.7, 1.6], "target": [0.5, 0.5, 0.5], "up": [0, 0, 1], "fov_y_deg": 30.0}
    W, H, i, j = 1920, 1080, 559, 285
    camera = RayCamera.from_contract(cam, W, H)
    offsets = np.linspace(-0.5, 0.5, 11)
    for axis in ("i", "j"):
        o, d = scan_camera(camera, i, j, offsets, axis).rays()
        for k, off in enumerate(offsets):
            o_ref, d_ref = contract_ray(cam, W, H, i + off * (axis == "i"), j + off * (axis == "j"))
            assert np.allclose(o[0, k], o_ref, atol=1e-12)
            assert np.allclose(d[0, k], d_ref, atol=1e-12)
