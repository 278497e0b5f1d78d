"""Derived magnitude field (io/magnitude.py): fit accuracy, conservative element ranges, readers."""
import dataclasses
import re

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from hovr_blender.engine import expansions as ex
from hovr_blender.engine import shapes
from hovr_blender.engine.mesh import element_field_ranges
from hovr_blender.io import magnitude, nektar, synthetic
from hovr_blender.io.magnitude import DerivedError, magnitude_mesh, parse_magnitude
from hovr_blender.io.nektar.format import read_nektar_field
from hovr_blender.io.vtu.format import read_vtu_field
from tests.helpers import data_file as shared_file

# Components of degree 2 (exact with 3 modes): u = 0 on a curve through the cube, so |u| has a
# kink inside some elements (the hard case for a polynomial fit).
COMPONENTS = (
    lambda x, y, z: x - 0.5 + 0.3 * y * y,
    lambda x, y, z: y - 0.4,
    lambda x, y, z: (z - 0.5) * x,
)


def _components(n=2, modes=3, funcs=COMPONENTS):
    base = synthetic.mixed_cube(n, modes, funcs[0], field_name="a")
    return [base] + [synthetic.with_field(base, f, modes, field_name=name) for f, name in zip(funcs[1:], "bc")]


@pytest.fixture(scope="module")
def kinked():
    comps = _components()
    return comps, magnitude_mesh(comps)


def _eval(mesh, e, xi):
    return ex.eval_modal(int(mesh.shape[e]), mesh.modes[e], mesh.element_coeffs(e), xi)


def _random_xi(shape, rng, n):
    return magnitude._random_inside(shape, n, rng)


def test_parse_magnitude():
    assert parse_magnitude("|u,v,w|") == ["u", "v", "w"]
    assert parse_magnitude(" | rhou , rhov,rhow | ") == ["rhou", "rhov", "rhow"]
    assert parse_magnitude("p") is None and parse_magnitude("") is None and parse_magnitude(None) is None
    for bad in ("|u,,v|", "||", "|u", "u|v"):
        with pytest.raises(DerivedError):
            parse_magnitude(bad)


def test_orders_and_shapes(kinked):
    comps, mag = kinked
    assert mag.field_name == "|a,b,c|" and mag.num_elements == comps[0].num_elements
    assert set(np.unique(mag.shape)) == {shapes.HEX, shapes.PRISM, shapes.TET, shapes.PYR}
    assert (mag.modes == 7).all()  # 2 * 3 + 1
    np.testing.assert_array_equal(magnitude.magnitude_modes([np.full((2, 3), 8), np.array([[2, 2, 2], [9, 9, 9]])]),
                                  [15, 15])  # capped at 15 modes
    np.testing.assert_array_equal(mag.vertices, comps[0].vertices)
    info = mag.derived_error
    assert info["bound"] >= info["max_error"] > 0 and info["modes"] == [7]
    assert re.search(r"\|a,b,c\|: magnitude fitted with 7 modes .* max error", mag.warnings[-1])


@settings(max_examples=150, deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture])
@given(data=st.data())
def test_fit_within_bound_and_ranges_conservative(kinked, data):
    """Random element, random points: the true magnitude and the fit lie in the element's
    classification range, and the fit is within the stated error bound of the truth."""
    comps, mag = kinked
    lo, hi = element_field_ranges(mag)
    e = data.draw(st.integers(0, mag.num_elements - 1))
    rng = np.random.default_rng(data.draw(st.integers(0, 2**31)))
    xi = _random_xi(int(mag.shape[e]), rng, 16)
    truth = magnitude.true_magnitude(comps, e, xi)
    fit = _eval(mag, e, xi)
    np.testing.assert_allclose(truth, np.sqrt(sum(_eval(c, e, xi) ** 2 for c in comps)), rtol=1e-14)
    assert np.all(truth >= lo[e] - 1e-12) and np.all(truth <= hi[e] + 1e-12)
    assert np.all(fit >= lo[e] - 1e-12) and np.all(fit <= hi[e] + 1e-12)
    assert np.abs(fit - truth).max() <= mag.derived_error["bound"]


def test_dense_check_of_the_bound_and_the_kink(kinked):
    """Many fresh points in every element: the bound holds; near u = 0 the magnitude's range
    reaches (almost) zero and the hull's lower end is never above the true values."""
    comps, mag = kinked
    rng = np.random.default_rng(123)
    worst = 0.0
    near, far = mag.field_range_hull
    assert np.all(near >= 0) and np.all(far >= near)
    for e in range(mag.num_elements):
        xi = _random_xi(int(mag.shape[e]), rng, 400)
        truth = magnitude.true_magnitude(comps, e, xi)
        worst = max(worst, np.abs(_eval(mag, e, xi) - truth).max())
        assert near[e] <= truth.min() + 1e-12 and truth.max() <= far[e] + 1e-12
    assert worst <= mag.derived_error["bound"]
    assert 0 < worst < 0.05  # a fit, not a copy: |u| is not a polynomial here


def test_magnitude_of_a_positive_polynomial_is_exact():
    comps = _components(funcs=(lambda x, y, z: x + 2.0, lambda x, y, z: 0.0 * x, lambda x, y, z: 0.0 * y))
    mag = magnitude_mesh(comps)
    rng = np.random.default_rng(1)
    for e in range(mag.num_elements):
        xi = _random_xi(int(mag.shape[e]), rng, 20)
        x = ex.eval_modal(int(mag.shape[e]), mag.geom_modes[e],
                          mag.geom_coeffs[mag.geom_offset[e]: mag.geom_offset[e] + ex.num_coeffs(int(mag.shape[e]), mag.geom_modes[e])], xi)
        np.testing.assert_allclose(_eval(mag, e, xi), x[:, 0] + 2.0, atol=1e-11)
    assert mag.derived_error["max_error"] < 1e-11


def test_range_hull_survives_object_transforms(kinked):
    _, mag = kinked
    M = np.array([[0, -2.0, 0, 1], [1, 0, 0, -3], [0, 0, 0.5, 2], [0, 0, 0, 1]])
    moved = mag.transformed(M)
    assert moved.field_range_hull is mag.field_range_hull
    for a, b in zip(element_field_ranges(moved), element_field_ranges(mag)):
        np.testing.assert_array_equal(a, b)
    # element_field_ranges encloses the hull: a hull wider than the fit's own range widens it
    lo, hi = element_field_ranges(mag)
    assert np.all(lo <= mag.field_range_hull[0]) and np.all(hi >= mag.field_range_hull[1])
    wide = dataclasses.replace(mag, field_range_hull=(lo - 1.0, hi + 2.0))
    wlo, whi = element_field_ranges(wide)
    np.testing.assert_array_equal(wlo, lo - 1.0)
    np.testing.assert_array_equal(whi, hi + 2.0)


def test_components_on_other_geometry_are_refused():
    a = synthetic.mixed_cube(1, 3, COMPONENTS[0])
    b = synthetic.mixed_cube(1, 3, COMPONENTS[1], lower=(1.0, 0.0, 0.0))
    with pytest.raises(DerivedError, match="other geometry"):
        magnitude_mesh([a, b])
    with pytest.raises(DerivedError, match="other elements"):
        magnitude_mesh([a, synthetic.mixed_cube(2, 3, COMPONENTS[1])])


# ---------------------------------------------------------------------------------------------
# Nektar++ "|u,v,w|"


def _check_against_components(mag, comps, rng, per=50):
    for e in range(mag.num_elements):
        xi = _random_xi(int(mag.shape[e]), rng, per)
        assert np.abs(_eval(mag, e, xi) - magnitude.true_magnitude(comps, e, xi)).max() <= mag.derived_error["bound"]


def test_nektar_velocity_magnitude():
    xml, fld = shared_file("nektar", "Tet_channel_m3.xml"), shared_file("nektar", "Tet_channel_m3.fld")
    mag = read_nektar_field(xml, fld, "| u, v, w |")
    comps = [nektar.read_nektar(xml, fld, f) for f in "uvw"]
    assert mag.field_name == "|u,v,w|" and (mag.modes == 7).all()
    np.testing.assert_array_equal(mag.element_ids, comps[0].element_ids)
    _check_against_components(mag, comps, np.random.default_rng(2))
    # a plain field name is read_nektar unchanged
    np.testing.assert_array_equal(read_nektar_field(xml, fld, "p").coeffs, nektar.read_nektar(xml, fld, "p").coeffs)


def test_nektar_momentum_magnitude_hump3d():
    xml, rst = shared_file("nektar", "hump3D_GLL.xml"), shared_file("nektar", "hump3D.rst")
    mag = read_nektar_field(xml, rst, "|rhou,rhov,rhow|")
    info = mag.derived_error
    assert info["relative"] < 0.05 and info["max_value"] > 1.0
    comps = [nektar.read_nektar(xml, rst, f) for f in ("rhou", "rhov", "rhow")]
    sample = np.random.default_rng(3).choice(mag.num_elements, 60, replace=False)
    lo, hi = element_field_ranges(mag)
    rng = np.random.default_rng(4)
    for e in sample:
        xi = _random_xi(shapes.HEX, rng, 40)
        truth = magnitude.true_magnitude(comps, e, xi)
        fit = _eval(mag, e, xi)
        assert np.abs(fit - truth).max() <= info["bound"]
        assert lo[e] <= truth.min() and truth.max() <= hi[e] and lo[e] <= fit.min() and fit.max() <= hi[e]


def test_nektar_magnitude_errors_name_the_file():
    xml, fld = shared_file("nektar", "Tet_channel_m3.xml"), shared_file("nektar", "Tet_channel_m3.fld")
    with pytest.raises(nektar.NektarError, match=re.escape(str(fld)) + ".*no field 'q'"):
        read_nektar_field(xml, fld, "|u,q|")
    with pytest.raises(nektar.NektarError, match="no field 'q'"):
        read_nektar_field(xml, fld, "|q,u|")
    with pytest.raises(DerivedError, match="empty component"):
        read_nektar_field(xml, fld, "|u,,v|")


# ---------------------------------------------------------------------------------------------
# VTU vectors


def _vector_vtu(tmp_path):
    import meshio

    pts = np.array([[0, 0, 0], [1, 0, 0], [1, 1, 0], [0, 1, 0], [0, 0, 1], [1, 0, 1], [1, 1, 1], [0, 1, 1],
                    [2, 0, 0], [2, 1, 0], [2, 0, 1], [2, 1, 1]], dtype=float)
    cells = [("hexahedron", np.array([[0, 1, 2, 3, 4, 5, 6, 7], [1, 8, 9, 2, 5, 10, 11, 6]]))]
    vel = np.c_[pts[:, 0] - 0.8, pts[:, 1] - 0.5, 0.2 * pts[:, 2]]
    path = tmp_path / "vec.vtu"
    meshio.write(str(path), meshio.Mesh(pts, cells, point_data={"s": pts[:, 0], "vel": vel}), binary=False)
    return path


def test_vtu_vector_magnitude_goes_through_the_derived_fit(tmp_path):
    from hovr_blender.io.vtu import read_vtu

    path = _vector_vtu(tmp_path)
    mag = read_vtu_field(path, "vel")
    assert mag.field_name == "|vel|" and (mag.modes == 5).all()  # trilinear components: 2 modes -> 5
    comps = [read_vtu(path, "vel", i) for i in range(3)]
    _check_against_components(mag, comps, np.random.default_rng(5), per=400)
    np.testing.assert_array_equal(read_vtu_field(path, "vel", "magnitude").coeffs, mag.coeffs)
    np.testing.assert_array_equal(read_vtu_field(path, "vel", 1).coeffs, comps[1].coeffs)
    np.testing.assert_array_equal(read_vtu_field(path, "s").coeffs, read_vtu(path, "s").coeffs)
    assert read_vtu_field(path).field_name == "s"  # no name: the first array, as read_vtu


def test_the_bench_prints_the_error_line(capsys):
    from bench.magnitude_error import main

    xml, fld = shared_file("nektar", "Tet_channel_m3.xml"), shared_file("nektar", "Tet_channel_m3.fld")
    assert main([str(xml), str(fld), "|u,v,w|"]) == 0
    assert re.match(r"48 elements; \|u,v,w\|: magnitude fitted with 7 modes .* max error", capsys.readouterr().out)


def test_view_files_accept_the_magnitude_syntax(tmp_path):
    """The CLI's data.field takes "|u,v,w|" too (Nektar++), and a VTU vector's magnitude is the
    same derived fit as in Blender (only the low-level read_vtu keeps VTK's nodal magnitude)."""
    from hovr_blender.io.sources import VolumeSource, load_volume

    def load_data(data):
        return load_volume(VolumeSource.from_view_data(data))

    def assert_same_fit(got, want):
        # the reader process's BLAS may sum the least-squares fit in another order (it runs with its
        # address space capped): the same fit to rounding, far below the fit's own error
        np.testing.assert_allclose(got, want, rtol=0, atol=1e-12 * np.abs(want).max())

    vec = _vector_vtu(tmp_path)
    assert_same_fit(load_data({"path": str(vec), "field": "vel"}).coeffs, read_vtu_field(vec, "vel").coeffs)

    xml, fld = shared_file("nektar", "Tet_channel_m3.xml"), shared_file("nektar", "Tet_channel_m3.fld")
    mesh = load_data({"path": str(xml), "solution": str(fld), "field": "|u,v,w|"})
    assert_same_fit(mesh.coeffs, read_nektar_field(xml, fld, "|u,v,w|").coeffs)
    with pytest.raises(nektar.NektarError, match="no field 'q'"):
        load_data({"path": str(xml), "solution": str(fld), "field": "|u,q|"})
