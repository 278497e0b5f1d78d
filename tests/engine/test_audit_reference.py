"""The independent reference (hovr_blender/audit): the conversion of project meshes to VTK
Lagrange cells, checked through VTK's own interpolation against analytic solutions, and the
integrator against the float64 reference where both are exact (the paper's sphere)."""
import json

import numpy as np
import pytest

pytest.importorskip("vtkmodules.vtkIOXML", reason="the vtk package (the independent reference's engine) is not installed")

from hovr_blender.audit import reference as R  # noqa: E402
from hovr_blender.audit import vtk_volume  # noqa: E402
from hovr_blender.engine import expansions as ex  # noqa: E402
from hovr_blender.engine.camera import RayCamera  # noqa: E402
from hovr_blender.engine.reference import reference_render  # noqa: E402
from hovr_blender.engine.view import View  # noqa: E402
from hovr_blender.io import builtin  # noqa: E402
from hovr_blender.io.nektar import read_nektar  # noqa: E402
from tests.helpers import REPO  # noqa: E402
from tests.helpers import data_file as shared_file  # noqa: E402


def vtk_values(grid, points):
    """(field, inside) at world points through VTK's cells only: the cells whose (padded) box
    holds the point, located by the reference (VTK's Newton, polished on VTK's own shape
    functions)."""
    ir = R.IndependentReference(grid, [0.0], [[0.0, 0.0, 0.0]], [0.0], [0.0])
    out, found = [], []
    for x in points:
        near = np.nonzero(np.all((ir.lo <= x) & (x <= ir.hi), axis=1))[0]
        value, inside = np.nan, False
        for c in near:
            inside, value = ir._at(c, x)
            if inside:
                break
        found.append(inside)
        out.append(value)
    return np.array(out), np.array(found)


def interior_points(mesh, n, rng):
    """World points inside the mesh's elements: random reference points mapped by the elements'
    own geometry (the values there are judged against the exact solution, not against it)."""
    out = []
    for e in rng.integers(0, mesh.num_elements, n):
        sh = int(mesh.shape[e])
        xi = rng.uniform(-0.95, 0.95, (64, 3))
        xi = xi[ex.inside(sh, xi, tol=-0.02)][:1]  # strictly inside, off the faces
        o = int(mesh.geom_offset[e])
        g = mesh.geom_coeffs[o:o + ex.num_coeffs(sh, mesh.geom_modes[e])]
        out.append(ex.eval_modal(sh, mesh.geom_modes[e], g, xi)[0])
    return np.array(out)


@pytest.mark.parametrize("stem, field, exact, tol", [
    ("Tet_channel_m3", "w", lambda x: x[:, 1] * (1 - x[:, 1]), 1e-12),
    ("Tet_channel_m3", "p", lambda x: -2 * (x[:, 2] - 1), 1e-12),
    ("Hex_01_01_01_03Modes_x2_Offset3", "p", lambda x: (x ** 2).sum(axis=1), 1e-12),
])
def test_converted_nektar_data_interpolate_the_exact_solution_in_vtk(stem, field, exact, tol):
    mesh = read_nektar(shared_file("nektar", stem + ".xml"), shared_file("nektar", stem + ".fld"), field)
    grid = vtk_volume.from_mesh(mesh)
    x = interior_points(mesh, 200, np.random.default_rng(0))
    got, found = vtk_values(grid, x)
    assert found.all()
    np.testing.assert_allclose(got, exact(x), atol=tol * max(1.0, np.abs(exact(x)).max()))


def test_converted_curved_hexahedron_in_vtk():
    """Hex_Mushroom: curved edges, 15 modes, u = sin(pi x/2) sin(pi y/2) sin(pi z/2) to 2.5e-9
    with Nektar++'s own geometry (its MANIFEST)."""
    mesh = read_nektar(shared_file("nektar", "Hex_Mushroom.xml"), shared_file("nektar", "Hex_Mushroom.fld"), "u")
    grid = vtk_volume.from_mesh(mesh)
    x = interior_points(mesh, 100, np.random.default_rng(1))
    got, found = vtk_values(grid, x)
    assert found.all()
    exact = np.prod(np.sin(np.pi * x / 2), axis=1)
    np.testing.assert_allclose(got, exact, atol=2.5e-9)


def test_pyramids_are_refused():
    mesh = read_nektar(shared_file("nektar", "Helmholtz3D_Pyr_Deformed.xml"))
    with pytest.raises(vtk_volume.AuditError, match="pyramid"):
        vtk_volume.from_mesh(mesh)


def test_reference_matches_the_float64_reference_on_the_sphere():
    """Both exact on the paper's sphere (an affine hexahedron): the independent reference agrees
    with engine/reference.py to 1e-9 and its own error estimate says so."""
    view = View.load(str(REPO / "examples" / "sphere.json"))
    cam = json.loads((REPO / "examples" / "sphere.json").read_text())["camera"]
    W, H = 40, 30
    mesh = builtin.sphere()
    ref, _ = reference_render(mesh, RayCamera.from_contract(cam, W, H), view.transfer_function, view.background)
    tf = view.transfer_function
    ir = R.IndependentReference(vtk_volume.from_mesh(mesh), tf.color_s, tf.color_rgb, tf.density_s,
                                tf.density_tau, tol=1e-10)
    js, is_ = np.nonzero(ref[..., 3] > 0.01)
    pick = np.random.default_rng(0).choice(len(js), 12, replace=False)
    for k in pick:
        o, d = R.contract_ray(cam, W, H, is_[k], js[k])
        p = ir.pixel(o, d, view.background)
        assert np.abs(p.rgba - ref[js[k], is_[k]]).max() < 1e-9
        assert p.error < 1e-8
    o, d = R.contract_ray(cam, W, H, 0, 0)  # a ray that misses the box
    p = ir.pixel(o, d, view.background)
    np.testing.assert_array_equal(p.rgba, [*view.background, 0.0])



def test_a_cell_the_ray_only_clips_is_not_missed():
    """A ray in a 2 x 2 brick passing 1e-3 beside the vertex the four cells share clips one cell
    over a chord of 8e-4, which fell between the samples of its box (SAMPLES_PER_BOX) and left
    a gap (1e-4 of alpha lost). Constant density: T = exp(-tau L) over the whole chord L."""
    from hovr_blender.audit.chords import box_chord
    from hovr_blender.io.synthetic import brick

    mesh = brick([0.0, 0.0, 0.0], [2.0, 2.0, 1.0], (2, 2, 1), 2, lambda x, y, z: 0.0 * x + 1.0)
    tau = 1.0
    ir = R.IndependentReference(vtk_volume.from_mesh(mesh), [0.0, 2.0], [[0.3, 0.6, 0.9]] * 2, [0.0, 2.0],
                                [tau, tau], tol=1e-10)
    d = np.array([1.0, 1.3, 0.0]) / np.linalg.norm([1.0, 1.3, 0.0])
    o = np.array([1.0, 1.0 + 1e-3, 0.5]) - 3.0 * d  # through (1, 1.001): cells 0, 2 (clipped), 3
    p = ir.pixel(o, d, np.zeros(3))
    assert {c for _, _, c in p.stretches} == {0, 2, 3}
    chord = float(box_chord(o[None], d[None], np.zeros(3), np.array([2.0, 2.0, 1.0]))[0])
    assert abs(p.rgba[3] - (1.0 - np.exp(-tau * chord))) < 1e-10
