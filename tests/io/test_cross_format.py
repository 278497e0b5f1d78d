"""Cross-format pixels: a real Nektar++ field, rewritten by vtk's own writer as Lagrange cells that
hold exactly the same polynomial per element, renders to the same image through read_vtu as
through read_nektar (tetrahedra and a hexahedron; two quadrature methods)."""
from __future__ import annotations

import numpy as np
import pytest

from hovr_blender.engine import expansions as ex
from hovr_blender.engine import shapes
from hovr_blender.engine.camera import RayCamera
from hovr_blender.engine.renderer import Renderer
from hovr_blender.engine.transfer_function import TransferFunction
from hovr_blender.engine.view import RenderOptions
from hovr_blender.io.nektar import read_nektar
from hovr_blender.io.vtu import read_vtu

from ..helpers import data_file as shared_file

VTK_LAGRANGE = {shapes.TET: 71, shapes.HEX: 72}

# Both files are straight-sided (affine elements) and carry a field of known form:
# Tet_channel_m3: 48 tetrahedra, 3 modes (P2), w = y(1 - y) in [0, 0.25];
# Hex_01_01_01_03Modes_x2_Offset3: one hexahedron [-1,1]^2 x [-4,-2], 3 modes (Q2), p = x^2+y^2+z^2.
CASES = {
    "tet": dict(mesh="Tet_channel_m3.xml", fld="Tet_channel_m3.fld", field="w",
                camera={"eye": [2.3, -1.4, 1.9], "target": [0.5, 0.5, 0.45], "up": [0, 0, 1], "fov_y_deg": 38.0},
                tf={"color": [[0.0, 0.1, 0.2, 0.9], [0.1, 0.2, 0.9, 0.4], [0.18, 0.9, 0.5, 0.1], [0.25, 1.0, 0.1, 0.1]],
                    "density": [[0.0, 0.0], [0.08, 0.4], [0.12, 3.0], [0.16, 0.2], [0.22, 0.5], [0.25, 8.0]]}),
    "hex": dict(mesh="Hex_01_01_01_03Modes_x2_Offset3.xml", fld="Hex_01_01_01_03Modes_x2_Offset3.fld", field="p",
                camera={"eye": [4.0, -3.0, 0.5], "target": [0.0, 0.0, -3.0], "up": [0, 0, 1], "fov_y_deg": 40.0},
                tf={"color": [[4.0, 0.9, 0.9, 0.2], [6.0, 0.2, 1.0, 0.3], [10.0, 0.1, 0.4, 1.0], [17.0, 1.0, 0.2, 0.6]],
                    "density": [[4.5, 0.0], [5.0, 1.5], [5.5, 0.0], [8.5, 0.0], [9.0, 1.0], [11.0, 0.1],
                                [15.0, 0.0], [16.0, 0.8], [17.0, 0.0]]}),
}
BG = [0.05, 0.04, 0.08]
W, H = 48, 32
# Both meshes carry the same polynomial per element, so the renders differ only by float32
# rounding: the kernel works in float32 on coefficient sets that agree to ~1e-15 in float64 but
# are different numbers (VTU: modal fit of Lagrange nodes; Nektar++: the file's modes), so each
# sample may move by a few float32 ulps (~1e-7 relative) and a pixel accumulates O(1e-6). A wrong
# node order, basis or geometry changes pixels by >= 1e-3 (checked below with a perturbed node).
# Measured on the CPU: 0 (the float32 coefficients differ only where they are ~1e-16).
TOL = 1e-5


def need_vtk():
    return pytest.importorskip("vtk", reason="the vtk package (the third-party writer) is not installed")


def vtk_parametric_coords(vtk, cell_type, n):
    """VTK's own parametric node coordinates (VTK point order) of a Lagrange cell with n nodes."""
    ug = vtk.vtkUnstructuredGrid()
    pts = vtk.vtkPoints()
    for i in range(n):
        pts.InsertNextPoint(float(i), 0.0, 0.0)
    ug.SetPoints(pts)
    ug.InsertNextCell(cell_type, n, list(range(n)))
    return np.array(ug.GetCell(0).GetParametricCoords()).reshape(n, 3)


def write_lagrange_vtu(vtk, mesh, path, perturb=None):
    """Each element of an affine Nektar++ mesh as one VTK Lagrange cell of degree P = modes - 1,
    nodes at VTK's Lagrange points, mapped through the element's own geometry, values from
    VolumeMesh.evaluate there. vtk's reference tetrahedron/hexahedron [0,1]^3 maps onto Nektar++'s
    [-1,1]^3 reference by xi = 2r - 1 (vertex onto vertex, affine), so the field composed with the
    map is still a polynomial of degree P in r: the Lagrange cell holds exactly the same polynomial.
    perturb=(node, delta) changes that node's value in every cell (the sensitivity check)."""
    ug = vtk.vtkUnstructuredGrid()
    pts = vtk.vtkPoints()
    pts.SetDataTypeToDouble()
    val = vtk.vtkDoubleArray()
    val.SetName(mesh.field_name)
    for e in range(mesh.num_elements):
        sh = int(mesh.shape[e])
        modes = mesh.modes[e]
        assert len(set(modes.tolist())) == 1 and mesh.affine[e], "isotropic affine elements only"
        p = int(modes[0]) - 1
        n = (p + 1) ** 3 if sh == shapes.HEX else (p + 1) * (p + 2) * (p + 3) // 6
        r = vtk_parametric_coords(vtk, VTK_LAGRANGE[sh], n)
        gm = mesh.geom_modes[e]
        g = mesh.geom_coeffs[mesh.geom_offset[e]: mesh.geom_offset[e] + ex.num_coeffs(sh, gm)]
        x = ex.eval_modal(sh, gm, g, 2.0 * r - 1.0)
        v = mesh.evaluate(e, x)
        if perturb is not None:
            v = v.copy()
            v[perturb[0]] += perturb[1]
        ids = [pts.InsertNextPoint(*xx) for xx in x]
        for vv in v:
            val.InsertNextValue(float(vv))
        ug.InsertNextCell(VTK_LAGRANGE[sh], len(ids), ids)
    ug.SetPoints(pts)
    ug.GetPointData().AddArray(val)
    w = vtk.vtkXMLUnstructuredGridWriter()
    w.SetFileName(str(path))
    w.SetInputData(ug)
    w.SetDataModeToBinary()
    assert w.Write() == 1
    return path


@pytest.fixture(scope="module", params=sorted(CASES))
def case(request, tmp_path_factory):
    vtk = need_vtk()
    c = CASES[request.param]
    nek = read_nektar(shared_file("nektar", c["mesh"]), shared_file("nektar", c["fld"]), field=c["field"])
    tmp = tmp_path_factory.mktemp(f"cross_{request.param}")
    vtu_mesh = read_vtu(write_lagrange_vtu(vtk, nek, tmp / "same.vtu"), c["field"])
    # one node value per cell moved by 1 % of the field's range: the comparison must see it
    bump = 0.01 * np.ptp(nek.field_samples(5))
    bumped = read_vtu(write_lagrange_vtu(vtk, nek, tmp / "bumped.vtu", perturb=(4, bump)), c["field"])
    cam = RayCamera.from_contract(c["camera"], W, H)
    tf = TransferFunction.from_contract(c["tf"])
    return request.param, nek, vtu_mesh, bumped, cam, tf


def test_vtu_holds_the_same_polynomial(case):
    """Per element, the VTU-read field equals the Nektar++ field at random interior points."""
    name, nek, vm, _, _, _ = case
    assert vm.num_elements == nek.num_elements
    assert np.array_equal(vm.shape, nek.shape) and np.array_equal(vm.modes, nek.modes)
    assert vm.affine.all()  # straight-sided cells recognised as affine: the kernel's exact path
    rng = np.random.default_rng(11)
    worst = 0.0
    scale = np.abs(nek.coeffs).max()
    for e in range(nek.num_elements):
        xi = rng.uniform(-1, 1, (20, 3))
        xi = xi[ex.inside(int(nek.shape[e]), xi, tol=0.0)]
        sh, gm = int(nek.shape[e]), nek.geom_modes[e]
        g = nek.geom_coeffs[nek.geom_offset[e]: nek.geom_offset[e] + ex.num_coeffs(sh, gm)]
        pts = ex.eval_modal(sh, gm, g, xi)
        worst = max(worst, float(np.abs(vm.evaluate(e, pts) - nek.evaluate(e, pts)).max()))
    assert worst < 1e-12 * scale, (name, worst)


@pytest.mark.parametrize("method", ["split", "classified"])
def test_same_pixels_from_both_formats(device, case, method):
    name, nek, vm, bumped, cam, tf = case
    opts = RenderOptions(method=method, h=0.01, tolerance=1e-6, min_transmittance=0.0)
    a = Renderer(nek, device).render(cam, tf, BG, opts).rgba.astype(np.float64)
    b = Renderer(vm, device).render(cam, tf, BG, opts).rgba.astype(np.float64)
    # the image has structure: some rays see the volume, and not all alike
    assert a[..., 3].max() > 0.2 and np.ptp(a[..., :3], axis=(0, 1)).max() > 0.1, (name, a[..., 3].max())
    diff = float(np.abs(a - b).max())
    print(f"{name} {method} {device}: max |nektar - vtu| = {diff:.2e}, alpha max {a[..., 3].max():.3f}")
    assert diff <= TOL, (name, method, diff)
    c = Renderer(bumped, device).render(cam, tf, BG, opts).rgba.astype(np.float64)
    assert float(np.abs(a - c).max()) > 100 * TOL, (name, method, "a 1 % node change is invisible")
