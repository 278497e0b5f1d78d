"""The PyFR reader (hovr_blender/io/pyfr) on files PyFR 3.1 wrote (tests/data/pyfr, MANIFEST.md):
a curved mixed mesh of all four element types and its Euler solution of order 2; the same data
as PyFR's own high-order VTU export (its Lagrange cells: tests/data/pyfr/make_shell_cells.py)
gives the same pixels through the VTU reader."""
from __future__ import annotations

import json
import subprocess
import sys

import numpy as np
import pytest

from hovr_blender.engine import expansions as ex
from hovr_blender.engine.camera import RayCamera
from hovr_blender.engine.mesh import subset
from hovr_blender.engine.renderer import Renderer
from hovr_blender.engine.shapes import HEX, PRISM, PYR, TET, VERTICES
from hovr_blender.engine.transfer_function import TransferFunction
from hovr_blender.engine.view import RenderOptions
from hovr_blender.io import formats
from hovr_blender.io.pyfr import PyFRError, elements as el
from hovr_blender.io.pyfr.format import list_fields, read_pyfr  # the parser, in this process
from hovr_blender.io.vtu import read_vtu

from ..helpers import data_file

MESH, SOLN, VTU = "shell.pyfrm", "shell-0.02.pyfrs", "shell_lagrange_p2.vtu"
CAMERA = {"eye": [2.2, -1.6, 1.9], "target": [0.5, 0.45, 0.5], "up": [0, 0, 1], "fov_y_deg": 40.0}
TF = {"color": [[1.0, 0.1, 0.2, 0.8], [1.1, 0.2, 0.9, 0.6], [1.2, 1.0, 0.8, 0.1], [1.3, 1.0, 0.2, 0.1]],
      "density": [[1.0, 0.0], [1.05, 0.5], [1.15, 3.0], [1.3, 8.0]]}
BG = [0.05, 0.05, 0.08]


def files():
    return data_file("pyfr", MESH), data_file("pyfr", SOLN)


@pytest.mark.parametrize("etype", sorted(el.ETYPES))
@pytest.mark.parametrize("order", [1, 2, 3, 4])
def test_change_of_basis_is_exact(etype, order):
    """Values at a point set -> modal coefficients whose expansion takes those values there again
    (an interpolation, not a fit), for PyFR's shape points and a skewed random set."""
    shape, m = el.ETYPES[etype], el.modes(etype, order)
    rng = np.random.default_rng(order)
    # PyFR's shape points, and the same points moved towards the centre and jittered
    shrunk = el.to_engine(etype, el.std_ele(etype, order))
    shrunk = 0.9 * shrunk + 0.1 * ex.uncollapse(shape, np.zeros(3)) + rng.uniform(-0.02, 0.02, shrunk.shape) / order
    for pts in (el.std_ele(etype, order), el.from_engine(etype, shrunk)):
        pts = el.check_points(etype, order, pts)
        values = rng.normal(size=len(pts))
        back = ex.eval_modal(shape, m, el.conversion(etype, order, pts) @ values, el.to_engine(etype, pts))
        assert np.abs(back - values).max() < 1e-9, (etype, order)


def test_points_that_carry_no_polynomial_are_refused():
    pts = el.std_ele("tet", 2)
    pts[3] = pts[2]  # two points alike: no interpolant
    with pytest.raises(el.PointsError, match="do not determine"):
        el.check_points("tet", 2, pts)
    with pytest.raises(el.PointsError, match="outside"):
        el.check_points("hex", 1, el.std_ele("hex", 1) * 1.5)


def test_reads_the_mixed_curved_case():
    mesh_path, soln_path = files()
    assert list_fields(soln_path) == ["rho", "u", "v", "w", "p", "rhou", "rhov", "rhow", "E"]
    m = read_pyfr(mesh_path, soln_path, "rho")
    counts = {s: int((m.shape == s).sum()) for s in (HEX, PRISM, PYR, TET)}
    assert counts == {HEX: 12, PRISM: 22, PYR: 6, TET: 240}
    assert not m.affine.all() and m.affine.any()  # the elements along the arc are curved
    assert (m.modes[m.shape == PYR] == 5).all() and (m.modes[m.shape != PYR] == 3).all()
    # the density pulse 1 + 0.3 exp(...) after 10 steps: PyFR's values at its points lie in
    # (0.71, 1.30), their interpolants overshoot between them (the slip walls turn the initial
    # velocity into waves)
    samples = m.field_samples(3)
    assert 0.4 < samples.min() and samples.max() < 1.6 and np.ptp(samples) > 0.3
    assert formats.format_of(mesh_path).name == "pyfr"


def test_a_partitioned_run_reads_as_the_one_part_run():
    """The shell case partitioned in two by PyFR (SCOTCH) and run on two MPI ranks: its solution
    holds each element's rank (-parts) in the mesh's element order, and the mesh its partitioning;
    the read equals the one-rank run's to the ranks' summation order (PyFR's values differ by
    8e-13), whichever partitioning the mesh holds."""
    import h5py

    mesh_path, soln_path = files()
    parted, parted_soln = data_file("pyfr", "shell-2parts.pyfrm"), data_file("pyfr", "shell-2parts-0.02.pyfrs")
    with h5py.File(parted, "r") as m, h5py.File(parted_soln, "r") as s:
        assert set(m["partitionings"]) == {"1", "2"}
        assert set(np.unique(s["soln/p2-tet-parts"][...])) == {0, 1}  # both ranks wrote elements
    for name in ("rho", "p"):
        one, two = read_pyfr(mesh_path, soln_path, name), read_pyfr(parted, parted_soln, name)
        np.testing.assert_array_equal(two.geom_coeffs, one.geom_coeffs)
        np.testing.assert_allclose(two.coeffs, one.coeffs, rtol=0, atol=1e-11)
    assert read_pyfr(parted).num_elements == 280  # the solution beside the mesh, by its name


def test_primitives_are_the_solvers_at_its_points():
    """u = rhou / rho and p = (gamma - 1)(E - |m|^2 / 2 rho) hold at the solution points."""
    mesh_path, soln_path = files()
    meshes = {n: read_pyfr(mesh_path, soln_path, n) for n in ("rho", "rhou", "u", "E", "rhov", "rhow", "p")}
    from hovr_blender.io.pyfr.files import read_solution
    pts = read_solution(soln_path).blocks["tet"][3]
    first = int(np.nonzero(meshes["rho"].shape == TET)[0][0])
    xi = el.to_engine("tet", pts)

    def at(name):
        mm = meshes[name]
        o, k = mm.coeff_offset[first], ex.num_coeffs(TET, mm.modes[first])
        return ex.eval_modal(TET, mm.modes[first], mm.coeffs[o:o + k], xi)

    assert np.allclose(at("u"), at("rhou") / at("rho"), rtol=0, atol=1e-12)
    kinetic = 0.5 * (at("rhou") ** 2 + at("rhov") ** 2 + at("rhow") ** 2) / at("rho")
    assert np.allclose(at("p"), 0.4 * (at("E") - kinetic), rtol=0, atol=1e-12)


def test_derived_fields_from_the_momenta():
    mesh_path, soln_path = files()
    q = read_pyfr(mesh_path, soln_path, "Q(rhou,rhov,rhow/rho)")
    assert q.derived is not None and q.field_name == "Q(rhou,rhov,rhow/rho)"
    with pytest.raises(PyFRError, match="no field 'T'"):
        read_pyfr(mesh_path, soln_path, "T")


@pytest.fixture(scope="module")
def native_and_export():
    mesh_path, soln_path = files()
    native = read_pyfr(mesh_path, soln_path, "rho")
    lagrange = subset(native, np.nonzero(native.shape != PYR)[0])  # PyFR exports pyramids as linear sub-cells
    return lagrange, read_vtu(data_file("pyfr", VTU), "Density")


def test_export_holds_the_same_polynomials(native_and_export):
    native, export = native_and_export
    assert native.num_elements == export.num_elements == 274
    rng = np.random.default_rng(5)
    # the same element in both: the one whose vertex centroid is the same
    centres = {id(mesh): np.array([mesh.vertices[e][: len(VERTICES[int(mesh.shape[e])])].mean(axis=0)
                                   for e in range(mesh.num_elements)]) for mesh in (native, export)}
    worst = 0.0
    for e in range(native.num_elements):
        k = int(np.argmin(np.linalg.norm(centres[id(export)] - centres[id(native)][e], axis=1)))
        sh, gm = int(native.shape[e]), native.geom_modes[e]
        g = native.geom_coeffs[native.geom_offset[e]: native.geom_offset[e] + ex.num_coeffs(sh, gm)]
        x = ex.eval_modal(sh, gm, g, ex.uncollapse(sh, rng.uniform(-0.9, 0.9, (6, 3))))
        worst = max(worst, float(np.abs(native.evaluate(e, x) - export.evaluate(k, x)).max()))
    assert worst < 1e-12, worst


@pytest.mark.parametrize("method", ["split", "classified"])
def test_same_image_as_pyfrs_own_export(device, native_and_export, method):
    """256 x 256, split and classified: native .pyfrm/.pyfrs against PyFR's VTU export. The two
    hold each element's polynomial in different reference frames (different coefficients), so the
    kernels run in float64: in float32 their rounding alone moves pixels by ~1e-5."""
    native, export = native_and_export
    cam = RayCamera.from_contract(CAMERA, 256, 256)
    tf = TransferFunction.from_contract(TF)
    opts = RenderOptions(method=method, h=0.01, tolerance=1e-8, min_transmittance=0.0, precision="float64")
    a = Renderer(native, device).render(cam, tf, BG, opts).rgba.astype(np.float64)
    b = Renderer(export, device).render(cam, tf, BG, opts).rgba.astype(np.float64)
    assert a[..., 3].max() > 0.2 and np.ptp(a[..., :3], axis=(0, 1)).max() > 0.1
    diff = float(np.abs(a - b).max())
    print(f"pyfr shell {method} {device}: max |native - export| = {diff:.2e}")
    assert diff <= 1e-6, (method, diff)


def test_renders_in_the_cli(tmp_path):
    mesh_path, soln_path = files()
    view = {"data": {"path": str(mesh_path), "field": "p"}, "camera": CAMERA, "image": {"width": 48, "height": 40},
            "transfer_function": {"color": [[0.7, 0.1, 0.2, 0.9], [1.0, 1.0, 0.6, 0.1]],
                                  "density": [[0.7, 0.0], [1.0, 4.0]]},
            "background": BG, "render": {"method": "split"}}
    (tmp_path / "v.json").write_text(json.dumps(view))
    out = subprocess.run([sys.executable, "-m", "hovr_blender.cli", "render", str(tmp_path / "v.json"),
                          "-o", str(tmp_path / "v.npy")], capture_output=True, text=True, timeout=600)
    assert out.returncode == 0, out.stderr
    image = np.load(tmp_path / "v.npy")
    assert image.shape == (40, 48, 4) and image[..., 3].max() > 0.05
