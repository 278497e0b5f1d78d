"""The paper-scale generator (hovr_blender/io/paper_scale.py): counts, conformity, valid curved
elements, and a field that is its analytic source up to the stated interpolation error."""
import numpy as np
import pytest

from hovr_blender.engine import expansions as ex
from hovr_blender.engine import shapes
from hovr_blender.engine.mesh import MeshError
from hovr_blender.io import paper_scale as ps
from hovr_blender.io.synthetic import mixed_cube

SMALL = dict(n_hex=48, n_prism=96)  # b = 1: 54 hexahedra + 84 prisms


@pytest.fixture(scope="module")
def small():
    return ps.paper_scale_mesh(**SMALL)


def _faces(mesh):
    """{vertex-set key: [(element, local face vertex list)]} over every element face."""
    faces = {}
    for e in range(mesh.num_elements):
        sh = int(mesh.shape[e])
        V = mesh.vertices[e]
        for f in shapes.FACES[sh]:
            key = frozenset(tuple(np.round(V[i], 7)) for i in f)
            faces.setdefault(key, []).append((e, list(f)))
    return faces


def _face_points(f, nsamp=4):
    """Weights (P, len(f)) of sample points on a face, in the face's cyclic vertex order."""
    s = np.linspace(0.05, 0.95, nsamp)
    S, T = np.meshgrid(s, s, indexing="ij")
    S, T = S.ravel(), T.ravel()
    if len(f) == 4:
        return np.stack([(1 - S) * (1 - T), S * (1 - T), S * T, (1 - S) * T], axis=1)
    keep = S + T < 1
    return np.stack([1 - S[keep] - T[keep], S[keep], T[keep]], axis=1)


def _geometry(mesh, e):
    sh = int(mesh.shape[e])
    o = int(mesh.geom_offset[e])
    return sh, tuple(mesh.geom_modes[e]), mesh.geom_coeffs[o:o + ex.num_coeffs(sh, mesh.geom_modes[e])]


def _shared_face_mismatch(mesh):
    """Largest distance between the two sides' geometry at matched points of every shared face,
    and the number of shared faces (a face with more than two owners fails the test)."""
    worst, shared = 0.0, 0
    for owners in _faces(mesh).values():
        assert len(owners) <= 2
        if len(owners) < 2:
            continue
        shared += 1
        (ea, fa), (eb, fb) = owners
        w = _face_points(fa)
        xs = []
        for e, f in ((ea, fa), (eb, fb)):
            sh, gm, g = _geometry(mesh, e)
            # the same physical vertex in both elements: order B's reference vertices like A's
            keys = [tuple(np.round(mesh.vertices[e][i], 7)) for i in f]
            order = [f[keys.index(tuple(np.round(mesh.vertices[ea][i], 7)))] for i in fa]
            xi = w @ shapes.VERTICES[sh][order]
            xs.append(ex.eval_modal(sh, gm, g, xi))
        worst = max(worst, float(np.abs(xs[0] - xs[1]).max()))
    return worst, shared


def test_counts_follow_the_request(small):
    info = small.paper_scale
    assert info["hexahedra"] == int((small.shape == shapes.HEX).sum())
    assert info["prisms"] == int((small.shape == shapes.PRISM).sum())
    assert info["hexahedra"] + info["prisms"] == small.num_elements
    assert info["prisms"] % 2 == 0  # each split cell gives two
    # the grid rounds to whole cells: within a third of the request at this tiny size
    assert abs(info["hexahedra"] - SMALL["n_hex"]) <= SMALL["n_hex"] / 3
    assert abs(info["prisms"] - SMALL["n_prism"]) <= SMALL["n_prism"] / 3
    assert np.all(small.modes == 7)  # order 6
    assert not small.affine.any()  # every element curved


def test_paper_scale_counts_within_five_percent():
    """The default request (3,400 hexahedra + 7,600 prisms); straight and order 1 to stay fast,
    the counts do not depend on either."""
    m = ps.paper_scale_mesh(order=1, curved=False)
    info = m.paper_scale
    assert abs(info["hexahedra"] - 3400) <= 0.05 * 3400
    assert abs(info["prisms"] - 7600) <= 0.05 * 7600
    assert info["hexahedra"] == int((m.shape == shapes.HEX).sum())
    assert m.affine.all()


def test_shared_faces_have_the_same_curved_geometry(small):
    worst, shared = _shared_face_mismatch(small)
    scale = np.abs(small.vertices).max()
    assert shared > small.num_elements  # interior faces: about 2 per element here
    assert worst <= 1e-12 * scale, worst
    # the hexahedron/prism interface is among them
    faces = _faces(small)
    mixed = [o for o in faces.values() if len(o) == 2 and small.shape[o[0][0]] != small.shape[o[1][0]]]
    assert len(mixed) > 0


def test_unshared_faces_are_exactly_the_domain_boundary():
    """Topology on the straight twin (computational coordinates): a face has one owner iff it
    lies on the channel's walls or the block's."""
    m = ps.paper_scale_mesh(**SMALL, curved=False, order=1)
    lo, hi = m.vertices.min(axis=(0, 1)), m.vertices.max(axis=(0, 1))
    for owners in _faces(m).values():
        e, f = owners[0]
        V = m.vertices[e][f]
        on_wall = any(np.allclose(V[:, d], lo[d]) or np.allclose(V[:, d], hi[d]) for d in range(3))
        on_block = (np.all(np.abs(V[:, :2]).max(axis=1) <= 0.5 + 1e-9)
                    and any(np.allclose(np.abs(V[:, d]), 0.5) for d in range(2)))
        assert (len(owners) == 1) == (on_wall or on_block), V


def test_jacobians_positive_inside_every_element(small):
    rng = np.random.default_rng(4)
    for sh in (shapes.HEX, shapes.PRISM):
        idx = np.nonzero(small.shape == sh)[0]
        gm = tuple(small.geom_modes[idx[0]])
        kg = ex.num_coeffs(sh, gm)
        G = small.geom_coeffs[small.geom_offset[idx][:, None] + np.arange(kg)[None, :]]
        cand = rng.uniform(-1, 1, (400, 3))
        pts = np.concatenate([cand[ex.inside(sh, cand, tol=0.0)], shapes.VERTICES[sh]])
        det = ps.jacobian_determinants(sh, gm, G, pts)
        assert det.min() > 0
        # curved indeed: the determinant varies inside elements
        assert np.ptp(det, axis=1).max() > 1e-3 * np.abs(det).max()


def test_too_much_curvature_is_refused():
    with pytest.raises(MeshError, match="Jacobian"):
        ps.paper_scale_mesh(**SMALL, order=2, curvature=8.0)


def test_field_is_its_source_to_the_stated_error(small):
    src = small.paper_scale["source"]
    err = ps.interpolation_error(small, src)
    assert err["relative"] <= ps.STATED_ERROR[1], err
    assert np.ptp(err["range"]) > 1.0  # a real flow: free stream 1, speed-up and vortices
    # the data set converges to its source with the order
    low = ps.paper_scale_mesh(**SMALL, order=2)
    err2 = ps.interpolation_error(low, low.paper_scale["source"])
    assert err["max_abs"] < 0.5 * err2["max_abs"]


def test_field_in_the_space_is_exact():
    """f linear in physical coordinates: f(x(xi)) has degree 2 per direction (quadratic map),
    inside the order-6 space, so the data set equals it to rounding."""
    def f(x, y, z):
        return 1.0 + 0.5 * x - 2.0 * y + 3.0 * z

    m = ps.paper_scale_mesh(**SMALL, func=f)
    assert ps.interpolation_error(m, f)["max_abs"] < 1e-10


def test_curved_copy_of_mixed_shapes_is_conforming():
    base = mixed_cube(2, 3, lambda x, y, z: x + y * z)

    def bend(x, y, z):
        return 0.08 * (1 - (2 * x - 1) ** 2), 0.05 * x * y, -0.06 * (y - 0.5) ** 2 + 0.02 * x

    m = ps.curved_copy(base, bend, geom_modes=3)
    assert set(np.unique(m.shape)) == {shapes.HEX, shapes.PRISM, shapes.TET, shapes.PYR}
    assert not m.affine.any()
    np.testing.assert_array_equal(m.coeffs, base.coeffs)
    worst, shared = _shared_face_mismatch(m)
    assert shared > 0 and worst <= 1e-12
    # a cubic displacement is outside 3 geometry modes: refused (faces would not match)
    with pytest.raises(MeshError, match="not exact"):
        ps.curved_copy(base, lambda x, y, z: (0.05 * x ** 3, 0 * y, 0 * z), geom_modes=3)
