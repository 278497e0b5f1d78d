"""A straight mesh without a geometry expansion (builtin sphere: from_affine_hexes) merges with
curved ones (several Blender volumes in one pass): with_geometry_expansion gives it trilinear
geometry whose vertex modes are its vertices, the same field, and the same image."""
import numpy as np

from hovr_blender.engine.camera import RayCamera
from hovr_blender.engine.mesh import concatenate, with_geometry_expansion
from hovr_blender.engine.renderer import Renderer
from hovr_blender.engine.transfer_function import TransferFunction
from hovr_blender.engine.view import RenderOptions
from hovr_blender.io import builtin

from ..helpers import jittered_trilinear_brick


def test_straight_mesh_gets_an_exact_geometry_expansion():
    m = builtin.sphere()
    g = with_geometry_expansion(m)
    assert m.geom_coeffs is None and g.geom_coeffs is not None and g.affine.all()
    np.testing.assert_allclose(g.ref_from_world, m.ref_from_world, atol=1e-14)
    x = np.random.default_rng(0).uniform(-2, 2, (50, 3))
    np.testing.assert_allclose(g.evaluate(0, x), m.evaluate(0, x), atol=1e-12)
    cam = RayCamera.from_contract({"eye": [6, 5, 4], "target": [0, 0, 0], "up": [0, 0, 1], "fov_y_deg": 40}, 24, 18)
    tf = TransferFunction.from_rgba_ramp([0, 0.5, 1], [(1, 0, 0, 0), (0, 1, 0, 1), (0, 0, 1, 0)], 0.5, 0.0, 18.0)
    opts = RenderOptions(precision="float64", tolerance=1e-8)
    a = Renderer(m).render(cam, tf, np.zeros(3), opts).rgba
    b = Renderer(g).render(cam, tf, np.zeros(3), opts).rgba
    assert a[..., 3].max() > 0.1
    np.testing.assert_allclose(b, a, atol=1e-7)


def test_mixed_meshes_concatenate():
    curved = jittered_trilinear_brick(2, 0.1)
    merged = concatenate([builtin.sphere().transformed(np.diag([0.1, 0.1, 0.1, 1.0])), curved])
    assert merged.num_elements == 1 + curved.num_elements
    assert merged.volume.tolist() == [0] + [1] * curved.num_elements
