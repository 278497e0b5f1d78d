"""Derived fields (contract §8) against closed forms on curved elements of all four shapes: a
polynomial velocity u = (x^2 + y z, x y - z^2, x z + y) whose gradient, vorticity and Q are
known exactly, the same velocity as momenta over a density (a quotient), and |grad f|. The host
oracle (derived_fields.derived_values) against the closed forms; whole renders (the kernels'
exact samples) against numpy: a cut plane coloured by Q at its crossing, and the depth of a
Q isosurface against the closed form's root along each ray; the name grammar and its errors."""
import numpy as np
import pytest

from hovr_blender.engine import expansions as ex
from hovr_blender.engine.derived_fields import (DerivedFieldError, derived_mesh, derived_values, parse_derived)
from hovr_blender.engine.isosurfaces import CutPlane, Isosurface, Surfaces
from hovr_blender.engine.render_result import RenderError
from hovr_blender.engine.renderer import Renderer
from hovr_blender.engine.transfer_function import TransferFunction
from hovr_blender.engine.view import RenderOptions
from hovr_blender.io.synthetic import curved_cube, with_field
from tests.helpers import framing


def velocity(x, y, z):
    return x * x + y * z, x * y - z * z, x * z + y


def density(x, y, z):
    return 1.0 + 0.5 * x


def q_exact(x, y, z):
    # L = [[2x, z, y], [y, x, -2z], [z, 1, x]]: Q = -1/2 tr(L L) = -3 x^2 - 2 y z + 2 z
    return -3.0 * x * x - 2.0 * y * z + 2.0 * z


def vorticity_exact(x, y, z):
    return np.sqrt((1.0 + 2.0 * z) ** 2 + 2.0 * (y - z) ** 2)


def grad_exact(x, y, z):
    return np.sqrt(4.0 * x * x + z * z + y * y)  # f = u_0 = x^2 + y z


@pytest.fixture(scope="module")
def geometry():
    return curved_cube(2)  # 31 elements of all four shapes; quadratic maps: a degree-2 field is degree 4 in xi


@pytest.fixture(scope="module")
def velocity_components(geometry):
    return [with_field(geometry, lambda x, y, z, i=i: velocity(x, y, z)[i], 5, f"u{i}") for i in range(3)]


@pytest.fixture(scope="module")
def momentum_components(geometry):
    comps = [with_field(geometry, lambda x, y, z, i=i: density(x, y, z) * velocity(x, y, z)[i], 7, f"m{i}")
             for i in range(3)]
    return comps + [with_field(geometry, density, 7, "rho")]


def _mapped(mesh, e, xi):
    sh = int(mesh.shape[e])
    o = int(mesh.geom_offset[e])
    G = mesh.geom_coeffs[o:o + ex.num_coeffs(sh, mesh.geom_modes[e])]
    return ex.eval_modal(sh, mesh.geom_modes[e], G, xi)


@pytest.mark.parametrize("name, exact", [("Q(u0,u1,u2)", q_exact), ("vorticity(u0,u1,u2)", vorticity_exact),
                                         ("speed(u0,u1,u2)", lambda x, y, z: np.linalg.norm(velocity(x, y, z), axis=0)),
                                         ("|grad|(u0)", grad_exact)])
def test_oracle_against_closed_forms(velocity_components, name, exact):
    spec = parse_derived(name)
    mesh = derived_mesh(spec, velocity_components[:1] if spec.operation == "|grad|" else velocity_components)
    for e in range(mesh.num_elements):
        sh = int(mesh.shape[e])
        xi = ex.fit_points(sh, (3, 3, 3)) * 0.9
        got = derived_values(mesh, mesh.derived, [e], xi)[0]
        x = _mapped(mesh, e, xi)
        np.testing.assert_allclose(got, exact(x[:, 0], x[:, 1], x[:, 2]), rtol=1e-9, atol=1e-9)
    assert mesh.field_name == spec.name


def test_quotient_is_the_velocity(momentum_components):
    """Q of momenta over density equals Q of the velocity they encode (exact per sample: u = m / rho
    is no polynomial, its derivatives by the quotient rule)."""
    mesh = derived_mesh(parse_derived("Q(m0,m1,m2/rho)"), momentum_components)
    for e in range(mesh.num_elements):
        xi = ex.fit_points(int(mesh.shape[e]), (3, 3, 3)) * 0.9
        x = _mapped(mesh, e, xi)
        np.testing.assert_allclose(derived_values(mesh, mesh.derived, [e], xi)[0], q_exact(*x.T), rtol=1e-8, atol=1e-8)


def test_transformed_keeps_data_units(velocity_components):
    """An object scaled by 2 and rotated: Q is still the data's (the Jacobian's object part undone)."""
    mesh = derived_mesh(parse_derived("Q(u0,u1,u2)"), velocity_components)
    c, s = np.cos(0.3), np.sin(0.3)
    M = np.array([[2 * c, -2 * s, 0, 1.0], [2 * s, 2 * c, 0, 0], [0, 0, 2, -1.0], [0, 0, 0, 1]])
    moved = mesh.transformed(M)
    e = 3
    xi = ex.fit_points(int(mesh.shape[e]), (3, 3, 3)) * 0.9
    np.testing.assert_allclose(derived_values(moved, moved.derived, [e], xi), derived_values(mesh, mesh.derived, [e], xi),
                               rtol=1e-9, atol=1e-9)


@pytest.mark.parametrize("text, message", [
    ("Q(rho)", None), ("Q(a,b)", "needs a velocity"), ("|grad|(a,b)", "one scalar"), ("vorticity(u,,w)", "separated"),
    ("Q(u,v,w", "OPERATION(components)")])
def test_grammar_errors(text, message):
    if message is None:
        assert parse_derived(text).components == ("rho",)  # one name: the reader decides whether it is a vector
        return
    with pytest.raises(DerivedFieldError, match=message.replace("(", r"\(").replace(")", r"\)")):
        parse_derived(text)


def test_grammar():
    assert parse_derived("p") is None
    assert parse_derived("|u,v,w|") is None  # the magnitude fit's syntax (io/magnitude.py), not this one
    spec = parse_derived(" vorticity( rhou, rhov ,rhow / rho ) ")
    assert spec.components == ("rhou", "rhov", "rhow") and spec.density == "rho"
    assert spec.name == "vorticity(rhou,rhov,rhow/rho)"


# ------------------------------------------------------------------ whole renders


def _clear_tf(lo, hi):
    """No volume; the colour ramp red = (s - lo) / (hi - lo) on the planes."""
    return TransferFunction(np.array([lo, hi]), np.array([[0.0, 0.0, 0.0], [1.0, 0.0, 0.0]]), np.array([lo, hi]),
                            np.zeros(2))


@pytest.fixture(scope="module")
def q_mesh(velocity_components):
    return derived_mesh(parse_derived("Q(u0,u1,u2)"), velocity_components)


def test_plane_colour_is_q_at_the_crossing(q_mesh, device):
    cam = framing(q_mesh, 20, 16)
    lo, hi = -4.0, 3.0
    plane = CutPlane.through((0.5, 0.5, 0.43), (0.2, 0.1, 1.0))
    res = Renderer(q_mesh, device).render(cam, _clear_tf(lo, hi), np.zeros(3),
                                          RenderOptions(precision="float64", device=device),
                                          surfaces=Surfaces((), (plane,)))
    o, d = cam.rays()
    n = np.asarray(plane.normal)
    t = (plane.offset - o @ n) / (d @ n)
    x = o + t[..., None] * d
    hit = res.rgba[..., 3] > 0.5
    assert hit.sum() > 60
    want = (q_exact(*x[hit].T) - lo) / (hi - lo)
    assert np.abs(res.rgba[hit][:, 0] - want).max() < 1e-6


def _first_root(o, d, level, t0, t1, n=4000):
    """The first t in [t0, t1] where Q(o + t d) crosses level (bisected), nan where none."""
    ts = np.linspace(t0, t1, n)
    q = q_exact(*(o[None] + ts[:, None] * d[None]).T) - level
    k = np.nonzero(np.sign(q[:-1]) != np.sign(q[1:]))[0]
    if k.size == 0:
        return np.nan, 0.0
    a, b = ts[k[0]], ts[k[0] + 1]
    for _ in range(60):
        m = 0.5 * (a + b)
        if np.sign(q_exact(*(o + m * d)) - level) == np.sign(q[k[0]]):
            a = m
        else:
            b = m
    slope = abs(q[k[0] + 1] - q[k[0]]) / (ts[1] - ts[0])
    return 0.5 * (a + b), slope


def test_q_isosurface_depth(q_mesh, device):
    """The depth of Q = -0.8 against the closed form's first root along each ray, where the ray
    crosses it clearly (slope of Q along the ray above 0.5) inside the curved cube."""
    cam = framing(q_mesh, 16, 12)
    level = -0.8
    res = Renderer(q_mesh, device).render(cam, _clear_tf(-4.0, 3.0), np.zeros(3),
                                          RenderOptions(precision="float64", device=device),
                                          surfaces=Surfaces((Isosurface(level, (1.0, 1.0, 1.0), 1.0),)))
    o, d = cam.rays()
    checked = 0
    for j in range(res.depth.shape[0]):
        for i in range(res.depth.shape[1]):
            if res.rgba[j, i, 3] < 0.5:
                continue
            t = res.depth[j, i]
            want, slope = _first_root(o[j, i], d[j, i], level, t - 0.05, t + 0.05)
            if slope > 0.5:
                checked += 1
                assert abs(t - want) < 1e-6, (j, i, t, want)
    assert checked > 20


def test_riemann_refused(q_mesh):
    with pytest.raises(RenderError, match="classified or split"):
        Renderer(q_mesh, "cpu").render(framing(q_mesh, 4, 4), _clear_tf(-4.0, 3.0), np.zeros(3),
                                       RenderOptions(method="riemann", h=0.05))


# ------------------------------------------------------------------ readers


def test_nektar_channel_vorticity_and_q():
    """Nektar++'s Tet_channel_m3: w = y (1 - y), u = v = 0, so |curl u| = |1 - 2y| and Q = 0."""
    from hovr_blender.io.nektar.format import read_nektar_field
    from tests.helpers import data_file

    path, fld = data_file("nektar", "Tet_channel_m3.xml"), data_file("nektar", "Tet_channel_m3.fld")
    vort = read_nektar_field(path, fld, "vorticity(u, v, w)")
    q = read_nektar_field(path, fld, "Q(u,v,w)")
    assert vort.field_name == "vorticity(u,v,w)" and vort.derived is not None
    xi = ex.fit_points(int(vort.shape[0]), (3, 3, 3)) * 0.5
    for e in range(0, vort.num_elements, 7):
        x = _mapped(vort, e, xi)
        np.testing.assert_allclose(derived_values(vort, vort.derived, [e], xi)[0], np.abs(1 - 2 * x[:, 1]), atol=1e-12)
        np.testing.assert_allclose(derived_values(q, q.derived, [e], xi)[0], 0.0, atol=1e-12)


def test_reader_errors_are_one_line():
    from hovr_blender.io.nektar.format import read_nektar_field
    from hovr_blender.io.vtu.format import read_vtu_field
    from tests.helpers import data_file

    tgv = data_file("vtu", "pyfr_tgv_hexprism_p4_t4.vtu")
    for field, message in (("Q(Pressure)", "not a velocity"), ("Q(Nope)", "no field 'Nope'"),
                           ("|grad|(Velocity)", "is a vector of 3")):
        with pytest.raises(DerivedFieldError, match=message) as err:
            read_vtu_field(tgv, field)
        assert "\n" not in str(err.value)
    with pytest.raises(DerivedFieldError, match="not a velocity"):
        read_nektar_field(data_file("nektar", "Tet_channel_m3.xml"), data_file("nektar", "Tet_channel_m3.fld"), "Q(p)")


def test_concatenate_and_subset_carry_the_components(q_mesh, geometry):
    """A scene of a derived volume and a plain one: the derived one's elements keep their
    components (the plain one's its own field), and a part of it (sort_last) its own."""
    from hovr_blender.engine.mesh import concatenate, subset

    plain = with_field(geometry, lambda x, y, z: x, 2)
    both = concatenate([plain, q_mesh])
    n = plain.num_elements
    assert not both.derived.derived[:n].any() and both.derived.derived[n:].all()
    xi = ex.fit_points(int(q_mesh.shape[4]), (3, 3, 3)) * 0.9
    np.testing.assert_array_equal(derived_values(both, both.derived, [n + 4], xi),
                                  derived_values(q_mesh, q_mesh.derived, [4], xi))
    part = subset(both, [n + 4, 0])
    np.testing.assert_array_equal(derived_values(part, part.derived, [0], xi), derived_values(q_mesh, q_mesh.derived, [4], xi))
    with pytest.raises(DerivedFieldError, match="one derived field per scene"):
        concatenate([q_mesh, q_mesh])


def test_derived_field_names():
    from hovr_blender.engine.derived_fields import derived_field_names

    names = derived_field_names({"Density": 1, "Velocity": 3, "Pressure": 1})
    assert names[:3] == ["Q(Velocity)", "vorticity(Velocity)", "speed(Velocity)"]
    assert "|grad|(Pressure)" in names and all(parse_derived(n) is not None for n in names)
    hump = derived_field_names(["rho", "rhou", "rhov", "rhow", "E"])
    assert "Q(rhou,rhov,rhow/rho)" in hump and "|grad|(rho)" in hump
    assert "Q(u,v,w)" in derived_field_names(["u", "v", "w", "p"])
    assert not any(n.startswith("Q(") for n in derived_field_names(["rhou", "rhov", "rhow"]))  # no density


def test_q_equals_vtk_on_the_lagrange_cells_of_pyfr():
    """An independent reference: VTK's gradient filter on PyFR's Lagrange cells themselves (each
    node belongs to one cell, so its point gradient is that cell's own derivative there) gives Q
    at the nodes; the derived field at the same points (the equispaced lattice of each order-4
    cell) is the same set of values. The linearised cells' point gradients (ParaView after
    tessellation) flatten Q's peaks: the contrast of docs/user-guide.md's picture."""
    vtk = pytest.importorskip("vtk")
    from vtk.util.numpy_support import vtk_to_numpy

    from hovr_blender.engine.derived_fields import lattice_values
    from hovr_blender.io.vtu.format import read_vtu_field
    from tests.helpers import data_file

    path = data_file("vtu", "pyfr_tgv_hexprism_p4_t4.vtu")
    mesh = read_vtu_field(path, "Q(Velocity)")
    reader = vtk.vtkXMLUnstructuredGridReader()
    reader.SetFileName(str(path))
    grad = vtk.vtkGradientFilter()
    grad.SetInputConnection(reader.GetOutputPort())
    grad.SetInputArrayToProcess(0, 0, 0, vtk.vtkDataObject.FIELD_ASSOCIATION_POINTS, "Velocity")
    grad.ComputeQCriterionOn()
    grad.SetQCriterionArrayName("Q")
    grad.Update()
    theirs = np.sort(vtk_to_numpy(grad.GetOutput().GetPointData().GetArray("Q")).astype(np.float64))
    mine = np.sort(lattice_values(mesh, per_axis=5))  # order 4: 5 equispaced nodes a direction
    assert mine.shape == theirs.shape
    np.testing.assert_allclose(mine, theirs, atol=1e-6 * np.abs(theirs).max())


def test_isosurface_coloured_by_the_speed(q_mesh, device):
    """A Q isosurface coloured by the speed through the ramp red = speed / 4, blue = 1: the
    headlight scales both channels alike, so red / blue is the speed at the surface point / 4,
    the speed exact there (the closed form at the point of the render's depth)."""
    cam = framing(q_mesh, 16, 12)
    iso = Isosurface(-0.8, (1.0, 1.0, 1.0), 1.0, color_by="speed", color_ramp=((0.0, 0.0, 0.0, 1.0), (4.0, 1.0, 0.0, 1.0)))
    res = Renderer(q_mesh, device).render(cam, _clear_tf(-4.0, 3.0), np.zeros(3),
                                          RenderOptions(precision="float64", device=device), surfaces=Surfaces((iso,)))
    hit = res.rgba[..., 3] > 0.5
    assert hit.sum() > 20
    o, d = cam.rays()
    x = o[hit] + res.depth[hit][:, None] * d[hit]
    speed = np.linalg.norm(velocity(*x.T), axis=0)
    np.testing.assert_allclose(res.rgba[hit][:, 0] / res.rgba[hit][:, 2], np.minimum(speed / 4.0, 1.0), atol=1e-6)
