"""Element validity (engine/validity.py): det J bounded over the whole element, not at samples.

The polynomial claims (det J(xi(u)) a polynomial of the stated degrees in the collapsed cube,
truncated expansions a subset of the modes) are checked against direct evaluation; the rule on
elements built to be folded, degenerate, near-degenerate and strongly curved, on real cells of
NGSolve's ball, and by property tests: random perturbations of every shape, the certified
bound never above the minimum that dense sampling plus a local descent finds.
"""
import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st
from numpy.polynomial import chebyshev

from hovr_blender.engine import expansions as ex
from hovr_blender.engine import shapes, validity
from hovr_blender.engine.mesh import MeshError
from hovr_blender.io.synthetic import curved_cube
from hovr_blender.io.vtu import VtuError, read_vtu
from hovr_blender.io.sources import VolumeSource, load_volume
from tests.helpers import data_file, folded_hex_map, lagrange_hex_vtu

SHAPES = [shapes.HEX, shapes.PRISM, shapes.TET, shapes.PYR]
MODES = {shapes.HEX: [(2, 2, 2), (3, 3, 3), (4, 4, 4), (7, 7, 7), (3, 5, 4)],
         shapes.PRISM: [(2, 2, 2), (3, 3, 3), (5, 5, 5), (3, 4, 5)],
         shapes.TET: [(2, 2, 2), (3, 3, 3), (5, 5, 5), (3, 3, 5)],
         shapes.PYR: [(2, 2, 2), (3, 3, 3), (5, 5, 5), (3, 4, 6)]}
SETTINGS = dict(deadline=None, derandomize=True, suppress_health_check=[HealthCheck.too_slow], print_blob=True)


def geometry(shape, modes, mapping):
    """(1, K, 3) modal geometry of x = mapping(xi) (exact for maps in the space)."""
    return ex.fit_modal(shape, modes, mapping(ex.fit_points(shape, modes)))[None]


def jacobians(shape, modes, G, xi):
    """(P, 3, 3) dx_i/dxi_j of one element's geometry G (K, 3) at xi (P, 3)."""
    return np.asarray(ex.eval_modal_grad(shape, modes, G, xi))


def determinant(shape, modes, G, u):
    """det J and the column-length product at xi(u) (P, 3) of the collapsed cube. u is held
    1e-7 short of a collapsed end: there the limit of det J depends on the direction (the
    pyramid's apex), which xi(u) alone would lose."""
    u = np.array(u, dtype=np.float64)
    if shape != shapes.HEX:
        u[:, 2] = np.minimum(u[:, 2], 1.0 - 1e-7)
    if shape == shapes.TET:
        u[:, 1] = np.minimum(u[:, 1], 1.0 - 1e-7)
    J = jacobians(shape, modes, G, ex.uncollapse(shape, u))
    return np.linalg.det(J), np.prod(np.linalg.norm(J, axis=1), axis=1)


def found_minimum(shape, modes, G, n=17, starts=6, steps=80):
    """(smallest det J found, largest column-length product): a dense tensor grid of the
    collapsed cube (its faces included), then projected descent from the best points."""
    t = np.linspace(-1.0, 1.0, n)
    u = np.stack(np.meshgrid(t, t, t, indexing="ij"), axis=-1).reshape(-1, 3)
    det, length = determinant(shape, modes, G, u)
    best = u[np.argsort(det)[:starts]].copy()
    val = np.sort(det)[:starts].copy()
    step = np.full(starts, 0.05)
    for _ in range(steps):
        grad = np.stack([(determinant(shape, modes, G, np.clip(best + h, -1, 1))[0]
                          - determinant(shape, modes, G, np.clip(best - h, -1, 1))[0]) / 2e-7
                         for h in 1e-7 * np.eye(3)], axis=1)
        norm = np.linalg.norm(grad, axis=1, keepdims=True)
        trial = np.clip(best - step[:, None] * grad / np.maximum(norm, 1e-300), -1.0, 1.0)
        tv = determinant(shape, modes, G, trial)[0]
        better = tv < val
        best[better], val[better] = trial[better], tv[better]
        step = np.where(better, step * 1.5, step * 0.5)
    return min(det.min(), val.min()), length.max()


# ------------------------------------------------------------------------- the polynomial


@pytest.mark.parametrize("shape", SHAPES)
def test_determinant_is_the_stated_polynomial_in_the_collapsed_cube(shape):
    """determinant_series (degrees from determinant_degrees) reproduces det J at random points
    of the collapsed cube for random geometries: the degrees are right, and the pyramid's
    rational map has a polynomial determinant there."""
    rng = np.random.default_rng(shape)
    for modes in MODES[shape]:
        K = ex.num_coeffs(shape, modes)
        G = rng.normal(size=(3, K, 3))
        series = validity.determinant_series(shape, modes, G)
        assert series.shape[1:] == tuple(d + 1 for d in validity.determinant_degrees(shape, modes))
        u = rng.uniform(-1, 1, (40, 3))
        for e in range(3):
            want = determinant(shape, modes, G[e], u)[0]
            got = np.array([chebyshev.chebval3d(*p, series[e]) for p in u])
            assert np.abs(got - want).max() <= 1e-11 * np.abs(want).max(), (modes, e)


@pytest.mark.parametrize("shape", SHAPES)
def test_truncated_expansion_is_a_subset_of_the_modes(shape):
    """The truncated passes drop modes: each kept mode is the same function in the smaller
    expansion."""
    xi = ex.uncollapse(shape, np.random.default_rng(1).uniform(-1, 1, (30, 3)))
    for modes in MODES[shape]:
        for m in range(2, min(modes)):
            keep = validity._mode_subset(shape, modes, (m, m, m))
            np.testing.assert_allclose(ex.basis_matrix(shape, (m, m, m), xi), ex.basis_matrix(shape, modes, xi)[:, keep],
                                       atol=1e-13)


# ------------------------------------------------------------------------- the rule


def test_folded_quadratic_hexahedron_is_refused_in_one_line(tmp_path):
    """Issue 29: a quadratic hexahedron with minimum det J -0.40 between the 4 x 4 x 4 fit points,
    which a sample-point check accepts, is refused, naming the element, the value, the place and
    the certified bound; also through the VTU reader."""
    modes = (3, 3, 3)
    G = geometry(shapes.HEX, modes, folded_hex_map)
    at_fit_points = np.linalg.det(jacobians(shapes.HEX, modes, G[0], ex.fit_points(shapes.HEX, modes)))
    assert len(at_fit_points) == 64 and at_fit_points.min() > 0.1  # what the fit-point probe saw
    assert found_minimum(shapes.HEX, modes, G[0])[0] == pytest.approx(-0.40, abs=1e-9)
    with pytest.raises(MeshError) as info:
        validity.check_elements(shapes.HEX, modes, G, ids=[7])
    message = str(info.value)
    assert "\n" not in message
    assert message.startswith("element 7: inverted or tangled hexahedron (Jacobian determinant -0.4 at xi = (")
    assert "certified minimum >= -0.4" in message
    path = tmp_path / "folded.vtu"
    path.write_bytes(lagrange_hex_vtu(folded_hex_map))
    with pytest.raises(VtuError, match=r"folded.vtu: cell 0: inverted or tangled hexahedron \(Jacobian determinant -0.4"):
        read_vtu(path)


def test_strongly_curved_valid_elements_are_accepted(tmp_path):
    """The same hexahedron folded less (det J from 0.1 to 1) is valid and accepted with a
    certified positive bound no higher than its minimum; so are the curved mixed cube's four
    shapes (io/synthetic.curved_cube) and a cubic hexahedron far from the origin."""
    modes = (3, 3, 3)
    G = geometry(shapes.HEX, modes, lambda xi: folded_hex_map(xi, 0.9))
    v = validity.check_elements(shapes.HEX, modes, G)
    assert 0 < v.lower[0] <= 0.1 + 1e-12
    path = tmp_path / "bent.vtu"
    path.write_bytes(lagrange_hex_vtu(lambda xi: folded_hex_map(xi, 0.9)))
    assert read_vtu(path).num_elements == 1
    mesh = curved_cube(2, modes=3)
    for shape in np.unique(mesh.shape):
        idx = np.flatnonzero(mesh.shape == shape)
        gm = tuple(mesh.geom_modes[idx[0]])
        K = ex.num_coeffs(int(shape), gm)
        G = np.stack([mesh.geom_coeffs[mesh.geom_offset[e]:mesh.geom_offset[e] + K] for e in idx])
        assert (validity.jacobian_validity(int(shape), gm, G).status == validity.VALID).all()
    far = geometry(shapes.HEX, (4, 4, 4), lambda xi: 1e6 + xi + 0.2 * np.sin(xi[..., ::-1]) ** 3)
    assert validity.jacobian_validity(shapes.HEX, (4, 4, 4), far).status[0] == validity.VALID


def test_ngsolve_ball_cells_near_degeneracy_are_accepted():
    """Real cells of NGSolve's ball whose det J falls to ~1e-7 of its scale along an edge:
    certified valid within the box budget (the edge found by subdivision and monotone faces)."""
    data = np.load(data_file("vtu", "ngsolve_ball_cells.npz"))
    gm = tuple(int(m) for m in data["geom_modes"][0])
    v = validity.check_elements(shapes.HEX, gm, data["geom"], ids=data["cells"])
    assert (v.lower > -validity.TOLERANCE * v.scale).all() and (v.boxes < validity.MAX_BOXES).all()
    lowest = np.array([found_minimum(shapes.HEX, gm, g, n=9, starts=3, steps=40)[0] for g in data["geom"]])
    assert (v.lower <= lowest + 1e-15).all()
    assert (lowest / v.scale).min() < 1e-5  # near-degenerate indeed


@pytest.mark.parametrize("shape", SHAPES)
def test_degenerate_and_flat_elements_are_refused(shape):
    """A vertex moved onto its neighbour (det J = 0 there) and a flat element (every vertex in
    one plane): degenerate; a mirrored element: inverted, and its orientation is negative."""
    modes = (2, 2, 2)
    V = shapes.VERTICES[shape].astype(float)
    straight = np.einsum("kv,vc->kc", np.linalg.pinv(ex.basis_matrix(shape, modes, V)), V)[None]
    assert validity.jacobian_validity(shape, modes, straight).status[0] == validity.VALID
    assert validity.orientation(shape, modes, straight)[0] > 0
    collapsed = V.copy()
    collapsed[0] = V[1]
    flat = V.copy()
    flat[:, 2] = 0.0
    mirrored = V * [-1.0, 1.0, 1.0]
    for points, status in ((collapsed, validity.DEGENERATE), (flat, validity.DEGENERATE), (mirrored, validity.INVERTED)):
        G = np.einsum("kv,vc->kc", np.linalg.pinv(ex.basis_matrix(shape, modes, V)), points)[None]
        v = validity.jacobian_validity(shape, modes, G)
        assert v.status[0] == status, (shapes.NAMES[shape], points)
        with pytest.raises(MeshError, match=r"^element 0: (degenerate|inverted or tangled) "):
            validity.check_elements(shape, modes, G)
    assert validity.orientation(shape, modes, np.einsum("kv,vc->kc", np.linalg.pinv(ex.basis_matrix(shape, modes, V)),
                                                        mirrored)[None])[0] < 0


def test_overflowing_geometry_is_named():
    G = geometry(shapes.HEX, (3, 3, 3), lambda xi: 1e300 * xi)
    with pytest.raises(MeshError, match=r"^element 0: hexahedron geometry too large for double precision"):
        validity.check_elements(shapes.HEX, (3, 3, 3), G)


# every real file: (kind, mesh, solution, field); the large ones marked slow
REAL_FILES = [
    ("nektar", "CubeAllElements.xml", "", ""), ("nektar", "Helmholtz3D_Pyr_Deformed.xml", "", ""),
    ("nektar", "Hex_01_01_01_03Modes_x2_Offset3.xml", "Hex_01_01_01_03Modes_x2_Offset3.fld", ""),
    ("nektar", "Hex_CurvedFace.xml", "Hex_CurvedFace.fld", ""), ("nektar", "Hex_Mushroom.xml", "Hex_Mushroom.fld", ""),
    ("nektar", "Pyr_channel_m6.xml", "", ""), ("nektar", "RotPerBcs3D_Annulus.xml", "", ""),
    ("nektar", "Tet_channel_m3.xml", "Tet_channel_m3.fld", "u"), ("nektar", "Womersley_PipeFlow.xml", "", ""),
    ("nektar", "wss_3D_periodic.xml", "wss_3D_periodic.fld", "rho"), ("vtu", "mfem_fichera_cells_p4.vtu", "", ""),
    ("vtu", "mfem_fichera_poisson_mixed_p4.vtu", "", ""), ("vtu", "pyfr_tgv_hexprism_p4_t4.vtu", "", ""),
    ("vtu", "ngsolve_post_heat_tetprism_p4.vtu", "", ""),
    pytest.param("nektar", "hump3D_GLL.xml", "hump3D.rst", "rho", marks=pytest.mark.slow),
    pytest.param("nektar", "scaleHO.xml", "", "", marks=pytest.mark.slow),
    pytest.param("vtu", "ngsolve_ball_poisson_hex_p6.vtu", "", "", marks=pytest.mark.slow),
]


@pytest.mark.parametrize("kind, name, solution, field", REAL_FILES)
def test_every_real_file_loads(kind, name, solution, field):
    """Every vendored and shared mesh is certified valid as it loads: the check refuses none of
    the real files (NGSolve's near-degenerate ball included)."""
    path = data_file(kind, name)
    mesh = load_volume(VolumeSource.resolve(str(path), str(data_file(kind, solution)) if solution else "", field))
    assert mesh.num_elements > 0


# ------------------------------------------------------------------------- property


@st.composite
def perturbed_elements(draw):
    """(shape, modes, geometry): the reference element, moved by a random affine map and every
    mode perturbed by up to `amplitude` (some stay valid, some fold)."""
    shape = draw(st.sampled_from(SHAPES))
    m = draw(st.integers(2, 4))
    top = draw(st.integers(m, 5))
    modes = (m, m, top) if shape != shapes.HEX else (m, draw(st.integers(2, 4)), top)
    amplitude = draw(st.floats(0.0, 2.5))
    seed = draw(st.integers(0, 2**31 - 1))
    rng = np.random.default_rng(seed)
    A = np.eye(3) + 0.3 * rng.normal(size=(3, 3))
    G = geometry(shape, modes, lambda xi: xi @ A.T + 5.0 * rng.normal(size=3))[0]
    G = G + amplitude * rng.normal(size=G.shape) / np.sqrt(G.shape[0])
    return shape, modes, G


@settings(max_examples=60, **SETTINGS)
@given(perturbed_elements())
def test_certified_bound_is_never_above_the_minimum(case):
    """The certified lower bound is at most the smallest det J that dense sampling plus a local
    descent finds; clearly valid elements (found minimum above 2 % of the scale) are accepted
    and clearly folded ones (below -2 %) refused as inverted."""
    shape, modes, G = case
    v = validity.jacobian_validity(shape, modes, G[None])
    found, scale = found_minimum(shape, modes, G)
    assert v.lower[0] <= found + 1e-12 * scale, (v, found)
    assert v.lower[0] <= v.lowest[0]
    if found > 0.02 * scale:
        assert v.status[0] == validity.VALID, (v, found, scale)
    if found < -0.02 * scale:
        assert v.status[0] == validity.INVERTED, (v, found, scale)
