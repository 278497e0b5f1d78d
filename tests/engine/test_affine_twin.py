"""Elements whose maps are affine to float32's rounding of their coordinates are walked as affine in
float32 (mesh.affine_twin at AFFINE_RTOL_FLOAT32, Renderer._upload) and as the file's maps in
float64: a real file gives straight edges by rounded points (hump3D: 1,555 of 1,760 hexahedra
affine to 6e-8 of their size, "curved" to the 1e-12 rule)."""
import numpy as np

from hovr_blender.engine.camera import RayCamera
from hovr_blender.engine.mesh import AFFINE_RTOL_FLOAT32, affine_twin
from hovr_blender.engine.renderer import Renderer
from hovr_blender.engine.transfer_function import TransferFunction
from hovr_blender.engine.view import RenderOptions
from hovr_blender.io.paper_scale import curved_copy
from hovr_blender.io.synthetic import mixed_cube


def _field(x, y, z):
    return x * y + 0.5 * z * z


def _bent(amplitude):
    return curved_copy(mixed_cube(2, 4, _field), lambda x, y, z: (amplitude * x * y, amplitude * (1 - z * z), 0 * x),
                       geom_modes=3)


def _render(mesh, precision):
    cam = RayCamera.from_contract({"projection": "perspective", "eye": [2.2, -1.4, 1.7], "target": [0.5, 0.5, 0.5],
                                   "up": [0, 0, 1], "fov_y_deg": 35.0}, 40, 30)
    tf = TransferFunction(np.array([0.0, 1.5]), np.array([[0.1, 0.2, 0.9], [0.9, 0.6, 0.1]]),
                          np.array([0.0, 1.5]), np.array([0.5, 3.0]))
    return Renderer(mesh, "cpu").render(cam, tf, np.zeros(3), RenderOptions(method="split", precision=precision,
                                                                            device="cpu"))


def test_a_map_straight_to_float32s_rounding_is_affine_in_float32_only():
    straight, nearly, bent = mixed_cube(2, 4, _field), _bent(1e-10), _bent(1e-3)
    assert not nearly.affine.any() and not bent.affine.any()
    twin = affine_twin(nearly, AFFINE_RTOL_FLOAT32)
    assert twin.affine.all()
    np.testing.assert_allclose(twin.ref_from_world, straight.ref_from_world, atol=1e-8)
    assert affine_twin(bent, AFFINE_RTOL_FLOAT32) is bent  # curved beyond float32's rounding: as it was
    assert affine_twin(straight, AFFINE_RTOL_FLOAT32) is straight
    r = Renderer(nearly, "cpu")
    assert r.mesh_args("float32").affine.numpy().all()
    assert not r.mesh_args("float64").affine.numpy().any()


def test_float32_images_of_a_nearly_straight_mesh_are_the_straight_ones_and_float64_keeps_its_maps():
    straight, nearly = mixed_cube(2, 4, _field), _bent(1e-10)
    a32, b32 = _render(straight, "float32"), _render(nearly, "float32")
    assert b32.stats["newton_iterations"] == 0  # no curved element left to locate
    np.testing.assert_allclose(b32.rgba, a32.rgba, rtol=0, atol=1e-6)
    a64, b64 = _render(straight, "float64"), _render(nearly, "float64")
    assert b64.stats["newton_iterations"] > 0  # the file's maps, located by Newton
    np.testing.assert_allclose(b64.rgba, a64.rgba, rtol=0, atol=1e-8)
