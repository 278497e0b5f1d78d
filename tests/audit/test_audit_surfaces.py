"""Isosurface depth and plane values against the independent reference (audit/vtk_reference.py:
VTK's own cells and interpolation, no code shared with the kernels or engine/expansions.py), on
sampled pixels of two third-party curved high-order files: NGSolve's ball (512 curved order-6
hexahedra) and MFEM's Fichera corner (curved order-4 tetrahedra, hexahedra and prisms). float64
renders; agreement within 1e-6 in depth and in value."""
import numpy as np
import pytest

pytest.importorskip("vtkmodules.vtkIOXML", reason="the vtk package (the independent reference's engine) is not installed")

from hovr_blender.audit import vtk_reference as R  # noqa: E402
from hovr_blender.audit import vtk_volume  # noqa: E402
from hovr_blender.engine.isosurfaces import CutPlane, Isosurface, Surfaces  # noqa: E402
from hovr_blender.engine.renderer import Renderer  # noqa: E402
from hovr_blender.engine.transfer_function import TransferFunction  # noqa: E402
from hovr_blender.engine.view import RenderOptions  # noqa: E402
from hovr_blender.io.vtu import read_vtu  # noqa: E402
from tests.helpers import data_file, framing_contract  # noqa: E402

W, H = 20, 15
PIXELS = 5


@pytest.mark.slow
@pytest.mark.parametrize("name, direction", [("ngsolve_ball_poisson_hex_p6.vtu", (1.0, -0.8, 0.7)),
                                             ("mfem_fichera_poisson_mixed_p4.vtu", (1.0, 0.9, 0.8))])
def test_isosurface_depth_and_plane_values_agree_with_vtk(name, direction):
    from hovr_blender.engine.camera import RayCamera

    path = data_file("vtu", name)
    mesh = read_vtu(path, "u")
    grid = vtk_volume.read_vtu(path, "u")
    camera = {"projection": "perspective", **framing_contract(mesh, direction)}
    cam = RayCamera.from_contract(camera, W, H)
    samples = mesh.field_samples(4)
    lo, hi = float(samples.min()), float(samples.max())
    level = float(np.percentile(samples, 60))
    dark = TransferFunction(np.array([lo, hi]), np.zeros((2, 3)), np.array([lo, hi]), np.zeros(2))
    ir = R.IndependentReference(grid, [lo, hi], [[0.0] * 3] * 2, [lo, hi], [0.0, 0.0])
    r = Renderer(mesh, "cpu")
    opts = RenderOptions(precision="float64")
    rng = np.random.default_rng(1)

    iso = r.render(cam, dark, np.zeros(3), opts, surfaces=Surfaces((Isosurface(level, (1.0, 1.0, 1.0)),)))
    js, is_ = np.nonzero(iso.rgba[..., 3] == 1.0)
    assert len(js) >= PIXELS
    for k in rng.choice(len(js), PIXELS, replace=False):
        o, d = R.contract_ray(camera, W, H, is_[k], js[k])
        t_ref = ir.first_crossing(o, d, level)
        assert abs(iso.depth[js[k], is_[k]] - t_ref) < 1e-6, (name, is_[k], js[k], iso.depth[js[k], is_[k]], t_ref)

    # the plane through the data's centre; red = f over [lo, hi] (so red is the field's value)
    box_lo, box_hi = mesh.bounds()
    centre = 0.5 * (box_lo.min(axis=0) + box_hi.max(axis=0))
    plane = CutPlane.through(centre, (0.2, 0.3, 1.0))
    red = TransferFunction(np.array([lo, hi]), np.array([[lo, 0.0, 0.0], [hi, 0.0, 0.0]]), np.array([lo, hi]),
                           np.zeros(2))
    cut = r.render(cam, red, np.zeros(3), opts, surfaces=Surfaces((), (plane,)))
    js, is_ = np.nonzero(cut.rgba[..., 3] == 1.0)
    assert len(js) >= PIXELS
    n = np.asarray(plane.normal)
    for k in rng.choice(len(js), PIXELS, replace=False):
        o, d = R.contract_ray(camera, W, H, is_[k], js[k])
        x = o + (plane.offset - o @ n) / (d @ n) * d
        value = ir.value_at(x)
        if not lo <= value <= hi:
            continue  # clamped by the ramp
        assert abs(cut.rgba[js[k], is_[k], 0] - value) < 1e-6, (name, is_[k], js[k], cut.rgba[js[k], is_[k], 0], value)
