"""The domain's walls (engine/walls.py): the right boundary faces, each tessellated within the
tolerance of the true curved surface, measured independently at random points of every face."""
import math
import re

import numpy as np
import pytest

from hovr_blender.engine import expansions as ex
from hovr_blender.engine import shapes
from hovr_blender.engine import walls
from hovr_blender.io.nektar import read_nektar
from hovr_blender.io.synthetic import brick, curved_cube, mixed_cube
from tests.helpers import data_file


def _annulus():
    return read_nektar(str(data_file("nektar", "RotPerBcs3D_Annulus.xml")))


def _random_uv(nsides, n, rng):
    uv = rng.uniform(-1.0, 1.0, (n, 2))
    if nsides == 3:  # fold the square onto the triangle u, v >= -1, u + v <= 0
        out = uv.sum(axis=1) > 0
        uv[out] = -uv[out][:, ::-1]
    return uv


def _true_points(mesh, e, f, uv):
    """x(u, v) of element e's face f, straight from the element's geometry expansion."""
    sh = int(mesh.shape[e])
    gm = mesh.geom_modes[e]
    o = int(mesh.geom_offset[e])
    g = mesh.geom_coeffs[o: o + ex.num_coeffs(sh, gm)]
    xi = walls.face_reference_points(walls.face_corners(sh, f), uv)
    return ex.eval_modal(sh, gm, g, xi)


def measured_deviation(mesh, w, per_face=200, seed=0):
    """Largest |x(u, v) - the tessellation at (u, v)| over random (u, v) of every face: the
    triangle of the face's grid that contains (u, v) (found by barycentric coordinates in the
    parameter plane), its corners' world points interpolated. Also checks that the vertices are
    the true surface's points at their grid parameters."""
    rng = np.random.default_rng(seed)
    worst = 0.0
    ntri_end = np.append(w.triangle_offset[1:], len(w.triangles))
    for n in range(len(w.element)):
        e, f, k = int(w.element[n]), int(w.face[n]), int(w.k[n])
        nsides = len(shapes.plane_vertices(int(mesh.shape[e]))[f])
        grid_uv, _ = walls.grid(nsides, k)
        V = w.vertices[w.vertex_offset[n]: w.vertex_offset[n] + len(grid_uv)]
        np.testing.assert_allclose(V, _true_points(mesh, e, f, grid_uv), atol=1e-12)
        T = w.triangles[w.triangle_offset[n]: ntri_end[n]] - w.vertex_offset[n]
        assert T.min() >= 0 and T.max() < len(grid_uv)
        uv = _random_uv(nsides, per_face, rng)
        P = grid_uv[T]  # (t, 3, 2)
        # barycentric coordinates of every point in every triangle
        a, b, c = P[:, 0], P[:, 1], P[:, 2]
        det = (b[:, 0] - a[:, 0]) * (c[:, 1] - a[:, 1]) - (c[:, 0] - a[:, 0]) * (b[:, 1] - a[:, 1])
        d = uv[:, None, :] - a[None]
        l1 = (d[..., 0] * (c[:, 1] - a[:, 1]) - d[..., 1] * (c[:, 0] - a[:, 0])) / det
        l2 = ((b[:, 0] - a[:, 0]) * d[..., 1] - (b[:, 1] - a[:, 1]) * d[..., 0]) / det
        lam = np.stack([1 - l1 - l2, l1, l2], axis=-1)  # (p, t, 3)
        inside = lam.min(axis=-1)
        tri = inside.argmax(axis=1)
        assert inside[np.arange(per_face), tri].min() > -1e-12, "a point in no triangle: the grid has a hole"
        lin = np.einsum("pw,pwc->pc", lam[np.arange(per_face), tri], V[T[tri]])
        worst = max(worst, float(np.linalg.norm(lin - _true_points(mesh, e, f, uv), axis=1).max()))
    return worst


def enclosed_volume(w):
    """The divergence theorem over the closed outward-wound triangles: the volume they enclose."""
    v = w.vertices[w.triangles]
    return float(np.einsum("ti,ti->t", v[:, 0], np.cross(v[:, 1], v[:, 2])).sum() / 6.0)


def test_face_parameterisations_land_on_the_reference_faces():
    for sh in range(4):
        for f, (normal, c) in enumerate(shapes.FACE_PLANES[sh]):
            corners = walls.face_corners(sh, f)
            assert {tuple(p) for p in corners} == {tuple(p) for p in shapes.VERTICES[sh][shapes.plane_vertices(sh)[f]]}
            uv = _random_uv(len(corners), 500, np.random.default_rng(f))
            xi = walls.face_reference_points(corners, uv)
            np.testing.assert_allclose(xi @ np.asarray(normal, float), c, atol=1e-12)
            assert ex.inside(sh, xi, tol=1e-12).all(), (shapes.NAMES[sh], f)
            ends = np.array([[-1, -1], [1, -1], [1, 1], [-1, 1]] if len(corners) == 4 else [[-1, -1], [1, -1], [-1, 1]], float)
            np.testing.assert_allclose(walls.face_reference_points(corners, ends), corners)


def test_annulus_walls_are_within_tolerance():
    mesh = _annulus()
    # a quarter annulus, r 0.3..1, z 0..1: 10 sectors x 2 radial x 3 axial hexahedra
    e, f = walls.boundary_faces(mesh)
    assert len(e) == 2 * 10 * 3 + 2 * 10 * 2 + 2 * 2 * 3 == 112
    for relative in (1e-3, 1e-4):
        tol = walls.default_tolerance(mesh, relative)
        w = walls.tessellate(mesh, tol)
        assert w.capped == 0 and not w.cap_hit
        assert w.k.max() > 1  # curved: refined
        measured = measured_deviation(mesh, w)
        print(f"annulus {relative:g} of the diagonal: tolerance {tol:.3g}, measured {measured:.3g}, "
              f"k {np.bincount(w.k).nonzero()[0].tolist()}, {len(w.triangles)} triangles")
        assert measured <= tol
        # closed and wound outward: it encloses the annulus' volume (pi/4 (1 - 0.3^2) x 1)
        assert enclosed_volume(w) == pytest.approx(math.pi / 4 * (1 - 0.09), rel=2e-3)


def test_curved_mixed_walls_are_within_tolerance():
    mesh = curved_cube(3, 3)
    assert set(np.unique(mesh.shape)) == {shapes.HEX, shapes.PRISM, shapes.TET, shapes.PYR}
    for relative in (1e-3, 1e-4):
        tol = walls.default_tolerance(mesh, relative)
        w = walls.tessellate(mesh, tol)
        assert w.capped == 0
        on = set(np.unique(mesh.shape[w.element]).tolist())
        assert {shapes.HEX, shapes.PRISM, shapes.TET} <= on  # the boundary has curved faces of several shapes
        measured = measured_deviation(mesh, w)
        print(f"curved mixed cube {relative:g} of the diagonal: tolerance {tol:.3g}, measured {measured:.3g}, "
              f"k {np.bincount(w.k).nonzero()[0].tolist()}, {len(w.triangles)} triangles")
        assert measured <= tol


def test_straight_mixed_cube_walls():
    mesh = mixed_cube(3, 2, lambda x, y, z: x)
    w = walls.tessellate(mesh, 1e-6)
    assert (w.k == 1).all()
    nsides = np.array([len(shapes.plane_vertices(int(s))[f]) for s, f in zip(mesh.shape[w.element], w.face)])
    assert len(w.triangles) == (nsides == 4).sum() * 2 + (nsides == 3).sum()
    v = w.vertices[w.triangles]
    area = 0.5 * np.linalg.norm(np.cross(v[:, 1] - v[:, 0], v[:, 2] - v[:, 0]), axis=1)
    assert area.sum() == pytest.approx(6.0, rel=1e-12)  # the unit cube's faces, each once (no inside faces)
    assert np.abs(np.minimum(w.vertices, 1 - w.vertices)).min(axis=1).max() < 1e-12  # all on the cube's faces
    assert enclosed_volume(w) == pytest.approx(1.0, rel=1e-12)


def test_straight_brick_two_triangles_per_quad():
    mesh = brick((0, 0, 0), (2, 3, 4), (2, 3, 4), 2, lambda x, y, z: x)  # no geometry expansion
    w = walls.tessellate(mesh)
    assert len(w.element) == 2 * (2 * 3 + 3 * 4 + 2 * 4)
    assert (w.k == 1).all() and len(w.triangles) == 2 * len(w.element)
    assert enclosed_volume(w) == pytest.approx(24.0, rel=1e-12)
    vertices, triangles = w  # unpacks as the two arrays
    assert vertices.shape == (4 * len(w.element), 3) and triangles.shape == (len(w.triangles), 3)


def test_cap_is_reported():
    mesh = _annulus()
    w = walls.tessellate(mesh, 1e-12, max_k=2)
    assert w.cap_hit and w.capped > 0 and w.k.max() == 2


def test_bad_tolerance():
    with pytest.raises(ValueError):
        walls.tessellate(_annulus(), 0.0)


def test_hump3d_wall_from_its_boundary_region():
    """A chosen composite's faces (hump3D's B[0], the WallViscous bottom with the hump): within
    the tolerance of the true surface at random points, and wound outward of the domain (down)."""
    from hovr_blender.io.nektar import mesh_boundaries

    path = data_file("nektar", "hump3D_GLL.xml")
    mesh = read_nektar(str(path))
    faces = mesh_boundaries(path).select("B[0]")
    tol = walls.default_tolerance(mesh)
    w = walls.tessellate(mesh, tol, faces=faces)
    assert w.capped == 0 and len(w.element) == 160 and w.k.max() > 1  # the hump's faces refined
    np.testing.assert_array_equal(w.element, faces[0])
    measured = measured_deviation(mesh, w)
    print(f"hump3D wall: tolerance {tol:.3g}, measured {measured:.3g}, k {np.bincount(w.k).nonzero()[0].tolist()}, "
          f"{len(w.triangles)} triangles")
    assert measured <= tol
    # the bottom is a graph over the 20 x 10 mm rectangle: its outward (downward) area vector is -A z
    v = w.vertices[w.triangles]
    area_vector = 0.5 * np.cross(v[:, 1] - v[:, 0], v[:, 2] - v[:, 0]).sum(axis=0)
    np.testing.assert_allclose(area_vector, [0.0, 0.0, -0.02 * 0.01], atol=1e-12)
    assert w.vertices[:, 2].max() == pytest.approx(0.00116454, abs=1e-8)


def test_face_selection_is_checked():
    mesh = mixed_cube(2, 2, lambda x, y, z: x)
    w = walls.tessellate(mesh, faces=([0, 0], [0, 1]))
    assert w.element.tolist() == [0, 0] and w.face.tolist() == [0, 1]
    n = mesh.num_elements
    tet = int(np.nonzero(mesh.shape == shapes.TET)[0][0])
    for faces, message in [
        (([n], [0]), f"element {n} is not in the mesh ({n} elements)"),
        (([-1], [0]), "element -1 is not in the mesh"),
        (([tet], [4]), f"element {tet} (tetrahedron) has no face 4"),
        (([0, 1], [0]), "two 1-D integer arrays of one length"),
        (([0.5], [0]), "two 1-D integer arrays of one length"),
        ((None, None), "two 1-D integer arrays"),
    ]:
        with pytest.raises(ValueError, match=re.escape(message)):
            walls.tessellate(mesh, faces=faces)
