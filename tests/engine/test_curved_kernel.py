"""Non-affine and curved elements: Newton-located segments through trilinear and curved maps."""
import numpy as np
import pytest

ex = pytest.importorskip("hovr_blender.engine.expansions")
if not hasattr(ex, "invert_map"):
    pytest.skip("engine/expansions.py not implemented yet", allow_module_level=True)

from hovr_blender.engine import shapes  # noqa: E402
from hovr_blender.engine.camera import RayCamera  # noqa: E402
from hovr_blender.engine.mesh import VolumeMesh  # noqa: E402
from hovr_blender.engine.renderer import Renderer  # noqa: E402
from hovr_blender.engine.transfer_function import TransferFunction  # noqa: E402
from hovr_blender.engine.view import RenderOptions  # noqa: E402
from hovr_blender.io.synthetic import straight_geometry  # noqa: E402

from ..helpers import jittered_trilinear_brick, linear_field  # noqa: E402

CAM = {"eye": [2.6, 1.9, 2.2], "target": [0.5, 0.5, 0.5], "up": [0, 0, 1], "fov_y_deg": 40}


def unit_box():
    v = (shapes.VERTICES[shapes.HEX] + 1) / 2
    return VolumeMesh.from_elements([shapes.HEX], (2, 2, 2), [straight_geometry(shapes.HEX, linear_field(*v.T)[:, None].repeat(3, 1))[:, 0]],
                                    (2, 2, 2), [straight_geometry(shapes.HEX, v)])


@pytest.mark.parametrize("method", ["trapezoid", "split"])
def test_trilinear_brick_renders_like_one_box(device, method):
    mesh = jittered_trilinear_brick(3, 0.25)
    assert not mesh.affine.any()
    tf = TransferFunction.from_contract({"color": [[1, 1, 0.3, 0], [4, 0, 0.4, 1]],
                                         "density": [[1.5, 0], [2, 4], [2.5, 0], [3.0, 0], [3.3, 2], [3.6, 0]]})
    cam = RayCamera.from_contract(CAM, 40, 30)
    opts = RenderOptions(method=method, h=0.01, tolerance=1e-7, min_transmittance=0)
    a = Renderer(mesh, device).render(cam, tf, [0, 0, 0], opts)
    b = Renderer(unit_box(), device).render(cam, tf, [0, 0, 0], opts)
    assert b.rgba[..., 3].max() > 0.3
    # trapezoid: each discretises its own segments (error ~2e-4 at this h); split is step-free
    np.testing.assert_allclose(a.rgba, b.rgba, atol=1e-3 if method == "trapezoid" else 5e-5)


def bulged_element(shape, amount=0.15, modes=3):
    """The reference element mapped to itself plus a smooth bulge (quadratic geometry)."""
    pts = ex.fit_points(shape, (modes,) * 3)
    x = pts + amount * np.stack([np.zeros(len(pts)), (1 - pts[:, 0] ** 2) * 0.5, (1 - pts[:, 1] ** 2) * 0.5], axis=1)
    return ex.fit_modal(shape, (modes,) * 3, x)


@pytest.mark.slow
@pytest.mark.parametrize("shape", [shapes.HEX, shapes.PRISM, shapes.TET, shapes.PYR])
def test_curved_chords_match_numpy(device, shape):
    """Constant density in a curved element: T = exp(-tau L), L from the numpy oracle's inversion."""
    g = bulged_element(shape)
    mesh = VolumeMesh.from_elements([shape], (2, 2, 2), [np.ones(ex.num_coeffs(shape, (2, 2, 2)))], (3, 3, 3), [g])
    assert not mesh.affine[0]
    tau = 1.1
    tf = TransferFunction.from_contract({"color": [[0, 1, 1, 1], [3, 1, 1, 1]], "density": [[-9, tau], [9, tau]]})
    cam = RayCamera.from_contract({"eye": [3.0, 2.2, 2.5], "target": [-0.3, 0.0, -0.2], "up": [0, 0, 1],
                                   "fov_y_deg": 45}, 8, 6)
    res = Renderer(mesh, device).render(cam, tf, [0, 0, 0], RenderOptions(method="split", min_transmittance=0))
    O, D = cam.rays()
    ts = np.linspace(0.0, 8.0, 4001)
    pts = O[:, :, None, :] + ts[None, None, :, None] * D[:, :, None, :]
    _, conv, ins = ex.invert_map(shape, (3, 3, 3), g, pts.reshape(-1, 3))
    L = (conv & ins).reshape(pts.shape[:3]).sum(axis=2) * (ts[1] - ts[0])
    assert (L > 0.3).sum() >= 4  # the element really is crossed
    # numpy's chord is a count of 2e-3 steps: compare at that resolution
    np.testing.assert_allclose(-np.log(1 - res.rgba[..., 3]), tau * L, atol=tau * 5e-3)
