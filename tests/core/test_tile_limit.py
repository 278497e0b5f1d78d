"""Launch tiles follow the resource policy's memory limit (core/limits.py): a render whose
one-tile buffers would exceed the limit is split into more tiles instead of being refused, and
the tiles do not change a pixel."""
import numpy as np

from hovr_blender.core import limits
from hovr_blender.core.camera import RayCamera
from hovr_blender.core.renderer import Renderer
from hovr_blender.core.transfer_function import TransferFunction
from hovr_blender.core.view import RenderOptions
from hovr_blender.io.synthetic import curved_cube


def _scene():
    mesh = curved_cube(2)
    V = mesh.vertices.reshape(-1, 3)
    c = 0.5 * (V.min(0) + V.max(0))
    cam = RayCamera.from_contract({"eye": [float(x) for x in c + [3.0, -2.0, 2.0]], "target": [float(x) for x in c],
                                   "up": [0, 0, 1], "fov_y_deg": 30}, 96, 64)
    v = mesh.field_samples(3)
    a, b = float(v.min()), float(v.max())
    tf = TransferFunction.from_contract({"color": [[a, 1, 0.2, 0], [b, 0, 0.3, 1]], "density": [[a, 0.0], [b, 3.0]]})
    return mesh, cam, tf


def test_tile_follows_memory_limit_and_keeps_pixels():
    mesh, cam, tf = _scene()
    r = Renderer(mesh, "cpu")
    prec = r._upload("float32").precision
    whole = r.render(cam, tf, np.zeros(3), RenderOptions())
    small = limits.ResourceLimits(max_memory=int(6000 * r._ray_bytes(prec)))  # tiles of ~3000 rays
    with limits.using(small):
        tile = r._tile_limit(prec)
        assert tile * r._ray_bytes(prec) <= 0.5 * small.max_memory
        assert tile < cam.width * cam.height  # the 96x64 image takes several tiles
        tiled = r.render(cam, tf, np.zeros(3), RenderOptions())
    np.testing.assert_array_equal(tiled.rgba, whole.rgba)
